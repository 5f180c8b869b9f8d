"""The main window's menus and what their actions do: File (sessions, your filter), View
(plots, 3D cameras, layouts, docks), Replay (and back to the recording), Filter (reset, align,
sensors, estimator), Help.

A mixin of MainWindow: its methods use the window's widgets (plots, controls, views).
"""

from __future__ import annotations

import platform
from typing import TYPE_CHECKING

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from app import __version__
from app.engine.commands import SetFollowTimeline, UnloadUserFilter
from app.ui.controls import ESTIMATOR_CHOICES, SENSOR_LABELS
from app.ui.user_filter_panel import (load_filter_dialog, new_filter_dialog,
                                      new_matlab_filter_dialog)

if TYPE_CHECKING:
    from app.ui.phone_view import PhoneView


class WindowMenus:
    """The menu bar and the actions behind it (window-wide shortcuts)."""

    def clear_plots(self) -> None:
        """Ctrl+L: forget the plotted samples, and say so (the filter goes on)."""
        self.plots.clear()
        self.statusBar().showMessage("plots cleared: the filter goes on; new samples are "
                                     "plotted from now", 4000)


    def _action(self, menu: QtWidgets.QMenu, text: str, shortcut: str | None, slot,
                checkable: bool = False, checked: bool = False) -> QtGui.QAction:
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
        self.connect_action = self._action(self.file_menu, "&Connect a phone…", None,
                                           self.show_connect_dialog)
        self.sessions.build_file_menu(self.file_menu)
        self.load_filter_action = self._action(
            self.file_menu, "&Load your filter…", None, lambda: load_filter_dialog(self, self.send))
        self.new_filter_action = self._action(
            self.file_menu, "&New filter from the course template…", None,
            lambda: new_filter_dialog(self, self.send))
        self.new_matlab_filter_action = self._action(
            self.file_menu, "New &MATLAB filter from the course's functions…", None,
            lambda: new_matlab_filter_dialog(self, self.send))
        self.unload_filter_action = self._action(self.file_menu, "&Unload your filter", None,
                                                 lambda: self.send(UnloadUserFilter()))
        self.file_menu.addSeparator()
        self.quit_action = self._action(self.file_menu, "&Quit", "Ctrl+Q", self.close)
        self._build_view_menu(menus.addMenu("&View"))
        self.replay_menu = menus.addMenu("&Replay")
        self.replay_menu.addAction(self.pause_action)
        self.sessions.build_replay_menu(self.replay_menu)
        self.replay_menu.addSeparator()
        self.follow_recording_action = self._action(
            self.replay_menu, "&Back to the recording", None,
            lambda: self.send(SetFollowTimeline(True)))
        self.follow_recording_action.setToolTip("Replay the recorded switches, estimator, "
                                                "settings and combinations again")
        self.follow_recording_action.setEnabled(False)
        self._build_filter_menu(menus.addMenu("F&ilter"))
        help_menu = menus.addMenu("&Help")
        self.about_action = self._action(help_menu, "&About", "F1", self.show_about)

    def _build_view_menu(self, menu: QtWidgets.QMenu) -> None:
        self.view_menu = menu
        self.pause_action = self._action(menu, "&Pause / follow (replay: play / pause)", "Space",
                                         self.toggle_pause)
        self.clear_action = self._action(menu, "&Clear plots", "Ctrl+L", self.clear_plots)
        self.unwrap_action = self._action(menu, "&Unwrap Euler angles", None,
                                          self.plots.set_unwrapped, checkable=True)
        self.plots.unwrap_checkbox.toggled.connect(self.unwrap_action.setChecked)
        menu.addSeparator()
        self.link_cameras_action = self._action(menu, "&Link 3D cameras", None,
                                                self.set_cameras_linked, checkable=True)
        self._action(menu, "Reset 3D &views", None, self.reset_cameras)
        menu.addSeparator()
        self.layouts_menu = menu.addMenu("&Layouts")
        self.layouts_menu.aboutToShow.connect(self._fill_layouts_menu)
        self._action(menu, "&Reset to defaults", None, self.reset_to_defaults)
        self.remember_action = self._action(menu, "Re&member my set-up (sensors, estimator)",
                                            None, self._on_remember_toggled, checkable=True)
        menu.addSeparator()
        for dock in self.docks():
            menu.addAction(dock.toggleViewAction())

    def _build_filter_menu(self, menu: QtWidgets.QMenu) -> None:
        self.reset_action = self._action(menu, "&Reset filter", "Ctrl+R",
                                         self._reset_filter)
        self.align_action = self._action(menu, "&Align heading with PHONE", "Ctrl+H",
                                         self._align_heading)
        menu.addSeparator()
        self.sensor_actions: dict[str, QtGui.QAction] = {}
        for number, (sensor, label) in enumerate(SENSOR_LABELS, start=1):
            self.sensor_actions[sensor] = self._action(
                menu, label, f"Ctrl+{number}",
                lambda checked, s=sensor: self.controls.set_sensor(s, checked),
                checkable=True, checked=True)
        menu.addSeparator()
        estimator_menu = menu.addMenu("&Estimator (OWN)")
        self.estimator_group = QtGui.QActionGroup(self)
        self.estimator_actions: dict[str, QtGui.QAction] = {}
        for name, label in ESTIMATOR_CHOICES:
            action = self._action(estimator_menu, label, None,
                                  lambda checked, n=name: self.controls.set_estimator(n),
                                  checkable=True, checked=name == "ekf")
            self.estimator_group.addAction(action)
            self.estimator_actions[name] = action

    # ---- actions --------------------------------------------------------------------------

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
