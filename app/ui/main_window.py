"""The main window: workspaces in tabs (Live: OWN and PHONE in 3D, and YOURS when your own
filter is loaded, above three tabs of plots, and the transport bar; Calibrate; Tune;
Consistency), docks for the filter's lights and switches, the sensor-combination table, the
connection and your filter, menus that show their state.

The window owns no filter state. A QTimer at display rate takes the engine's latest
snapshot with `engine.poll()` (non-blocking) and hands its parts to the widgets; the widgets
send user intent back with `engine.send(command)`. The engine runs on its own thread, so
the frame rate does not depend on the sample rate and the filter never waits for drawing.

Per frame only what moves is drawn: the 3D views (each rendered once, only when its pose
changed), the lights and the plots. Tables, counters and the status bar are text that nobody
reads at 60 Hz: they follow the latest snapshot at PANEL_INTERVAL_S, and only labels whose
text changed are touched. The frame rate shown (and measured by benchmarks/gui_fps.py) counts
frames actually painted, not timer ticks.

Layout, geometry and view options persist (QSettings); named layouts can be saved and restored
(View → Layouts); the sensor switches and the estimator start at their defaults unless the user
chose View → "Remember my set-up". The first start is sized to the screen it opens on.

The window is put together from mixins, one responsibility each: window_menus.py (the menus and
their actions), window_status.py (the status bar, the slow panels, the frame count) and
window_persistence.py (the default layout, named layouts, QSettings).
"""

from __future__ import annotations

import math
import time
from collections import deque
from pathlib import Path
from typing import Any, Protocol

from PySide6 import QtCore, QtGui, QtWidgets

import ekf
from app.engine.commands import LoadUserFilter
from app.engine.config import ConfigError
from app.engine.tuning.profiles import ProfileStore
from app.engine.snapshot import SENSOR_NAMES, Snapshot, absent_sensors, absent_text
from app.ui.calibration import CalibrationWorkspace
from app.ui.connect_phone import ConnectPhoneDialog, PhoneAppsBox
from app.ui.connection import ConnectionPanel, connection_text
from app.ui.consistency import ConsistencyView
from app.ui.controls import ComparisonPanel, FilterPanel
from app.ui.failures import FailureDialog
from app.ui.layouts import LayoutStore
from app.ui.lights import LightsPanel
from app.ui.phone_view import PhoneView, software_gl
from app.ui.plots import PlotPanel
from app.ui.sessions import SessionControls
from app.ui.transport import TransportBar
from app.ui.tune_workspace import TuneWorkspace
from app.ui.user_filter_panel import UserFilterPanel
from app.ui.window_menus import WindowMenus
from app.ui.window_persistence import WindowPersistence
from app.ui.window_status import PaintCounter, WindowStatus

ORGANIZATION = "OrientationLab"
APPLICATION = "OrientationLab"
FRAME_INTERVAL_MS = 16          # ~60 Hz display rate (hardware OpenGL or no 3D)
# With software OpenGL every 3D frame is rasterised on the CPU next to the filter: 40 Hz keeps
# the motion smooth (>= 30 fps) at two thirds of the cost.
SOFTWARE_GL_FRAME_INTERVAL_MS = 25
PANEL_INTERVAL_S = 0.2          # tables, counters, status bar: 5 updates per second
NO_ORI_AFTER_MS = 2000          # samples but no ORI for this long: "no ORI in this stream"


class EngineLike(Protocol):
    """What the window needs from the engine (app.engine.Engine, or a test double)."""

    def poll(self) -> Snapshot | None: ...
    def send(self, command: Any) -> None: ...
    def start(self) -> None: ...
    def stop(self) -> None: ...


def default_settings() -> QtCore.QSettings:
    return QtCore.QSettings(ORGANIZATION, APPLICATION)


PREPARING_TEXT = "preparing the filter\n(the first start compiles it: about half a minute)"


def phone_no_data_text(snapshot: Snapshot) -> str:
    """Why PHONE has nothing to show: "" when it has an orientation."""
    if snapshot.phone_quat is not None:
        return ""
    if snapshot.preparing:
        return PREPARING_TEXT
    if (snapshot.t_ms is not None and snapshot.t0_ms is not None
            and snapshot.t_ms - snapshot.t0_ms >= NO_ORI_AFTER_MS):
        return "no ORI in this stream\n(the phone sends no orientation of its own)"
    return "waiting for data"


class MainWindow(WindowMenus, WindowPersistence, WindowStatus, QtWidgets.QMainWindow):
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
        tune_log: the session the Tune workspace re-filters (the replayed log, the demo);
            None: the user opens one there.
        profiles: where calibration and tuning profiles are kept (None: the data folder).
        engine_factory: path -> a new (unstarted) engine replaying it, for File → Open and
            drops (default: app.engine.config.open_replay with default settings).
        phone_factory: (app, where) -> a new (unstarted) engine on another phone app, for
            File → Connect a phone and the connection panel (None: they say it cannot).
    """

    def __init__(self, engine: EngineLike, settings: QtCore.QSettings | None = None,
                 use_gl: bool | None = None, frame_interval_ms: int | None = None,
                 log_path: Path | None = None, tune_log: str | Path | None = None,
                 profiles: ProfileStore | None = None, engine_factory=None,
                 phone_factory=None) -> None:
        super().__init__()
        self.engine = engine
        self._engine_factory = engine_factory
        self._phone_factory = phone_factory
        self.settings = settings if settings is not None else default_settings()
        self.failure_dialog = FailureDialog(self, log_path)
        self._failures_shown = 0
        self.last_snapshot: Snapshot | None = None
        self.ticks = 0                      # display ticks (timer callbacks)
        self.frames_painted = 0             # ticks whose changes reached the screen
        self.snapshots_received = 0
        self._engine_stopped = False
        self._last_warning = ""
        self._frame_times: deque[float] = deque()
        self._painted_tick = -1
        self._panel_snapshot: Snapshot | None = None   # not yet shown in the slow panels
        self._absent: frozenset[str] = frozenset()     # sensors not in this stream
        self._panels_shown_at = -math.inf
        self._linking_cameras = False
        self.filter_settings = ekf.PRESETS["default"]   # what the filter runs with (status)
        self.configuration = None                       # the engine's (a ConfigurationView)
        self._user_history = None                       # the YOURS re-run last drawn
        self.profiles = profiles or ProfileStore()

        self.setWindowTitle("Orientation Lab")
        self.setObjectName("main_window")
        self.setDockOptions(QtWidgets.QMainWindow.DockOption.AnimatedDocks
                            | QtWidgets.QMainWindow.DockOption.AllowNestedDocks
                            | QtWidgets.QMainWindow.DockOption.AllowTabbedDocks)
        self._build_live_workspace(use_gl)
        self.workspaces = QtWidgets.QTabWidget()
        self.workspaces.setObjectName("workspaces")
        self.workspaces.setDocumentMode(True)
        self.add_workspace(self.live_workspace, "Live / Replay")
        self._build_tool_workspaces(use_gl, tune_log)
        central = QtWidgets.QWidget()
        central.setObjectName("central")
        box = QtWidgets.QVBoxLayout(central)
        box.setContentsMargins(0, 0, 0, 0)
        box.setSpacing(2)
        box.addWidget(self.workspaces, 1)
        box.addWidget(self.transport)   # below every workspace: the replay and REC always there
        self.setCentralWidget(central)
        self._build_docks()
        self._build_status_bar()
        self.sessions = SessionControls(self, self._engine_factory)
        self._build_actions()
        self.setAcceptDrops(True)
        self.layouts = LayoutStore(self.settings)
        self.restore_settings()

        self._frame_filter = PaintCounter(self._on_paint)
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

    def _build_live_workspace(self, use_gl: bool | None) -> None:
        self.own_view = PhoneView("OWN", use_gl=use_gl)
        self.phone_view = PhoneView("PHONE", use_gl=use_gl)
        self.user_view = PhoneView("YOURS", use_gl=use_gl)
        self.user_view.setVisible(False)        # shown while your filter is loaded
        self.plots = PlotPanel()
        self.transport = TransportBar(self.send)
        self.views_splitter = QtWidgets.QSplitter(QtCore.Qt.Orientation.Horizontal)
        self.views_splitter.setObjectName("views_splitter")
        self.views_splitter.addWidget(self.own_view)
        self.views_splitter.addWidget(self.phone_view)
        self.views_splitter.addWidget(self.user_view)
        self.central_splitter = QtWidgets.QSplitter(QtCore.Qt.Orientation.Vertical)
        self.central_splitter.setObjectName("central_splitter")
        self.central_splitter.setChildrenCollapsible(False)
        self.central_splitter.addWidget(self.views_splitter)
        self.central_splitter.addWidget(self.plots)
        self.central_splitter.setStretchFactor(0, 4)
        self.central_splitter.setStretchFactor(1, 6)
        self.live_workspace = QtWidgets.QWidget()
        self.live_workspace.setObjectName("live_workspace")
        box = QtWidgets.QVBoxLayout(self.live_workspace)
        box.setContentsMargins(0, 0, 0, 0)
        box.setSpacing(2)
        box.addWidget(self.central_splitter, 1)
        for view in self.views():
            view.camera_changed.connect(lambda v=view: self._on_camera_changed(v))
        self.transport.navigated.connect(self.plots.follow)    # a seek or Play: follow again

    def _build_tool_workspaces(self, use_gl: bool | None, tune_log: str | Path | None) -> None:
        """Calibrate (task 2, Allan, magnetometer), Tune (settings, A/B re-filter, auto-tune)
        and Consistency (innovations): each draws and sends through the window's send."""
        settings = lambda: self.filter_settings   # noqa: E731 (read when used)
        self.calibration = CalibrationWorkspace(self.send, settings, store=self.profiles,
                                                use_gl=self.own_view.gl_view is not None)
        self.tune = TuneWorkspace(self.send, settings, log=tune_log, store=self.profiles)
        self.consistency = ConsistencyView(self.send)
        self.add_workspace(self.calibration, "Calibrate")
        self.add_workspace(self.tune, "Tune")
        self.add_workspace(self.consistency, "Consistency")

    def views(self) -> tuple[PhoneView, ...]:
        """The 3D views: OWN, PHONE, YOURS (hidden while no filter of yours is loaded)."""
        return (self.own_view, self.phone_view, self.user_view)

    def add_workspace(self, widget: QtWidgets.QWidget, title: str) -> int:
        """A workspace tab (Live / Replay; later calibration, tuning, consistency)."""
        index = self.workspaces.addTab(widget, title)
        self.workspaces.tabBar().setVisible(self.workspaces.count() > 1)
        return index

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
        dock.setMinimumWidth(330)
        self.addDockWidget(QtCore.Qt.DockWidgetArea.RightDockWidgetArea, dock)
        return dock

    def _build_docks(self) -> None:
        self.lights = LightsPanel()
        self.controls = FilterPanel(self.send)
        self.comparison = ComparisonPanel(self.send)
        self.connection = ConnectionPanel(self.send, PhoneAppsBox(self.connect_phone,
                                                                  self.show_connect_dialog))
        filter_widget = QtWidgets.QWidget()
        filter_layout = QtWidgets.QVBoxLayout(filter_widget)
        filter_layout.setContentsMargins(4, 2, 4, 2)
        filter_layout.setSpacing(2)
        filter_layout.addWidget(self.lights)
        filter_layout.addWidget(self.controls)
        filter_layout.addStretch(1)
        self.filter_dock = self._add_dock("Filter", "filter_dock", filter_widget)
        # never narrower than its switches and buttons need: without a sideways scroll bar the
        # panel would be cut at the right
        scroll = self.filter_dock.widget()
        self.filter_dock.setMinimumWidth(max(330, min(
            420, filter_widget.minimumSizeHint().width()
            + scroll.verticalScrollBar().sizeHint().width() + 2 * scroll.frameWidth())))
        self.comparison_dock = self._add_dock("Sensor combinations", "comparison_dock",
                                              self.comparison)
        self.connection_dock = self._add_dock("Connection", "connection_dock", self.connection)
        self.user_panel = UserFilterPanel(self.send, settings=self.settings)
        self.user_dock = self._add_dock("Your filter", "user_dock", self.user_panel)
        self.controls.uncertainty_toggled.connect(self.own_view.set_uncertainty_visible)
        self.controls.sensor_toggled.connect(self._on_sensor_toggled)
        self.controls.estimator_changed.connect(self._on_estimator_changed)

    def docks(self) -> tuple[QtWidgets.QDockWidget, ...]:
        return (self.filter_dock, self.comparison_dock, self.connection_dock, self.user_dock)

    # ---- engine --------------------------------------------------------------------------

    def send(self, command: Any) -> None:
        """Forward one command to the engine (applied between two batches of samples). What it
        changes comes back with the engine's snapshots (apply_snapshot)."""
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
        has_data = bool(snapshot.status.initialised)
        if has_data:
            self.own_view.set_orientation(snapshot.own_quat, snapshot.own_cov)
        else:
            self.own_view.set_no_data(PREPARING_TEXT if snapshot.preparing
                                      else "waiting for data")
            self.own_view.set_orientation(None)
        phone_text = phone_no_data_text(snapshot)
        if phone_text:
            self.phone_view.set_no_data(phone_text)
        self.phone_view.set_orientation(snapshot.phone_quat)
        self.lights.update_status(snapshot.status, has_data)
        self.controls.update_status(snapshot.status)
        self._show_absent(absent_sensors(snapshot))
        self._apply_configuration(snapshot)
        self._apply_user(snapshot)
        self.calibration.feed(snapshot)
        self.consistency.apply_snapshot(snapshot)
        self.plots.append(snapshot.plot, snapshot.status.sensors_enabled)
        self.plots.set_status(snapshot.status)
        self.plots.set_time_origin(snapshot.t0_ms)
        replay = snapshot.replay
        self.transport.update_replay(replay, replay.get("name", "") if replay
                                     else connection_text(snapshot.health))
        self.transport.update_markers(snapshot.markers)
        self.transport.update_recording(snapshot.recording)
        self.plots.set_session(snapshot.session_plot if replay else None)
        if snapshot.t_ms is not None and snapshot.t0_ms is not None:
            self.plots.set_position((snapshot.t_ms - snapshot.t0_ms) / 1000.0)
        self.plots.set_markers(snapshot.markers)
        self.sessions.follow(snapshot)
        self._panel_snapshot = snapshot
        if snapshot.failures and snapshot.failures[-1].number > self._failures_shown:
            latest = snapshot.failures[-1]
            self._failures_shown = latest.number
            self.failure_dialog.show_failure(latest, latest.number)
            self.statusBar().showMessage(f"engine error: {latest.message}", 15000)

    def _apply_configuration(self, snapshot: Snapshot) -> None:
        """The engine's configuration and the settings it runs now, when the snapshot carries
        new ones: everywhere (Calibrate and Tune start from them, Tune re-runs its session with
        the configuration, the Filter dock says what of a replayed recording is yours)."""
        running = snapshot.status.settings
        configuration = snapshot.configuration
        changed = configuration is not self.configuration
        if running is not None and running is not self.filter_settings:
            self.filter_settings = running
            changed = True
        if changed:
            self.configuration = configuration
            self.tune.configuration_changed(configuration, running)
            self.controls.show_configuration(configuration)
            self.fit_filter_dock()               # the replay's line: room for it
            self.follow_recording_action.setEnabled(bool(configuration and configuration.yours
                                                         and configuration.replaying))

    def _show_absent(self, absent: frozenset[str]) -> None:
        """Sensors the stream does not deliver: "no gyroscope in this stream" on their switches
        (greyed out, the tick kept; their menu entries too), over their plots and in the
        combination rows that use them (at the next refresh_panels)."""
        if absent == self._absent:
            return
        self._absent = absent
        self.controls.set_absent(absent)
        self.fit_filter_dock()                   # the note under the switches: room for it
        for sensor, action in self.sensor_actions.items():
            action.setEnabled(sensor not in absent)
            action.setToolTip(absent_text(sensor) if sensor in absent else action.text())
        for sensor in SENSOR_NAMES:
            self.plots.set_no_data(sensor, absent_text(sensor) if sensor in absent else "")
        self._panels_shown_at = -math.inf        # the table at the next tick

    def _apply_user(self, snapshot: Snapshot) -> None:
        """YOURS: its 3D view, its curves (a re-run's history replaces them), its panel."""
        user = snapshot.user
        present = user is not None
        if present != self.user_view.isVisible():
            self.user_view.setVisible(present)
        if present != self.plots.user_present:
            self.plots.set_user_present(present)
        if not present:
            self._user_history = None
            return
        if user.quat is not None:
            self.user_view.set_orientation(user.quat, user.cov)
        else:
            self.user_view.set_no_data(user.state if user.state != "running"
                                       else "waiting for data")
            self.user_view.set_orientation(None)
        history = user.history
        if history is not None and history is not self._user_history:
            self._user_history = history
            t0 = snapshot.t0_ms if snapshot.t0_ms is not None else 0
            self.plots.replace_user_history((history.t_ms - t0) / 1000.0, history.euler_deg,
                                            (history.t_err_ms - t0) / 1000.0, history.error_deg)

    # ---- sessions ---------------------------------------------------------------------------

    def connect_phone(self, app: str, where: str) -> bool:
        """Switch to another phone app (see connect_phone.py); a one-line message when it
        cannot be."""
        if self._phone_factory is None:
            QtWidgets.QMessageBox.warning(self, "Cannot connect", "this window cannot switch "
                                          "its source")
            return False
        try:
            engine = self._phone_factory(app, where)
        except ConfigError as error:
            QtWidgets.QMessageBox.warning(self, "Cannot connect", str(error))
            return False
        self.swap_engine(engine)
        hint = engine.source.connect_hint()
        self.statusBar().showMessage(hint, 10000)
        return True

    def show_connect_dialog(self) -> None:
        """File → Connect a phone…: the steps per app, phyphox's QR code."""
        dialog = ConnectPhoneDialog(self.connect_phone, self)
        dialog.setAttribute(QtCore.Qt.WidgetAttribute.WA_DeleteOnClose)
        dialog.resize(860, 560)
        dialog.show()
        self.connect_dialog = dialog

    def swap_engine(self, engine: EngineLike) -> None:
        """Replace the engine (File → Open, a drop): the old one stops (its recording is
        saved), the plots start afresh, the new one starts."""
        yours = self.last_snapshot.user if self.last_snapshot is not None else None
        old, self.engine = self.engine, engine
        old.stop()
        self.plots.set_session(None)
        self.plots.clear()
        self.plots.follow()
        self._show_absent(frozenset())
        self.last_snapshot = None
        self._failures_shown = 0
        try:
            engine.start()
        except OSError as error:
            self.sessions._complain("Cannot open", f"cannot start the source: "
                                                   f"{error.strerror or error}")
        if yours is not None and yours.path:
            engine.send(LoadUserFilter(yours.path))     # your filter goes on with the new one
        source = getattr(engine, "source", None)
        self.tune.use_session(getattr(source, "path", None))
        name = getattr(source, "name", "")
        self.setWindowTitle(f"Orientation Lab — {name}" if name else "Orientation Lab")

    def dragEnterEvent(self, event: QtGui.QDragEnterEvent) -> None:  # noqa: N802 (Qt name)
        if self.sessions.drop_paths(event.mimeData()):
            event.acceptProposedAction()

    def dropEvent(self, event: QtGui.QDropEvent) -> None:  # noqa: N802 (Qt name)
        paths = self.sessions.drop_paths(event.mimeData())
        if paths:
            event.acceptProposedAction()
            self.sessions.open(paths[0])

    # ---- shutdown -------------------------------------------------------------------------

    def shutdown(self) -> None:
        """Stop drawing and stop the engine's thread (idempotent)."""
        self.timer.stop()
        self.tune.close_runs()
        for view in self.views():
            view.release_gl()
        if not self._engine_stopped:
            self._engine_stopped = True
            self.engine.stop()

    def closeEvent(self, event: QtGui.QCloseEvent) -> None:  # noqa: N802 (Qt name)
        self.save_settings()
        self.shutdown()
        super().closeEvent(event)
