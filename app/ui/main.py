"""Open the window: `orientation-lab` with no command ends up in :func:`run_gui`.

The engine is built first, through the engine's one configuration module, so a bad path or
setting is a one-line ConfigError before any window opens; Qt is imported only inside the
functions, so importing this module costs nothing for the headless commands.
"""

from __future__ import annotations

import errno
import logging
import logging.handlers
import os
import signal
import sys
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from app import paths
from app.engine.config import ConfigError, SourceOptions, load_settings, make_source, open_replay
from app.engine.offline.outputs import write_output
from app.engine.live.worker import on_finishing_signals
from app.engine.live.worker import Engine
from app.stream.forwarder import LineForwarder
from app.stream.sources import DEMO_SESSION

GUI_SWITCH_INTERVAL_S = 0.0002
HEADLESS_COMMANDS = ("filter, evaluate, calibrate, calibrate-mag, tune, simulate, send, serve, "
                     "new-filter, export")


@dataclass
class WindowOptions:
    """What the window opens on: the source, filter settings (file or preset name) and, for
    screenshots, a PNG to save after exit_after seconds; filter: your own filter file, run
    beside ours as YOURS (--filter); forward: (host, port) that gets a copy of every line from
    the phone (--forward)."""

    source: SourceOptions = field(default_factory=SourceOptions)
    settings: str | None = None
    screenshot: str | None = None
    exit_after: float | None = None
    size: tuple[int, int] | None = None
    filter: str | None = None
    forward: tuple[str, int] | None = None
    record: str | None = None              # record from the start into this folder
    record_max_mb: float | None = None
    record_min_free_mb: float | None = None


def build_engine(options: WindowOptions) -> Engine:
    """An (unstarted) engine for the options; ConfigError for a bad path or setting."""
    forwarder = LineForwarder(*options.forward) if options.forward else None
    return Engine(make_source(options.source), settings=load_settings(options.settings),
                  limits=options.source.limits, user_filter=options.filter,
                  forwarder=forwarder)


def session_to_tune(source: SourceOptions) -> Path | str | None:
    """What the Tune workspace re-filters: the replayed log or session, or the demo's."""
    if source.replay:
        return source.replay
    return DEMO_SESSION if source.demo else None


def replay_engine_factory(options: WindowOptions):
    """File → Open and drops: an engine replaying a path with the window's settings."""
    def build(path: str) -> Engine:
        return Engine(open_replay(path, limits=options.source.limits),
                      settings=load_settings(options.settings), limits=options.source.limits)
    return build


def phone_engine_factory(options: WindowOptions):
    """The connection panel and File → Connect a phone: an engine on another phone app
    ("sensor-fusion" PORT, "phyphox" URL, "sensor-logger" PORT) with the window's settings,
    bounds, who may connect and forward target."""
    def build(app: str, where: str) -> Engine:
        source = replace(options.source, replay=None, demo=False, phyphox=None,
                         sensor_logger=None)
        if app == "phyphox":
            source = replace(source, phyphox=where)
        elif app == "sensor-logger":
            source = replace(source, sensor_logger=where)
        else:
            source = replace(source, port=where)
        forwarder = LineForwarder(*options.forward) if options.forward else None
        return Engine(make_source(source), settings=load_settings(options.settings),
                      limits=options.source.limits, forwarder=forwarder)
    return build


def check_display() -> None:
    """ConfigError (one line, exit 2) instead of Qt aborting when there is no screen: DISPLAY
    unset, or set to an X server that does not answer (a stale DISPLAY over ssh, a closed
    server)."""
    if not sys.platform.startswith("linux"):
        return
    env = os.environ
    platform = env.get("QT_QPA_PLATFORM", "")
    if not (env.get("DISPLAY") or env.get("WAYLAND_DISPLAY") or platform):
        raise ConfigError("no display to open the window on (DISPLAY is not set); without a "
                          f"screen use the headless commands: {HEADLESS_COMMANDS} "
                          "(orientation-lab COMMAND --help)")
    uses_x = platform.startswith("xcb") or (not platform and not env.get("WAYLAND_DISPLAY"))
    if uses_x and env.get("DISPLAY") and not x_server_answers():
        raise ConfigError(f"no display to open the window on (the X server DISPLAY="
                          f"{env['DISPLAY']} does not answer); without a screen use the "
                          f"headless commands: {HEADLESS_COMMANDS} (orientation-lab COMMAND "
                          "--help)")


def x_server_answers() -> bool:
    """Whether the X server named by DISPLAY accepts a connection, asked through libxcb (the
    library Qt's xcb platform connects with, so the answer is the one Qt would get). True when
    libxcb cannot be loaded: then Qt's own message is the best there is."""
    import ctypes
    import ctypes.util

    try:
        xcb = ctypes.CDLL(ctypes.util.find_library("xcb") or "libxcb.so.1")
    except OSError:
        return True
    xcb.xcb_connect.restype = ctypes.c_void_p
    xcb.xcb_connect.argtypes = (ctypes.c_char_p, ctypes.c_void_p)
    xcb.xcb_connection_has_error.argtypes = (ctypes.c_void_p,)
    xcb.xcb_disconnect.argtypes = (ctypes.c_void_p,)
    connection = xcb.xcb_connect(None, None)
    try:
        return bool(connection) and xcb.xcb_connection_has_error(connection) == 0
    finally:
        if connection:
            xcb.xcb_disconnect(connection)


def log_to_file() -> Path | None:
    """Engine failures (with tracebacks) go to the user's log file, at most 1 MB x 3."""
    try:
        path = paths.log_file()
        handler = logging.handlers.RotatingFileHandler(path, maxBytes=1 << 20, backupCount=2,
                                                       encoding="utf-8")
    except OSError:
        return None
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s: %(message)s"))
    root = logging.getLogger("orientation_lab")
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    return path


def make_application():
    """The QApplication, configured for the window (call before any widget exists).

    - GL contexts share (the 3D views all render in one offscreen context of their own, see
      app/ui/phone_view.py; sharing keeps any other GL widget able to use their resources).
    - A shorter GIL switch interval: the engine thread runs Python code, and the GUI thread
      gives up the GIL on every Qt call and takes it back for every Python method Qt calls
      (each plot item's paint and boundingRect); with the default 5 ms it then waits up to
      5 ms to get it back, hundreds of times per frame. 0.2 ms keeps a busy engine (a 10x
      replay) from halving the frame rate; the engine pays only while the GUI wants the GIL.
    - LP_NUM_THREADS (Mesa llvmpipe's rasteriser threads) is left to Mesa: limiting it to
      0 or 1 thread did not lower the process's CPU per frame (measured with
      benchmarks/gui_fps.py) and made each frame take longer.
    """
    from PySide6 import QtCore, QtWidgets
    QtCore.QCoreApplication.setAttribute(QtCore.Qt.ApplicationAttribute.AA_ShareOpenGLContexts)
    sys.setswitchinterval(GUI_SWITCH_INTERVAL_S)
    return QtWidgets.QApplication.instance() or QtWidgets.QApplication([])


def run_gui(options: WindowOptions) -> int:
    """Open the window; returns the exit status once it closes. ConfigError for bad options."""
    if options.screenshot and options.exit_after is None:
        raise ConfigError("--screenshot needs --exit-after S")
    engine = build_engine(options)   # before Qt: a bad path is a one-line error, no window
    check_display()
    log_path = log_to_file()

    from PySide6 import QtCore

    from app import __version__
    from app.ui.main_window import APPLICATION, ORGANIZATION, MainWindow

    QtCore.QCoreApplication.setOrganizationName(ORGANIZATION)
    QtCore.QCoreApplication.setApplicationName(APPLICATION)
    QtCore.QCoreApplication.setApplicationVersion(__version__)
    app = make_application()

    settings = None
    temporary_settings = None
    if options.screenshot:
        # A screenshot shows the default layout and leaves the user's preferences alone.
        temporary_settings = tempfile.TemporaryDirectory(prefix="orientation-lab-")
        settings = QtCore.QSettings(str(Path(temporary_settings.name) / "settings.ini"),
                                    QtCore.QSettings.Format.IniFormat)
    finishing: list[bool] = []          # SIGTERM or SIGHUP came: the window closes
    restore_signals = on_finishing_signals(lambda: finishing.append(True))
    try:
        engine.start()
    except OSError as error:            # e.g. the port is taken
        restore_signals()
        engine.stop()
        given = options.source
        where = ("" if given.replay else f" (listening on {given.sensor_logger})"
                 if given.sensor_logger else f" (listening on {given.host}:{given.port})")
        raise ConfigError(f"cannot start the source{where}: {error.strerror or error}"
                          + ("; another program (or Orientation Lab) uses that port: choose "
                             "another with --port" if error.errno == errno.EADDRINUSE else "")) \
            from None
    if options.record:
        from app.engine.commands import StartRecording
        engine.send(StartRecording(options.record, options.record_max_mb,
                                   options.record_min_free_mb))
    window = None
    try:
        window = MainWindow(engine, settings=settings, log_path=log_path,
                            tune_log=session_to_tune(options.source),
                            engine_factory=replay_engine_factory(options),
                            phone_factory=phone_engine_factory(options))
        if options.size is not None:
            window.resize(*options.size)
            window.arrange_default_layout()
        elif options.screenshot:
            window.resize(1600, 1000)
            window.arrange_default_layout()
        window.show()
        return _run_event_loop(app, window, options, finishing)
    finally:
        # The window stops the engine when it closes; stop it here when it never opened.
        if window is not None:
            window.shutdown()
        else:
            engine.stop()
        if temporary_settings is not None:
            temporary_settings.cleanup()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        restore_signals()


def _png(image: Any) -> bytes:
    """A QImage as the bytes of a PNG file."""
    from PySide6 import QtCore
    data = QtCore.QByteArray()
    buffer = QtCore.QBuffer(data)
    buffer.open(QtCore.QIODevice.OpenModeFlag.WriteOnly)
    image.save(buffer, "PNG")
    buffer.close()
    return bytes(data)


def _run_event_loop(app: Any, window: Any, options: WindowOptions,
                    finishing: list[bool]) -> int:
    from PySide6 import QtCore
    status = {"code": 0}

    def finish() -> None:
        if options.screenshot:
            image = window.grab().toImage()   # the 3D views show offscreen renders: included
            try:
                write_output(options.screenshot, _png(image))
            except ConfigError as error:
                print(f"orientation-lab: error: {error}", file=sys.stderr)
                status["code"] = 1
        window.close()
        app.quit()

    if options.exit_after is not None:
        QtCore.QTimer.singleShot(int(options.exit_after * 1000), finish)
    # Ctrl+C in the terminal closes the window cleanly; the timer lets Python see it, and
    # closes the window after a SIGTERM or SIGHUP (also one that came while it opened).
    signal.signal(signal.SIGINT, lambda *_: window.close())
    wake = QtCore.QTimer()
    wake.timeout.connect(lambda: finishing and window.close())
    wake.start(250)
    app.exec()
    wake.stop()
    return status["code"]
