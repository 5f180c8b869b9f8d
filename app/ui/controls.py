"""Sensor switches, estimator choice, filter actions and the live comparison table.

Every control only forwards intent: it calls `send(command)` with a command from
app/snapshot.py. What the filter actually does comes back in the next snapshot and is shown
from there (the checkboxes follow the engine's status unless the user just clicked them).
"""

from __future__ import annotations

import math
import time
from typing import Callable

from PySide6 import QtCore, QtWidgets

from app.engine.commands import (AlignHeading, ResetFilter, SetComparisonsEnabled, SetEstimator,
                                 SetSensorEnabled)
from app.engine.snapshot import Comparison, FilterStatus

ESTIMATOR_CHOICES = (
    ("ekf", "EKF (default preset)"),
    ("course", "EKF (course preset)"),
    ("complementary", "Complementary filter"),
    ("gyro", "Gyroscope only"),
    ("accmag", "Accelerometer + magnetometer"),
)
SENSOR_LABELS = (("gyr", "Gyroscope"), ("acc", "Accelerometer"), ("mag", "Magnetometer"))
# How long a click wins over the engine's echo of the old state (the command is applied
# between two batches of samples, so a snapshot in flight may still show the old value).
USER_PRIORITY_S = 1.0


class ControlsPanel(QtWidgets.QWidget):
    """Switches and actions. Signals: uncertainty_toggled(bool) for the 3D view."""

    uncertainty_toggled = QtCore.Signal(bool)

    def __init__(self, send: Callable[[object], None],
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self._send = send
        self._last_user_change: dict[str, float] = {}
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)

        sensors_box = QtWidgets.QGroupBox("Sensors in the filter")
        sensors_layout = QtWidgets.QHBoxLayout(sensors_box)
        self.sensor_checkboxes: dict[str, QtWidgets.QCheckBox] = {}
        for sensor, label in SENSOR_LABELS:
            checkbox = QtWidgets.QCheckBox(label)
            checkbox.setChecked(True)
            checkbox.setObjectName(f"sensor_{sensor}")
            checkbox.toggled.connect(lambda checked, s=sensor: self._on_sensor_toggled(s, checked))
            sensors_layout.addWidget(checkbox)
            self.sensor_checkboxes[sensor] = checkbox
        layout.addWidget(sensors_box)

        filter_box = QtWidgets.QGroupBox("Estimator")
        filter_layout = QtWidgets.QGridLayout(filter_box)
        self.estimator_combo = QtWidgets.QComboBox()
        for name, label in ESTIMATOR_CHOICES:
            self.estimator_combo.addItem(label, name)
        self.estimator_combo.currentIndexChanged.connect(self._on_estimator_changed)
        self.reset_button = QtWidgets.QPushButton("Reset filter")
        self.reset_button.setToolTip("Start the estimate again from the next samples (Ctrl+R)")
        self.reset_button.clicked.connect(lambda: self._send(ResetFilter()))
        self.align_button = QtWidgets.QPushButton("Align heading")
        self.align_button.setToolTip("Turn OWN's world about up so its heading matches PHONE's "
                                     "(Ctrl+H)")
        self.align_button.clicked.connect(lambda: self._send(AlignHeading()))
        self.uncertainty_checkbox = QtWidgets.QCheckBox("Show uncertainty")
        self.uncertainty_checkbox.setToolTip("Rings at OWN's axis tips: 2σ of the attitude error "
                                             "from the filter's covariance, magnified 10×")
        self.uncertainty_checkbox.setChecked(True)
        self.uncertainty_checkbox.toggled.connect(self.uncertainty_toggled)
        filter_layout.addWidget(self.estimator_combo, 0, 0, 1, 2)
        filter_layout.addWidget(self.reset_button, 1, 0)
        filter_layout.addWidget(self.align_button, 1, 1)
        filter_layout.addWidget(self.uncertainty_checkbox, 2, 0, 1, 2)
        layout.addWidget(filter_box)

        comparison_box = QtWidgets.QGroupBox("Sensor combinations (side by side)")
        comparison_layout = QtWidgets.QVBoxLayout(comparison_box)
        self.comparisons_checkbox = QtWidgets.QCheckBox("Run every combination")
        self.comparisons_checkbox.setChecked(True)
        self.comparisons_checkbox.toggled.connect(
            lambda checked: self._send(SetComparisonsEnabled(bool(checked))))
        self.comparison_table = QtWidgets.QTableWidget(0, 3)
        self.comparison_table.setHorizontalHeaderLabels(["Sensors", "∠ to PHONE (°)", "RMSE (°)"])
        self.comparison_table.verticalHeader().setVisible(False)
        self.comparison_table.setEditTriggers(QtWidgets.QAbstractItemView.EditTrigger.NoEditTriggers)
        self.comparison_table.setSelectionMode(
            QtWidgets.QAbstractItemView.SelectionMode.NoSelection)
        header = self.comparison_table.horizontalHeader()
        header.setSectionResizeMode(0, QtWidgets.QHeaderView.ResizeMode.Stretch)
        for column in (1, 2):
            header.setSectionResizeMode(column, QtWidgets.QHeaderView.ResizeMode.ResizeToContents)
        self.comparison_table.setMinimumHeight(120)
        comparison_layout.addWidget(self.comparisons_checkbox)
        comparison_layout.addWidget(self.comparison_table)
        layout.addWidget(comparison_box, 1)

    # ---- user intent -> commands ----------------------------------------------------------

    def _on_sensor_toggled(self, sensor: str, checked: bool) -> None:
        self._last_user_change[sensor] = time.monotonic()
        self._send(SetSensorEnabled(sensor, bool(checked)))

    def _on_estimator_changed(self, index: int) -> None:
        self._last_user_change["estimator"] = time.monotonic()
        self._send(SetEstimator(self.estimator_combo.itemData(index)))

    def toggle_sensor(self, sensor: str) -> None:
        """Flip one sensor switch (keyboard shortcut)."""
        checkbox = self.sensor_checkboxes[sensor]
        checkbox.setChecked(not checkbox.isChecked())

    def estimator(self) -> str:
        return self.estimator_combo.currentData()

    def set_estimator(self, name: str) -> None:
        index = self.estimator_combo.findData(name)
        if index >= 0:
            self.estimator_combo.setCurrentIndex(index)

    # ---- engine state -> widgets ----------------------------------------------------------

    def _user_recently_changed(self, key: str) -> bool:
        return time.monotonic() - self._last_user_change.get(key, -math.inf) < USER_PRIORITY_S

    def update_status(self, status: FilterStatus) -> None:
        """Follow the engine's view of the switches without sending commands back."""
        for sensor, checkbox in self.sensor_checkboxes.items():
            enabled = status.sensors_enabled.get(sensor)
            if (enabled is not None and enabled != checkbox.isChecked()
                    and not self._user_recently_changed(sensor)):
                checkbox.blockSignals(True)
                checkbox.setChecked(enabled)
                checkbox.blockSignals(False)
        if status.estimator != self.estimator() and not self._user_recently_changed("estimator"):
            index = self.estimator_combo.findData(status.estimator)
            if index >= 0:
                self.estimator_combo.blockSignals(True)
                self.estimator_combo.setCurrentIndex(index)
                self.estimator_combo.blockSignals(False)

    def update_comparisons(self, comparisons: list[Comparison]) -> None:
        table = self.comparison_table
        if table.rowCount() != len(comparisons):
            table.setRowCount(len(comparisons))
        for row, comparison in enumerate(comparisons):
            texts = (comparison.name.replace("+", " + "),
                     _degrees(comparison.angle_to_phone_deg), _degrees(comparison.rmse_deg))
            for column, text in enumerate(texts):
                item = table.item(row, column)
                if item is None:
                    item = QtWidgets.QTableWidgetItem()
                    if column:
                        item.setTextAlignment(QtCore.Qt.AlignmentFlag.AlignRight
                                              | QtCore.Qt.AlignmentFlag.AlignVCenter)
                    table.setItem(row, column, item)
                if item.text() != text:
                    item.setText(text)

    def comparison_rows(self) -> list[tuple[str, str, str]]:
        """The table's text, row by row (for tests and the status bar)."""
        table = self.comparison_table
        return [tuple(table.item(row, column).text() for column in range(3))
                for row in range(table.rowCount())]


def _degrees(value: float) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.1f}"
