"""The main window: workspaces in tabs (Live: OWN and PHONE in 3D, and YOURS when your own
filter is loaded, above three tabs of plots, and the transport bar; Calibrate; Tune;
Consistency), docks for the filter's lights and switches, the sensor-combination table, the
connection and your filter, menus that show their state (File: sessions, your filter; View:
plots, 3D cameras, layouts, docks; Replay, and back to the recording; Filter: reset, align,
sensors, estimator; Help), the status bar, and the dialog that shows an engine failure.

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
(View → Layouts, kept by a LayoutStore); the sensor switches and the estimator start at their
defaults unless the user chose View → "Remember my set-up". The first start is sized to the
screen it opens on.
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

import ekf
from app import __version__
from app.engine.commands import LoadUserFilter, SetFollowTimeline, UnloadUserFilter
from app.engine.config import ConfigError
from app.engine.tuning.profiles import ProfileStore
from app.engine.errors import EngineFailure
from app.engine.snapshot import SENSOR_NAMES, Snapshot, absent_sensors, absent_text
from app.stream.protocol import FILTER_TAGS
from app.ui.calibration import CalibrationWorkspace
from app.ui.connection import ConnectionPanel, ConnectPhoneDialog, PhoneAppsBox, connection_text
from app.ui.consistency import ConsistencyView
from app.ui.controls import ESTIMATOR_CHOICES, SENSOR_LABELS, ComparisonPanel, FilterPanel
from app.ui.elided import ElidingStatusBar
from app.ui.lights import LightsPanel
from app.ui.phone_view import PhoneView, software_gl
from app.ui.plots import PlotPanel
from app.ui.sessions import SessionControls
from app.ui.transport import TransportBar
from app.ui.tuning import TuneWorkspace
from app.ui.user_filter_panel import (UserFilterPanel, load_filter_dialog, new_filter_dialog,
                                      new_matlab_filter_dialog)

ORGANIZATION = "OrientationLab"
APPLICATION = "OrientationLab"
FRAME_INTERVAL_MS = 16          # ~60 Hz display rate (hardware OpenGL or no 3D)
# With software OpenGL every 3D frame is rasterised on the CPU next to the filter: 40 Hz keeps
# the motion smooth (>= 30 fps) at two thirds of the cost.
SOFTWARE_GL_FRAME_INTERVAL_MS = 25
PANEL_INTERVAL_S = 0.2          # tables, counters, status bar: 5 updates per second
NO_ORI_AFTER_MS = 2000          # samples but no ORI for this long: "no ORI in this stream"
SETTINGS_VERSION = 2
FIT_ATTEMPTS = 4
DEFAULT_SIZE = (1600, 1000)     # the first start: this, or 92 % of a smaller screen
# QMainWindow.saveState's version of a layout: a state from another layout is ignored
LAYOUT_VERSION = 2


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
        self._filter_dock_fitted = False     # fitted at the first show
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

    def _build_status_bar(self) -> None:
        bar = ElidingStatusBar()
        self.setStatusBar(bar)
        self.state_status = QtWidgets.QLabel("waiting")
        self.time_status = QtWidgets.QLabel("t = –")
        self.rates_status = QtWidgets.QLabel("")
        self.fps_status = QtWidgets.QLabel("")
        # the texts that change every refresh keep the width of their widest value, so the
        # status bar's layout does not jump (nor cut the last one) as they change
        metrics = self.fps_status.fontMetrics()
        self.fps_status.setMinimumWidth(metrics.horizontalAdvance("888 fps") + 4)
        self.time_status.setMinimumWidth(metrics.horizontalAdvance("t = 8888.8 s") + 4)
        for label in (self.state_status, self.time_status, self.rates_status, self.fps_status):
            bar.addPermanentWidget(label)

    # ---- menus ----------------------------------------------------------------------------

    def add_action(self, menu: QtWidgets.QMenu, text: str, shortcut: str | None, slot,
                   checkable: bool = False, checked: bool = False) -> QtGui.QAction:
        """An action in `menu` and on the window (its shortcut works whichever panel has
        focus), calling `slot` when triggered."""
        action = QtGui.QAction(text, self)
        if shortcut is not None:
            action.setShortcut(QtGui.QKeySequence(shortcut))
            # Window-wide, so the shortcut works whichever panel has focus.
            action.setShortcutContext(QtCore.Qt.ShortcutContext.WindowShortcut)
        action.setCheckable(checkable)
        if checkable:
            action.setChecked(checked)
        action.triggered.connect(slot)
        menu.addAction(action)
        self.addAction(action)
        return action

    def _build_actions(self) -> None:
        menus = self.menuBar()
        self.file_menu = menus.addMenu("&File")
        self.connect_action = self.add_action(self.file_menu, "&Connect a phone…", None,
                                              self.show_connect_dialog)
        self.sessions.build_file_menu(self.file_menu)
        self.load_filter_action = self.add_action(
            self.file_menu, "&Load your filter…", None, lambda: load_filter_dialog(self, self.send))
        self.new_filter_action = self.add_action(
            self.file_menu, "&New filter from the course template…", None,
            lambda: new_filter_dialog(self, self.send))
        self.new_matlab_filter_action = self.add_action(
            self.file_menu, "New &MATLAB filter from the course's functions…", None,
            lambda: new_matlab_filter_dialog(self, self.send))
        self.unload_filter_action = self.add_action(self.file_menu, "&Unload your filter", None,
                                                    lambda: self.send(UnloadUserFilter()))
        self.file_menu.addSeparator()
        self.quit_action = self.add_action(self.file_menu, "&Quit", "Ctrl+Q", self.close)
        self._build_view_menu(menus.addMenu("&View"))
        self.replay_menu = menus.addMenu("&Replay")
        self.replay_menu.addAction(self.pause_action)
        self.sessions.build_replay_menu(self.replay_menu)
        self.replay_menu.addSeparator()
        self.follow_recording_action = self.add_action(
            self.replay_menu, "&Back to the recording", None,
            lambda: self.send(SetFollowTimeline(True)))
        self.follow_recording_action.setToolTip("Replay the recorded switches, estimator, "
                                                "settings and combinations again")
        self.follow_recording_action.setEnabled(False)
        self._build_filter_menu(menus.addMenu("F&ilter"))
        help_menu = menus.addMenu("&Help")
        self.about_action = self.add_action(help_menu, "&About", "F1", self.show_about)

    def _build_view_menu(self, menu: QtWidgets.QMenu) -> None:
        self.view_menu = menu
        self.pause_action = self.add_action(menu, "&Pause / follow (replay: play / pause)", "Space",
                                            self.toggle_pause)
        self.clear_action = self.add_action(menu, "&Clear plots", "Ctrl+L", self.clear_plots)
        self.unwrap_action = self.add_action(menu, "&Unwrap Euler angles", None,
                                             self.plots.set_unwrapped, checkable=True)
        self.plots.unwrap_checkbox.toggled.connect(self.unwrap_action.setChecked)
        menu.addSeparator()
        self.link_cameras_action = self.add_action(menu, "&Link 3D cameras", None,
                                                   self.set_cameras_linked, checkable=True)
        self.add_action(menu, "Reset 3D &views", None, self.reset_cameras)
        menu.addSeparator()
        self.layouts_menu = menu.addMenu("&Layouts")
        self.layouts_menu.aboutToShow.connect(self._fill_layouts_menu)
        self.add_action(menu, "&Reset to defaults", None, self.reset_to_defaults)
        self.remember_action = self.add_action(menu, "Re&member my set-up (sensors, estimator)",
                                               None, self._on_remember_toggled, checkable=True)
        menu.addSeparator()
        for dock in self.docks():
            menu.addAction(dock.toggleViewAction())

    def _build_filter_menu(self, menu: QtWidgets.QMenu) -> None:
        self.reset_action = self.add_action(menu, "&Reset filter", "Ctrl+R",
                                            self._reset_filter)
        self.align_action = self.add_action(menu, "&Align heading with PHONE", "Ctrl+H",
                                            self._align_heading)
        menu.addSeparator()
        self.sensor_actions: dict[str, QtGui.QAction] = {}
        for number, (sensor, label) in enumerate(SENSOR_LABELS, start=1):
            self.sensor_actions[sensor] = self.add_action(
                menu, label, f"Ctrl+{number}",
                lambda checked, s=sensor: self.controls.set_sensor(s, checked),
                checkable=True, checked=True)
        menu.addSeparator()
        estimator_menu = menu.addMenu("&Estimator (OWN)")
        self.estimator_group = QtGui.QActionGroup(self)
        self.estimator_actions: dict[str, QtGui.QAction] = {}
        for name, label in ESTIMATOR_CHOICES:
            action = self.add_action(estimator_menu, label, None,
                                     lambda checked, n=name: self.controls.set_estimator(n),
                                     checkable=True, checked=name == "ekf")
            self.estimator_group.addAction(action)
            self.estimator_actions[name] = action

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

    # ---- the slow panels and the status bar ------------------------------------------------

    def refresh_panels(self) -> None:
        """Show the latest snapshot in the comparison table, connection panel and status bar
        (called from tick() at most every PANEL_INTERVAL_S)."""
        snapshot = self._panel_snapshot
        self._panel_snapshot = None
        self._panels_shown_at = time.monotonic()
        _set_text(self.fps_status, f"{self.frames_per_second():.0f} fps")
        if snapshot is None:
            return
        self.comparison.update_comparisons(snapshot.comparisons, snapshot.comparison_estimator,
                                           self._absent)
        self.connection.update_health(snapshot.health)
        self.user_panel.update_status(snapshot.user)
        self._update_status_bar(snapshot)

    def _update_status_bar(self, snapshot: Snapshot) -> None:
        health = snapshot.health
        _set_text(self.state_status, connection_text(health))
        if snapshot.t_ms is None or snapshot.t0_ms is None:
            _set_text(self.time_status, "t = –")
        else:
            _set_text(self.time_status, f"t = {(snapshot.t_ms - snapshot.t0_ms) / 1000.0:.1f} s")
            self.time_status.setToolTip(f"time since the session's start; the phone's clock: "
                                        f"{snapshot.t_ms / 1000.0:.3f} s")
        _set_text(self.rates_status, "  ".join(f"{tag} {rate:.0f} Hz"
                                               for tag, rate in sorted(health.rates_hz.items())
                                               if tag in FILTER_TAGS and rate > 0))
        if health.warnings and health.warnings[-1] != self._last_warning:
            self._last_warning = health.warnings[-1]
            self.statusBar().showMessage(self._last_warning, 8000)

    # ---- frame counting -------------------------------------------------------------------

    def _drawn_widgets(self) -> list[QtWidgets.QWidget]:
        """The widgets that change every frame: their paint events are the frames."""
        widgets = [group.graphics.viewport() for group in self.plots.groups.values()]
        for view in self.views():
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

    def clear_plots(self) -> None:
        """Ctrl+L: forget the plotted samples, and say so (the filter goes on)."""
        self.plots.clear()
        self.statusBar().showMessage("plots cleared: the filter goes on; new samples are "
                                     "plotted from now", 4000)

    def toggle_pause(self) -> None:
        """Space: play/pause a replay; otherwise pause/follow the plots."""
        if self.transport.replaying:
            self.transport.toggle_paused()
        else:
            self.plots.toggle_paused()
            self.statusBar().showMessage("plots paused: drag to look back, Space or Follow "
                                         "to follow again" if self.plots.paused
                                         else "plots follow the newest samples", 4000)

    def _reset_filter(self) -> None:
        self.controls.reset_button.click()
        self.statusBar().showMessage("filter reset: it starts again from the next samples", 4000)

    def _align_heading(self) -> None:
        self.controls.align_button.click()
        self.statusBar().showMessage("aligning OWN's heading with PHONE's…", 4000)

    def _on_sensor_toggled(self, sensor: str, enabled: bool) -> None:
        action = self.sensor_actions[sensor]
        if action.isChecked() != enabled:
            action.setChecked(enabled)
        label = dict(SENSOR_LABELS)[sensor].lower()
        self.statusBar().showMessage(f"{label} {'in' if enabled else 'out of'} the filter", 3000)

    def _on_estimator_changed(self, name: str) -> None:
        action = self.estimator_actions.get(name)
        if action is not None and not action.isChecked():
            action.setChecked(True)
        self.statusBar().showMessage(f"OWN is now: {dict(ESTIMATOR_CHOICES).get(name, name)}",
                                     3000)

    def set_cameras_linked(self, linked: bool) -> None:
        if self.link_cameras_action.isChecked() != bool(linked):
            self.link_cameras_action.setChecked(bool(linked))
        if linked:
            for other in (self.phone_view, self.user_view):
                other.set_camera(self.own_view.camera())
        self.statusBar().showMessage("3D cameras linked: turning one turns both" if linked
                                     else "3D cameras move on their own", 3000)

    def _on_camera_changed(self, view: PhoneView) -> None:
        if not self.link_cameras_action.isChecked() or self._linking_cameras:
            return
        self._linking_cameras = True
        try:
            for other in self.views():
                if other is not view:
                    other.set_camera(view.camera())
        finally:
            self._linking_cameras = False

    def reset_cameras(self) -> None:
        for view in self.views():
            view.reset_camera()

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

    # ---- layout ----------------------------------------------------------------------------

    def arrange_default_layout(self) -> None:
        """The docks on the right: Filter above, the table and the connection below, tabbed
        together on screens too short to stack all three; the views above the plots."""
        for dock in self.docks():
            dock.setFloating(False)
            dock.show()
            self.addDockWidget(QtCore.Qt.DockWidgetArea.RightDockWidgetArea, dock)
        height = self.height()
        if height < 950:
            self.tabifyDockWidget(self.comparison_dock, self.connection_dock)
            self.tabifyDockWidget(self.connection_dock, self.user_dock)
            self.comparison_dock.raise_()
        else:
            self.splitDockWidget(self.comparison_dock, self.connection_dock,
                                 QtCore.Qt.Orientation.Vertical)
            self.tabifyDockWidget(self.connection_dock, self.user_dock)
            self.connection_dock.raise_()
        self.resizeDocks([self.filter_dock], [max(340, self.filter_dock.minimumWidth(),
                                                  int(self.width() * 0.24))],
                         QtCore.Qt.Orientation.Horizontal)
        self.central_splitter.setSizes([int(height * 0.36), int(height * 0.64)])
        self.views_splitter.setSizes([1, 1, 1])
        self.fit_filter_dock()
        self.hide_stray_tab_bars()
        QtCore.QTimer.singleShot(0, self.hide_stray_tab_bars)     # once laid out

    def hide_stray_tab_bars(self) -> None:
        """Hide the tab bars of tab groups an earlier arrangement made and this one undid (Qt
        leaves them on screen, e.g. "Sensor combinations | Connection" after a 1280x720 layout
        is arranged again at 1920x1080): each group keeps the one bar right below its docks."""
        groups: dict[frozenset, list[QtWidgets.QDockWidget]] = {}
        for dock in self.docks():
            if self.tabifiedDockWidgets(dock):
                group = [dock, *self.tabifiedDockWidgets(dock)]
                groups[frozenset(member.windowTitle() for member in group)] = group
        bars: dict[frozenset, list[QtWidgets.QTabBar]] = {}
        for bar in self.findChildren(QtWidgets.QTabBar):
            if bar.parentWidget() is self and bar.isVisible():
                texts = frozenset(bar.tabText(i) for i in range(bar.count()))
                bars.setdefault(texts, []).append(bar)
        for texts, found in bars.items():
            group = groups.get(texts)
            if group is None:
                for bar in found:
                    bar.hide()
                continue
            shown = [dock.geometry() for dock in group
                     if dock.geometry().intersects(self.rect())] or [self.rect()]
            place = shown[0]

            def distance(bar: QtWidgets.QTabBar) -> int:
                where = bar.geometry()
                return (abs(where.top() - place.bottom() - 1) + abs(where.left() - place.left())
                        + abs(where.width() - place.width()))
            found.sort(key=distance)
            for bar in found[1:]:
                bar.hide()

    def fit_filter_dock(self) -> None:
        """The Filter dock as tall as its lights, switches and buttons (it does not scroll in
        the default layout); the docks below it give up the room, never below their own
        minimum."""
        QtCore.QTimer.singleShot(0, self._fit_filter_dock_now)    # once laid out

    def _fit_filter_dock_now(self, attempt: int = 0) -> None:
        dock = self.filter_dock
        if dock.isFloating() or not dock.isVisible():
            return              # (the window's first show fits it)
        scroll = dock.widget()
        missing = scroll.widget().sizeHint().height() - scroll.viewport().height()
        if missing > 0 and attempt < FIT_ATTEMPTS:
            # the dock right below gives up the room (resizeDocks with one dock shares the
            # change among its neighbours and leaves a few pixels short); ask again until the
            # dock has the room or its neighbour is at its minimum
            top = dock.geometry().top()
            below = [other for other in self.docks() if other is not dock
                     and not other.isFloating() and other.geometry().intersects(self.rect())
                     and other.geometry().top() > top]
            if below:
                neighbour = min(below, key=lambda other: other.geometry().top())
                self.resizeDocks([dock, neighbour],
                                 [dock.height() + missing,
                                  max(neighbour.minimumSizeHint().height(),
                                      neighbour.height() - missing)],
                                 QtCore.Qt.Orientation.Vertical)
            else:
                self.resizeDocks([dock], [dock.height() + missing],
                                 QtCore.Qt.Orientation.Vertical)
            QtCore.QTimer.singleShot(0, lambda: self._fit_filter_dock_now(attempt + 1))

    def showEvent(self, event: QtGui.QShowEvent) -> None:  # noqa: N802 (Qt name)
        super().showEvent(event)
        if not self._filter_dock_fitted:
            self._filter_dock_fitted = True
            self.fit_filter_dock()

    # ---- layouts and persistence ----------------------------------------------------------

    def _fill_layouts_menu(self) -> None:
        menu = self.layouts_menu
        menu.clear()
        menu.addAction("Save current layout as…", self.save_layout_as)
        names = self.layouts.names()
        if names:
            menu.addSeparator()
            for name in names:
                menu.addAction(name, lambda n=name: self.apply_layout(n))
            delete = menu.addMenu("Delete")
            for name in names:
                delete.addAction(name, lambda n=name: self.delete_layout(n))

    def save_layout_as(self, name: str | None = None) -> None:
        if name is None:
            name, ok = QtWidgets.QInputDialog.getText(self, "Save layout", "Layout name:")
            if not ok:
                return
        name = name.strip()
        if not name:
            return
        self.layouts.save(name, self)
        self.statusBar().showMessage(f"layout '{name}' saved", 3000)

    def apply_layout(self, name: str) -> None:
        if self.layouts.apply(name, self):
            self.statusBar().showMessage(f"layout '{name}'", 3000)

    def delete_layout(self, name: str) -> None:
        self.layouts.delete(name)
        self.statusBar().showMessage(f"layout '{name}' deleted", 3000)

    def reset_to_defaults(self) -> None:
        """Default layout, view options, switches and estimator (saved layouts stay)."""
        self.arrange_default_layout()
        self.plots.set_window_s(10.0)
        self.plots.set_unwrapped(False)
        self.plots.set_current_group("sensors")
        self.set_cameras_linked(False)
        self.reset_cameras()
        self.controls.uncertainty_checkbox.setChecked(True)
        for sensor in self.controls.sensor_checkboxes:
            self.controls.set_sensor(sensor, True)
        self.controls.set_estimator("ekf")
        self.statusBar().showMessage("layout and switches back to their defaults", 4000)

    def _on_remember_toggled(self, remember: bool) -> None:
        self.settings.setValue("setup/remember", bool(remember))
        self.statusBar().showMessage(
            "sensor switches and estimator will be restored at the next start" if remember
            else "the next start begins with all sensors and the default EKF", 4000)

    def size_to_screen(self) -> None:
        """The first start: DEFAULT_SIZE, or 92 % of a smaller screen, centred on it."""
        screen = self.screen() or QtGui.QGuiApplication.primaryScreen()
        if screen is None:
            self.resize(*DEFAULT_SIZE)
            return
        available = screen.availableGeometry()
        width = min(DEFAULT_SIZE[0], int(available.width() * 0.92))
        height = min(DEFAULT_SIZE[1], int(available.height() * 0.92))
        self.resize(width, height)
        self.move(available.x() + (available.width() - width) // 2,
                  available.y() + (available.height() - height) // 2)

    def save_settings(self) -> None:
        s = self.settings
        s.setValue("version", SETTINGS_VERSION)
        s.setValue("window/geometry", self.saveGeometry())
        self.layouts.write_current(s, self, "window")
        s.setValue("plots/window_s", self.plots.window_s)
        s.setValue("view/uncertainty", self.controls.uncertainty_checkbox.isChecked())
        s.setValue("view/link_cameras", self.link_cameras_action.isChecked())
        s.setValue("view/unwrapped", self.plots.unwrapped)
        s.setValue("setup/remember", self.remember_action.isChecked())
        s.setValue("filter/estimator", self.controls.estimator())
        for sensor, checkbox in self.controls.sensor_checkboxes.items():
            s.setValue(f"filter/sensor_{sensor}", checkbox.isChecked())
        s.setValue("filter/comparisons", self.comparison.comparisons_checkbox.isChecked())
        s.setValue("filter/comparison_estimator", self.comparison.estimator())
        s.sync()

    def restore_settings(self) -> None:
        """Apply saved geometry, layout and view options; the switches and the estimator only
        when the user chose "Remember my set-up" (their changes reach the engine as
        commands)."""
        s = self.settings
        geometry = s.value("window/geometry")
        if geometry is None or not self.restoreGeometry(geometry):
            self.size_to_screen()
        self.arrange_default_layout()
        if _to_bool(s.value("version"), False):
            self.layouts.read_current(s, self, "window")
        window_s = s.value("plots/window_s")
        if window_s is not None:
            try:
                self.plots.set_window_s(float(window_s))
            except (TypeError, ValueError):
                pass
        self.controls.uncertainty_checkbox.setChecked(_to_bool(s.value("view/uncertainty"), True))
        self.own_view.set_uncertainty_visible(self.controls.uncertainty_checkbox.isChecked())
        self.link_cameras_action.setChecked(_to_bool(s.value("view/link_cameras"), False))
        self.plots.set_unwrapped(_to_bool(s.value("view/unwrapped"), False))
        remember = _to_bool(s.value("setup/remember"), False)
        self.remember_action.setChecked(remember)
        if not remember:
            return
        estimator = s.value("filter/estimator")
        if isinstance(estimator, str):
            self.controls.set_estimator(estimator)
        for sensor, checkbox in self.controls.sensor_checkboxes.items():
            checkbox.setChecked(_to_bool(s.value(f"filter/sensor_{sensor}"), True))
        self.comparison.comparisons_checkbox.setChecked(
            _to_bool(s.value("filter/comparisons"), True))
        comparison_estimator = s.value("filter/comparison_estimator")
        if isinstance(comparison_estimator, str):
            index = self.comparison.estimator_combo.findData(comparison_estimator)
            if index >= 0:
                self.comparison.estimator_combo.setCurrentIndex(index)

    # ---- sessions --------------------------------------------------------------------------

    def connect_phone(self, app: str, where: str) -> bool:
        """Switch to another phone app (see connection.py); a one-line message when it
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
            self.sessions.complain("Cannot open", f"cannot start the source: "
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


class LayoutStore:
    """Named window layouts (as x-IMU3's GUI and PlotJuggler save theirs): where the docks are,
    the splitters between the 3D views and the plots, and which tab of plots shows.

    Kept in the window's QSettings under "layouts/<name>/..."; the layout the window closed
    with is "window/..." and comes back at the next start.
    """

    def __init__(self, settings: QtCore.QSettings) -> None:
        self.settings = settings

    def names(self) -> list[str]:
        self.settings.beginGroup("layouts")
        try:
            return sorted(self.settings.childGroups())
        finally:
            self.settings.endGroup()

    @staticmethod
    def _key(name: str) -> str:
        return "layouts/" + name.replace("/", "∕")

    def save(self, name: str, window: Any) -> None:
        self.write_current(self.settings, window, self._key(name))
        self.settings.sync()

    def apply(self, name: str, window: Any) -> bool:
        if name not in self.names():
            return False
        return self.read_current(self.settings, window, self._key(name))

    def delete(self, name: str) -> None:
        self.settings.remove(self._key(name))
        self.settings.sync()

    @staticmethod
    def write_current(settings: QtCore.QSettings, window: Any, prefix: str) -> None:
        settings.setValue(f"{prefix}/state", window.saveState(LAYOUT_VERSION))
        settings.setValue(f"{prefix}/central_splitter", window.central_splitter.saveState())
        settings.setValue(f"{prefix}/views_splitter", window.views_splitter.saveState())
        settings.setValue(f"{prefix}/plot_tab", window.plots.current_group())

    @staticmethod
    def read_current(settings: QtCore.QSettings, window: Any, prefix: str) -> bool:
        state = settings.value(f"{prefix}/state")
        restored = state is not None and window.restoreState(state, LAYOUT_VERSION)
        for key, splitter in (("central_splitter", window.central_splitter),
                              ("views_splitter", window.views_splitter)):
            value = settings.value(f"{prefix}/{key}")
            if value is not None:
                splitter.restoreState(value)
        tab = settings.value(f"{prefix}/plot_tab")
        if isinstance(tab, str) and tab in window.plots.groups:
            window.plots.set_current_group(tab)
        return bool(restored)


class FailureDialog(QtWidgets.QDialog):
    """Shows the latest engine failure: the one-line message, the whole traceback on demand and
    a "Copy details" button (for a bug report); :meth:`show_failure` replaces what it shows.
    Non-modal: the window keeps drawing while it is open."""

    def __init__(self, parent: QtWidgets.QWidget | None = None,
                 log_path: Path | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("failure_dialog")
        self.setWindowTitle("Orientation Lab: engine error")
        self.setModal(False)
        self.log_path = log_path
        self.failure: EngineFailure | None = None
        self.message = QtWidgets.QLabel()
        self.message.setWordWrap(True)
        self.message.setTextInteractionFlags(
            self.message.textInteractionFlags() | QtGui.Qt.TextInteractionFlag.TextSelectableByMouse)
        self.outcome = QtWidgets.QLabel()
        self.outcome.setWordWrap(True)
        self.details = QtWidgets.QPlainTextEdit()
        self.details.setReadOnly(True)
        self.details.setVisible(False)
        self.details.setMinimumHeight(220)
        self.details_button = QtWidgets.QPushButton("Show details")
        self.details_button.setCheckable(True)
        self.details_button.toggled.connect(self._show_details)
        self.copy_button = QtWidgets.QPushButton("Copy details")
        self.copy_button.clicked.connect(self.copy_details)
        close = QtWidgets.QPushButton("Close")
        close.clicked.connect(self.hide)
        buttons = QtWidgets.QHBoxLayout()
        buttons.addWidget(self.details_button)
        buttons.addWidget(self.copy_button)
        buttons.addStretch(1)
        buttons.addWidget(close)
        layout = QtWidgets.QVBoxLayout(self)
        layout.addWidget(self.message)
        layout.addWidget(self.outcome)
        layout.addWidget(self.details, 1)
        layout.addLayout(buttons)
        self.resize(640, 200)

    def show_failure(self, failure: EngineFailure, total: int) -> None:
        self.failure = failure
        self.message.setText(f"<b>The engine hit an error</b> (#{failure.number}, "
                             f"{failure.when} UTC):<br>{_escape(failure.message)}")
        then = ("The engine stopped: it failed several times in a row. Open the source again "
                "to retry." if failure.fatal else
                "The batch of samples it was working on was skipped; the engine goes on.")
        where = f" Details are also in {self.log_path}." if self.log_path else ""
        more = f" ({total} errors so far.)" if total > 1 else ""
        self.outcome.setText(then + more + where)
        self.details.setPlainText(failure.details)
        self.show()
        self.raise_()

    def copy_details(self) -> None:
        if self.failure is not None:
            QtWidgets.QApplication.clipboard().setText(
                f"{self.failure.message}\n\n{self.failure.details}")

    def _show_details(self, visible: bool) -> None:
        self.details.setVisible(visible)
        self.details_button.setText("Hide details" if visible else "Show details")
        self.adjustSize()


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _to_bool(value: Any, default: bool) -> bool:
    # QSettings returns strings ("true"/"false") from INI files and bools from the registry.
    if value is None:
        return default
    if isinstance(value, str):
        return value.lower() in ("true", "1", "yes")
    return bool(value)


def _set_text(label: QtWidgets.QLabel, text: str) -> None:
    """Change a label only when its text changes (setText re-lays out and repaints)."""
    if label.text() != text:
        label.setText(text)


class PaintCounter(QtCore.QObject):
    """Event filter calling `on_paint()` for every paint event of the widgets it watches."""

    def __init__(self, on_paint) -> None:
        super().__init__()
        self._on_paint = on_paint

    def eventFilter(self, watched: QtCore.QObject, event: QtCore.QEvent) -> bool:  # noqa: N802
        if event.type() == QtCore.QEvent.Type.Paint:
            self._on_paint()
        return False
