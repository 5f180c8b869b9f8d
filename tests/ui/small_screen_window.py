"""The whole window on a small screen, as a user meets it: run as a script in its own process
(the screen's size is the process's: offscreen with a config file, or an X server such as
Xvfb), it opens the window as `orientation-lab` does (sized to the screen), streams a log to it
through the phone emulator (or plays the demo), starts a recording, loads a filter of yours that fails, then shows
every workspace, the Tune and Calibrate tabs and every dock in turn and reports, as JSON on
stdout, the window's width against the screen's and everything cut (tests/ui/clipping.py):

    python tests/ui/small_screen_window.py LOG BROKEN_FILTER.py OUT_FOLDER [live|demo]

Used by tests/ui/test_ui_small_screen.py.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.append(str(HERE))              # clipping (after the package paths: tests/ekf ≠ ekf)

TIMEOUT_S = 60.0


def main(log: str, broken: str, out: str, source: str = "live") -> int:
    """source: "live" (the phone emulator streams `log` over TCP) or "demo" (the built-in demo
    replays, the TCP server listening)."""
    from PySide6 import QtCore

    from app.engine.commands import LoadUserFilter, StartRecording, StopRecording
    from app.engine.config import SourceOptions
    from app.stream.emulator import PhoneEmulator
    from app.stream.lines import read_lines
    from app.ui.main import WindowOptions, build_engine, make_application
    from app.ui.main_window import MainWindow
    from clipping import clipped, hidden_columns, scrolls

    app = make_application()
    engine = build_engine(WindowOptions(source=SourceOptions(host="127.0.0.1", port=0,
                                                             demo=source == "demo")))
    engine.start()
    settings = QtCore.QSettings(str(Path(out) / "settings.ini"),
                                QtCore.QSettings.Format.IniFormat)
    window = MainWindow(engine, settings=settings, tune_log=log)
    window.show()
    screen = window.screen().availableGeometry()
    report: dict = {"screen": [screen.width(), screen.height()], "findings": [], "widths": [],
                    "right_edges": [], "minimum_width": 0}

    def pump_until(condition, what: str) -> None:
        deadline = time.monotonic() + TIMEOUT_S
        while not condition():
            if time.monotonic() > deadline:
                raise SystemExit(f"timed out waiting for {what}")
            app.processEvents(QtCore.QEventLoop.ProcessEventsFlag.AllEvents, 20)

    def settle() -> None:
        """Let the window lay out and draw a few frames (the timer's ticks)."""
        frames = window.ticks + 4
        pump_until(lambda: window.ticks >= frames, "display frames")

    def check(where: str) -> None:
        settle()
        # a refresh in the last pump may have asked for a new layout: Qt lays out before it
        # paints, so look at the window as it is painted
        app.sendPostedEvents(None, QtCore.QEvent.Type.LayoutRequest)
        geometry = window.frameGeometry()
        report["widths"].append(window.width())
        report["right_edges"].append(geometry.right())
        report["minimum_width"] = max(report["minimum_width"],
                                      window.minimumSizeHint().width())
        for finding in clipped(window, whole=(window.filter_dock.widget(),)):
            report["findings"].append(f"{where}: {finding}")
        scroll = window.filter_dock.widget()
        if scrolls(scroll):
            report["findings"].append(
                f"{where}: the Filter dock scrolls ({scroll.widget().sizeHint().height()} px in "
                f"{scroll.viewport().height()})")
        tables = [window.comparison.table, window.tune.settings_panel.table]
        if window.tune.ab_view is not None:
            tables.append(window.tune.ab_view.table)
        if window.tune.tuning_panel is not None:
            tables += [window.tune.tuning_panel.parameters, window.tune.tuning_panel.figures]
        for table in tables:
            for column in hidden_columns(table):
                report["findings"].append(f"{where}: {table.objectName() or type(table).__name__}"
                                          f" hides its column {column!r}")
        if window.transport.replaying and window.transport.slider.width() < 150:
            report["findings"].append(f"{where}: the time slider is "
                                      f"{window.transport.slider.width()} px wide")

    if source == "live":
        pump_until(lambda: engine.source.port, "the TCP server")
    stop = threading.Event()
    lines = read_lines(log)

    def phone() -> None:
        with PhoneEmulator("127.0.0.1", engine.source.port) as emulator:
            emulator.stream_lines(lines, 1.0, True, stop)

    sender = threading.Thread(target=phone, daemon=True)
    if source == "live":
        sender.start()
    window.send(LoadUserFilter(broken))
    window.send(StartRecording(str(Path(out) / "recording")))
    pump_until(lambda: (window.last_snapshot is not None and window.last_snapshot.recording
                        and window.last_snapshot.recording.get("active")
                        and window.last_snapshot.recording.get("lines", 0) > 800
                        and window.last_snapshot.user is not None
                        and window.last_snapshot.user.problem is not None),
               "the stream, the recording and your filter's problem")
    window.workspaces.setCurrentWidget(window.tune)
    pump_until(lambda: window.tune.refilterer is not None
               and window.tune.refilterer.current is not None, "Tune's re-run")
    window.calibration.analyse_log(log)
    for index in range(window.workspaces.count()):
        window.workspaces.setCurrentIndex(index)
        name = window.workspaces.tabText(index)
        check(name)
        if window.workspaces.currentWidget() is window.tune:
            window.tune.tabs.setCurrentIndex(1)
            check("Tune / Auto-tune")
            window.tune.tabs.setCurrentIndex(0)
        if window.workspaces.currentWidget() is window.calibration:
            views = window.calibration.rest.views
            for view in range(views.count()):
                views.setCurrentIndex(view)
                check(f"Calibrate / {views.tabText(view)}")
    window.workspaces.setCurrentIndex(0)
    zoom(window.plots)                  # the note that the plots no longer follow
    check("Live / Replay, a plot zoomed")
    for dock in window.docks():
        dock.raise_()
        check(f"dock {dock.objectName()}")
    window.send(StopRecording())
    pump_until(lambda: not window.last_snapshot.recording.get("active"), "the recording saved")
    check("after the recording")
    stop.set()
    if sender.is_alive():
        sender.join(10.0)
    window.close()
    window.shutdown()
    print(json.dumps(report))
    return 0


def zoom(plots) -> None:
    """Turn the mouse wheel over the accelerometer's plot, as a user zooms it."""
    from PySide6 import QtCore, QtGui, QtWidgets
    group = plots.groups["sensors"]
    view_box = plots.plots["acc"].getViewBox()
    position = QtCore.QPointF(group.graphics.mapFromScene(view_box.sceneBoundingRect().center()))
    viewport = group.graphics.viewport()
    event = QtGui.QWheelEvent(position, QtCore.QPointF(viewport.mapToGlobal(position.toPoint())),
                              QtCore.QPoint(0, 0), QtCore.QPoint(0, 240),
                              QtCore.Qt.MouseButton.NoButton,
                              QtCore.Qt.KeyboardModifier.NoModifier,
                              QtCore.Qt.ScrollPhase.NoScrollPhase, False)
    QtWidgets.QApplication.sendEvent(viewport, event)
    if not plots.follow_note.isVisible():
        raise SystemExit("the zoom did not stop following")


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:5]))
