"""The main window's layout and what persists (QSettings): the default arrangement of the
docks, named layouts (View → Layouts), geometry and view options, and the sensor switches and
estimator when the user chose View → "Remember my set-up". The first start is sized to the
screen it opens on.

A mixin of MainWindow: its methods use the window's docks, plots, controls and actions.
"""

from __future__ import annotations

from typing import Any

from PySide6 import QtCore, QtGui, QtWidgets

SETTINGS_VERSION = 2
FIT_ATTEMPTS = 4
DEFAULT_SIZE = (1600, 1000)     # the first start: this, or 92 % of a smaller screen


def _to_bool(value: Any, default: bool) -> bool:
    # QSettings returns strings ("true"/"false") from INI files and bools from the registry.
    if value is None:
        return default
    if isinstance(value, str):
        return value.lower() in ("true", "1", "yes")
    return bool(value)


class WindowPersistence:
    """Default layout, named layouts, saving and restoring the window's set-up."""

    _filter_dock_fitted = False

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
