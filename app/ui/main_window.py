"""The main window: OWN and PHONE in 3D, lights and switches, connection panel, live plots.

The window owns no filter state. A QTimer at display rate takes the engine's latest
snapshot with `engine.poll()` (non-blocking) and hands its parts to the widgets; the widgets
send user intent back with `engine.send(command)`. The engine runs on its own thread, so
the frame rate does not depend on the sample rate and the filter never waits for drawing.

Per frame only what moves is drawn: the two 3D views (each rendered once, only when its pose
changed), the lights and the plots. Tables, counters and the status bar are text that nobody
reads at 60 Hz: they follow the latest snapshot at PANEL_INTERVAL_S, and only labels whose
text changed are touched. The frame rate shown (and measured by benchmarks/gui_fps.py) counts
frames actually painted, not timer ticks.
"""

from __future__ import annotations

import math
import platform
import time
from collections import deque
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from app import __version__
from app.engine.snapshot import Snapshot
from app.ui.connection import ConnectionPanel, connection_text
from app.ui.controls import ControlsPanel
from app.ui.failures import FailureDialog
from app.ui.lights import LightsPanel
from app.ui.phone_view import PhoneView, software_gl
from app.ui.plots import PlotPanel

ORGANIZATION = "OrientationLab"
APPLICATION = "OrientationLab"
FRAME_INTERVAL_MS = 16          # ~60 Hz display rate (hardware OpenGL or no 3D)
# With software OpenGL every 3D frame is rasterised on the CPU next to the filter: 40 Hz keeps
# the motion smooth (>= 30 fps) at two thirds of the cost.
SOFTWARE_GL_FRAME_INTERVAL_MS = 25
PANEL_INTERVAL_S = 0.2          # tables, counters, status bar: 5 updates per second
SETTINGS_VERSION = 1


class EngineLike(Protocol):
    """What the window needs from the engine (app.engine.Engine, or a test double)."""

    def poll(self) -> Snapshot | None: ...
    def send(self, command: Any) -> None: ...
    def start(self) -> None: ...
    def stop(self) -> None: ...


def default_settings() -> QtCore.QSettings:
    return QtCore.QSettings(ORGANIZATION, APPLICATION)


def _to_bool(value: Any, default: bool) -> bool:
    # QSettings returns strings ("true"/"false") from INI files and bools from the registry.
    if value is None:
        return default
    if isinstance(value, str):
        return value.lower() in ("true", "1", "yes")
    return bool(value)


class MainWindow(QtWidgets.QMainWindow):
    """The application window around one engine.

    Args:
        engine: anything with poll/send/start/stop (the window does not start it; it stops it
            when the window closes).
        settings: where layout and switches persist; default QSettings("OrientationLab",
            "OrientationLab"). Tests pass an INI file.
        use_gl: force 3D views on/off; None detects (never GL on the offscreen platform).
        frame_interval_ms: display refresh period; None: FRAME_INTERVAL_MS, or
            SOFTWARE_GL_FRAME_INTERVAL_MS when the 3D views render in software.
        log_path: where engine failures are logged (named in the failure dialog).
    """

    def __init__(self, engine: EngineLike, settings: QtCore.QSettings | None = None,
                 use_gl: bool | None = None, frame_interval_ms: int | None = None,
                 log_path: Path | None = None) -> None:
        super().__init__()
        self.engine = engine
        self.failure_dialog = FailureDialog(self, log_path)
        self._failures_shown = 0
        self.settings = settings if settings is not None else default_settings()
        self.last_snapshot: Snapshot | None = None
        self.ticks = 0                      # display ticks (timer callbacks)
        self.frames_painted = 0             # ticks whose changes reached the screen
        self.snapshots_received = 0
        self._engine_stopped = False
        self._last_warning = ""
        self._frame_times: deque[float] = deque()
        self._painted_tick = -1
        self._panel_snapshot: Snapshot | None = None   # not yet shown in the slow panels
        self._panels_shown_at = -math.inf

        self.setWindowTitle("Orientation Lab")
        self.setObjectName("main_window")
        self.setDockOptions(QtWidgets.QMainWindow.DockOption.AnimatedDocks
                            | QtWidgets.QMainWindow.DockOption.AllowNestedDocks)

        # Centre: the two phones side by side above the plots.
        self.own_view = PhoneView("OWN", use_gl=use_gl)
        self.phone_view = PhoneView("PHONE", use_gl=use_gl)
        self.plots = PlotPanel()
        self.views_splitter = QtWidgets.QSplitter(QtCore.Qt.Orientation.Horizontal)
        self.views_splitter.setObjectName("views_splitter")
        self.views_splitter.addWidget(self.own_view)
        self.views_splitter.addWidget(self.phone_view)
        self.central_splitter = QtWidgets.QSplitter(QtCore.Qt.Orientation.Vertical)
        self.central_splitter.setObjectName("central_splitter")
        self.central_splitter.addWidget(self.views_splitter)
        self.central_splitter.addWidget(self.plots)
        self.central_splitter.setStretchFactor(0, 4)
        self.central_splitter.setStretchFactor(1, 5)
        self.central_splitter.setSizes([420, 520])     # until a saved layout says otherwise
        self.setCentralWidget(self.central_splitter)

        # Side: lights and switches, then the connection panel, in docks.
        self.lights = LightsPanel()
        self.controls = ControlsPanel(self.send)
        self.connection = ConnectionPanel(self.send)
        filter_widget = QtWidgets.QWidget()
        filter_layout = QtWidgets.QVBoxLayout(filter_widget)
        filter_layout.setContentsMargins(4, 4, 4, 4)
        filter_layout.addWidget(self.lights)
        filter_layout.addWidget(self.controls, 1)
        self.filter_dock = self._add_dock("Filter", "filter_dock", filter_widget)
        self.connection_dock = self._add_dock("Connection", "connection_dock", self.connection)
        self.controls.uncertainty_toggled.connect(self.own_view.set_uncertainty_visible)

        self._build_status_bar()
        self._build_actions()
        self.resize(1500, 950)
        self.restore_settings()

        self._frame_filter = _PaintCounter(self._on_paint)
        for widget in self._drawn_widgets():
            widget.installEventFilter(self._frame_filter)

        if frame_interval_ms is None:
            frame_interval_ms = (SOFTWARE_GL_FRAME_INTERVAL_MS
                                 if self.own_view.gl_view is not None and software_gl()
                                 else FRAME_INTERVAL_MS)
        self.frame_interval_ms = int(frame_interval_ms)
        self.timer = QtCore.QTimer(self)
        self.timer.setTimerType(QtCore.Qt.TimerType.PreciseTimer)
        self.timer.timeout.connect(self.tick)
        self.timer.start(self.frame_interval_ms)

    # ---- construction ---------------------------------------------------------------------

    def _add_dock(self, title: str, name: str, widget: QtWidgets.QWidget) -> QtWidgets.QDockWidget:
        dock = QtWidgets.QDockWidget(title, self)
        dock.setObjectName(name)
        scroll = QtWidgets.QScrollArea()
        scroll.setWidgetResizable(True)
        # Panels wrap their text instead: a sideways scroll bar hides the ends of lines.
        scroll.setHorizontalScrollBarPolicy(QtCore.Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setFrameShape(QtWidgets.QFrame.Shape.NoFrame)
        scroll.setWidget(widget)
        dock.setWidget(scroll)
        dock.setMinimumWidth(340)
        self.addDockWidget(QtCore.Qt.DockWidgetArea.RightDockWidgetArea, dock)
        return dock

    def _build_status_bar(self) -> None:
        bar = self.statusBar()
        self.state_status = QtWidgets.QLabel("waiting")
        self.time_status = QtWidgets.QLabel("t = –")
        self.rates_status = QtWidgets.QLabel("")
        self.fps_status = QtWidgets.QLabel("")
        for label in (self.state_status, self.time_status, self.rates_status, self.fps_status):
            bar.addPermanentWidget(label)

    def _action(self, menu: QtWidgets.QMenu, text: str, shortcut: str | QtGui.QKeySequence | None,
                slot, checkable: bool = False) -> QtGui.QAction:
        action = QtGui.QAction(text, self)
        if shortcut is not None:
            action.setShortcut(QtGui.QKeySequence(shortcut))
            # Window-wide, so the shortcut works whichever panel has focus.
            action.setShortcutContext(QtCore.Qt.ShortcutContext.WindowShortcut)
        action.setCheckable(checkable)
        action.triggered.connect(slot)
        menu.addAction(action)
        self.addAction(action)
        return action

    def _build_actions(self) -> None:
        menus = self.menuBar()
        file_menu = menus.addMenu("&File")
        self.quit_action = self._action(file_menu, "&Quit", "Ctrl+Q", self.close)
        view_menu = menus.addMenu("&View")
        self.pause_action = self._action(view_menu, "&Pause / follow (replay: play / pause)",
                                         "Space", self.toggle_pause)
        self.clear_action = self._action(view_menu, "&Clear plots", "Ctrl+L", self.plots.clear)
        self._action(view_menu, "Reset 3D &views", None, self.reset_cameras)
        view_menu.addSeparator()
        view_menu.addAction(self.filter_dock.toggleViewAction())
        view_menu.addAction(self.connection_dock.toggleViewAction())
        filter_menu = menus.addMenu("F&ilter")
        self.reset_action = self._action(filter_menu, "&Reset filter", "Ctrl+R",
                                         self.controls.reset_button.click)
        self.align_action = self._action(filter_menu, "&Align heading with PHONE", "Ctrl+H",
                                         self.controls.align_button.click)
        filter_menu.addSeparator()
        for number, (sensor, label) in enumerate((("gyr", "gyroscope"), ("acc", "accelerometer"),
                                                  ("mag", "magnetometer")), start=1):
            self._action(filter_menu, f"Toggle {label}", f"Ctrl+{number}",
                         lambda checked=False, s=sensor: self.controls.toggle_sensor(s))
        help_menu = menus.addMenu("&Help")
        self.about_action = self._action(help_menu, "&About", "F1", self.show_about)

    # ---- engine --------------------------------------------------------------------------

    def send(self, command: Any) -> None:
        """Forward one command to the engine (applied between two batches of samples)."""
        self.engine.send(command)

    def tick(self) -> None:
        """One display frame: take the latest snapshot, draw it."""
        self.ticks += 1
        snapshot = self.engine.poll()
        if snapshot is not None:
            self.apply_snapshot(snapshot)
        self.plots.refresh()
        if time.monotonic() - self._panels_shown_at >= PANEL_INTERVAL_S:
            self.refresh_panels()

    def apply_snapshot(self, snapshot: Snapshot) -> None:
        """Hand one snapshot's parts to the widgets: what moves at once, the text panels at
        their own pace (refresh_panels)."""
        self.last_snapshot = snapshot
        self.snapshots_received += 1
        self.own_view.set_orientation(snapshot.own_quat, snapshot.own_cov)
        self.phone_view.set_orientation(snapshot.phone_quat)
        self.lights.update_status(snapshot.status)
        self.controls.update_status(snapshot.status)
        self.plots.append(snapshot.plot)
        self.plots.set_status(snapshot.status)
        self.connection.update_replay(snapshot.replay)
        self._panel_snapshot = snapshot
        if snapshot.failures and snapshot.failures[-1].number > self._failures_shown:
            latest = snapshot.failures[-1]
            self._failures_shown = latest.number
            self.failure_dialog.show_failure(latest, latest.number)
            self.statusBar().showMessage(f"engine error: {latest.message}", 15000)

    def refresh_panels(self) -> None:
        """Show the latest snapshot in the comparison table, connection panel and status bar
        (called from tick() at most every PANEL_INTERVAL_S)."""
        snapshot = self._panel_snapshot
        self._panel_snapshot = None
        self._panels_shown_at = time.monotonic()
        _set_text(self.fps_status, f"{self.frames_per_second():.0f} fps")
        if snapshot is None:
            return
        self.controls.update_comparisons(snapshot.comparisons)
        self.connection.update_health(snapshot.health)
        self._update_status_bar(snapshot)

    def _update_status_bar(self, snapshot: Snapshot) -> None:
        health = snapshot.health
        _set_text(self.state_status, connection_text(health))
        _set_text(self.time_status, "t = –" if snapshot.t_ms is None
                  else f"t = {snapshot.t_ms / 1000.0:.2f} s")
        _set_text(self.rates_status, "  ".join(f"{tag} {rate:.0f} Hz"
                                               for tag, rate in sorted(health.rates_hz.items())
                                               if tag in ("ACC", "GYR", "MAG", "ORI") and rate > 0))
        if health.warnings and health.warnings[-1] != self._last_warning:
            self._last_warning = health.warnings[-1]
            self.statusBar().showMessage(self._last_warning, 8000)

    # ---- frame counting -------------------------------------------------------------------

    def _drawn_widgets(self) -> list[QtWidgets.QWidget]:
        """The widgets that change every frame: their paint events are the frames."""
        widgets = [self.plots.graphics.viewport()]
        for view in (self.own_view, self.phone_view):
            widgets.append(view.gl_view if view.gl_view is not None else view.placeholder)
        return widgets

    def _on_paint(self) -> None:
        # Qt paints all widgets changed in one event-loop pass together: count one frame
        # per display tick that got painted, however many widgets it repainted.
        if self._painted_tick == self.ticks:
            return
        self._painted_tick = self.ticks
        self.frames_painted += 1
        now = time.monotonic()
        self._frame_times.append(now)
        while self._frame_times and now - self._frame_times[0] > 1.0:
            self._frame_times.popleft()

    def frames_per_second(self) -> float:
        """Frames painted in the last second."""
        now = time.monotonic()
        while self._frame_times and now - self._frame_times[0] > 1.0:
            self._frame_times.popleft()
        return float(len(self._frame_times))

    # ---- actions --------------------------------------------------------------------------

    def toggle_pause(self) -> None:
        """Space: play/pause a replay; otherwise pause/follow the plots."""
        if self.connection.replaying:
            self.connection.toggle_replay_paused()
        else:
            self.plots.toggle_paused()

    def reset_cameras(self) -> None:
        self.own_view.reset_camera()
        self.phone_view.reset_camera()

    def about_text(self) -> str:
        import pyqtgraph
        import PySide6
        return (f"<h3>Orientation Lab {__version__}</h3>"
                "<p>Live orientation estimation for the Sensor Fusion phone app: "
                "a quaternion EKF (OWN) beside the phone's own estimate (PHONE).</p>"
                f"<p>Python {platform.python_version()}<br>"
                f"Qt {QtCore.qVersion()}, PySide6 {PySide6.__version__}<br>"
                f"pyqtgraph {pyqtgraph.__version__}<br>numpy {np.__version__}</p>")

    def show_about(self) -> None:
        QtWidgets.QMessageBox.about(self, "About Orientation Lab", self.about_text())

    # ---- persistence ----------------------------------------------------------------------

    def save_settings(self) -> None:
        s = self.settings
        s.setValue("version", SETTINGS_VERSION)
        s.setValue("window/geometry", self.saveGeometry())
        s.setValue("window/state", self.saveState(SETTINGS_VERSION))
        s.setValue("window/central_splitter", self.central_splitter.saveState())
        s.setValue("window/views_splitter", self.views_splitter.saveState())
        s.setValue("plots/window_s", self.plots.window_s)
        s.setValue("filter/estimator", self.controls.estimator())
        for sensor, checkbox in self.controls.sensor_checkboxes.items():
            s.setValue(f"filter/sensor_{sensor}", checkbox.isChecked())
        s.setValue("view/uncertainty", self.controls.uncertainty_checkbox.isChecked())
        s.setValue("filter/comparisons", self.controls.comparisons_checkbox.isChecked())
        s.sync()

    def restore_settings(self) -> None:
        """Apply saved layout and switches; switch changes reach the engine as commands."""
        s = self.settings
        geometry = s.value("window/geometry")
        if geometry is not None:
            self.restoreGeometry(geometry)
        state = s.value("window/state")
        if state is not None:
            self.restoreState(state, SETTINGS_VERSION)
        for key, splitter in (("window/central_splitter", self.central_splitter),
                              ("window/views_splitter", self.views_splitter)):
            value = s.value(key)
            if value is not None:
                splitter.restoreState(value)
        window_s = s.value("plots/window_s")
        if window_s is not None:
            try:
                self.plots.set_window_s(float(window_s))
            except (TypeError, ValueError):
                pass
        estimator = s.value("filter/estimator")
        if isinstance(estimator, str):
            self.controls.set_estimator(estimator)
        for sensor, checkbox in self.controls.sensor_checkboxes.items():
            checkbox.setChecked(_to_bool(s.value(f"filter/sensor_{sensor}"), True))
        self.controls.uncertainty_checkbox.setChecked(_to_bool(s.value("view/uncertainty"), True))
        self.own_view.set_uncertainty_visible(self.controls.uncertainty_checkbox.isChecked())
        self.controls.comparisons_checkbox.setChecked(_to_bool(s.value("filter/comparisons"), True))

    # ---- shutdown -------------------------------------------------------------------------

    def shutdown(self) -> None:
        """Stop drawing and stop the engine's thread (idempotent)."""
        self.timer.stop()
        for view in (self.own_view, self.phone_view):
            view.release_gl()
        if not self._engine_stopped:
            self._engine_stopped = True
            self.engine.stop()

    def closeEvent(self, event: QtGui.QCloseEvent) -> None:  # noqa: N802 (Qt name)
        self.save_settings()
        self.shutdown()
        super().closeEvent(event)


def _set_text(label: QtWidgets.QLabel, text: str) -> None:
    """Change a label only when its text changes (setText re-lays out and repaints)."""
    if label.text() != text:
        label.setText(text)


class _PaintCounter(QtCore.QObject):
    """Event filter calling `on_paint()` for every paint event of the widgets it watches."""

    def __init__(self, on_paint) -> None:
        super().__init__()
        self._on_paint = on_paint

    def eventFilter(self, watched: QtCore.QObject, event: QtCore.QEvent) -> bool:  # noqa: N802
        if event.type() == QtCore.QEvent.Type.Paint:
            self._on_paint()
        return False
