"""Open the window: `orientation-lab` with no subcommand ends up in run_gui(args).

Qt is imported only inside the functions, so the command line can add these arguments
(add_gui_arguments) without importing Qt for its headless subcommands.
"""

from __future__ import annotations

import argparse
import signal
import tempfile
from pathlib import Path
from typing import Any

DEFAULT_PORT = 3400


def add_gui_arguments(parser: argparse.ArgumentParser) -> None:
    """The window's options on the top-level parser (no Qt import)."""
    group = parser.add_argument_group("window")
    group.add_argument("--host", default="0.0.0.0",
                       help="address to listen on for the phone (default all)")
    group.add_argument("--port", type=int, default=DEFAULT_PORT,
                       help=f"TCP port for the phone (default {DEFAULT_PORT})")
    group.add_argument("--demo", action="store_true",
                       help="play the built-in demo session (still listening)")
    group.add_argument("--replay", metavar="LOG", help="play a phone log or recording")
    group.add_argument("--speed", type=float, default=1.0, help="replay speed (default 1)")
    group.add_argument("--loop", action="store_true", help="replay in a loop")
    group.add_argument("--settings", metavar="FILE.json", help="filter settings")
    group.add_argument("--screenshot", metavar="PNG",
                       help="save the window to PNG after --exit-after seconds, then quit")
    group.add_argument("--exit-after", type=float, metavar="S", help="quit after S seconds")


def _usage_error(message: str) -> Exception:
    try:
        from app.cli import UsageError
    except ImportError:   # the window can run without the CLI module
        return SystemExit(f"orientation-lab: error: {message}")
    return UsageError(message)


def _load_filter_settings(path: str | None) -> Any:
    if not path:
        return None
    import ekf
    try:
        if hasattr(ekf.EKFSettings, "load"):
            return ekf.EKFSettings.load(path)
        import json
        return ekf.EKFSettings.from_dict(json.loads(Path(path).read_text()))
    except FileNotFoundError:
        raise _usage_error(f"settings file not found: {path}") from None
    except (OSError, ValueError, TypeError) as error:
        raise _usage_error(f"bad settings file {path}: {error}") from None


def make_source(args: argparse.Namespace) -> Any:
    """The engine's source for these arguments: a replayed log, the demo, or the TCP server.

    --demo plays the demo while the TCP server listens; a phone that connects takes over.
    """
    from app.io import sources
    replay = getattr(args, "replay", None)
    if replay:
        if not Path(replay).is_file():
            raise _usage_error(f"log file not found: {replay}")
        speed = float(getattr(args, "speed", 1.0) or 1.0)
        if speed <= 0:
            raise _usage_error("--speed must be positive")
        return sources.LogFileSource(replay, speed=speed, loop=bool(getattr(args, "loop", False)))
    if getattr(args, "demo", False):
        return sources.DemoOrPhoneSource(
            sources.demo_source(),
            sources.TcpSource(getattr(args, "host", "0.0.0.0"), int(getattr(args, "port", DEFAULT_PORT))))
    return sources.TcpSource(getattr(args, "host", "0.0.0.0"),
                             int(getattr(args, "port", DEFAULT_PORT)))


def build_engine(args: argparse.Namespace) -> Any:
    """An (unstarted) Engine for the arguments."""
    from app.engine import Engine
    from app.io.logfile import LogError
    settings = _load_filter_settings(getattr(args, "settings", None))
    try:
        source = make_source(args)
    except (LogError, OSError) as error:     # unreadable or damaged beyond use
        raise _usage_error(str(error)) from None
    return Engine(source, settings=settings)


def _grab_window(window) -> "Any":
    """The whole window as a QImage (the 3D views are ordinary widgets showing their
    offscreen renders, so QWidget.grab includes them)."""
    return window.grab().toImage()


GUI_SWITCH_INTERVAL_S = 0.0002


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
    import sys

    from PySide6 import QtCore, QtWidgets
    QtCore.QCoreApplication.setAttribute(QtCore.Qt.ApplicationAttribute.AA_ShareOpenGLContexts)
    sys.setswitchinterval(GUI_SWITCH_INTERVAL_S)
    return QtWidgets.QApplication.instance() or QtWidgets.QApplication([])


def run_gui(args: argparse.Namespace) -> int:
    """Open the window for parsed arguments; returns the exit status once it closes."""
    from PySide6 import QtCore, QtWidgets

    from app import __version__
    from app.ui.main_window import APPLICATION, ORGANIZATION, MainWindow

    screenshot = getattr(args, "screenshot", None)
    exit_after = getattr(args, "exit_after", None)
    if screenshot and exit_after is None:
        raise _usage_error("--screenshot needs --exit-after S")
    if exit_after is not None and exit_after < 0:
        raise _usage_error("--exit-after must be >= 0")

    engine = build_engine(args)   # before Qt: a bad path is a one-line error, no window

    QtCore.QCoreApplication.setOrganizationName(ORGANIZATION)
    QtCore.QCoreApplication.setApplicationName(APPLICATION)
    QtCore.QCoreApplication.setApplicationVersion(__version__)
    app = make_application()

    settings = None
    temporary_settings = None
    if screenshot:
        # A screenshot shows the default layout and leaves the user's preferences alone.
        temporary_settings = tempfile.TemporaryDirectory(prefix="orientation-lab-")
        settings = QtCore.QSettings(str(Path(temporary_settings.name) / "settings.ini"),
                                    QtCore.QSettings.Format.IniFormat)

    try:
        engine.start()
    except OSError as error:            # e.g. the port is taken
        engine.stop()
        raise _usage_error(f"cannot start the source: {error.strerror or error}") from None
    window = None
    try:
        window = MainWindow(engine, settings=settings)
        if screenshot:
            window.resize(1600, 1000)
        window.show()
        status = {"code": 0}

        def finish() -> None:
            if screenshot:
                image = _grab_window(window)
                if not image.save(str(screenshot)):
                    print(f"orientation-lab: error: cannot write {screenshot}")
                    status["code"] = 1
            window.close()
            app.quit()

        if exit_after is not None:
            QtCore.QTimer.singleShot(int(exit_after * 1000), finish)
        # Ctrl+C in the terminal closes the window cleanly; the timer lets Python see it.
        signal.signal(signal.SIGINT, lambda *_: window.close())
        wake = QtCore.QTimer()
        wake.timeout.connect(lambda: None)
        wake.start(250)
        app.exec()
        wake.stop()
        return status["code"]
    finally:
        # The window stops the engine when it closes; stop it here when it never opened.
        if window is not None:
            window.shutdown()
        else:
            engine.stop()
        if temporary_settings is not None:
            temporary_settings.cleanup()
        signal.signal(signal.SIGINT, signal.default_int_handler)


if __name__ == "__main__":   # python -m app.ui.main --demo
    parser = argparse.ArgumentParser(prog="orientation-lab")
    add_gui_arguments(parser)
    raise SystemExit(run_gui(parser.parse_args()))

