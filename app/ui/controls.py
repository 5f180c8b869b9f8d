"""Sensor switches, estimator choice and filter actions (FilterPanel), and the table of sensor
combinations run side by side (ComparisonPanel).

Every control only forwards intent: it calls `send(command)` with a command from
app.engine.commands. What the filter actually does comes back in the next snapshot and is shown
from there (the switches follow the engine's status unless the user just clicked them).
"""

from __future__ import annotations

import math
import time
from typing import Callable

from PySide6 import QtCore, QtWidgets

from app.engine.commands import (AlignHeading, ResetFilter, SetComparisonsEnabled, SetEstimator,
                                 SetFollowTimeline, SetSensorEnabled)
from app.engine.processing.configuration import ConfigurationView
from app.engine.snapshot import SENSOR_NAMES, Comparison, FilterStatus, absent_text

ESTIMATOR_CHOICES = (
    ("ekf", "EKF (default preset)"),
    ("course", "EKF (course preset)"),
    ("complementary", "Complementary filter"),
    ("gyro", "Gyroscope only"),
    ("accmag", "Accelerometer + magnetometer"),
)
ESTIMATOR_LABELS = dict(ESTIMATOR_CHOICES)
SENSOR_LABELS = (("gyr", "Gyroscope"), ("acc", "Accelerometer"), ("mag", "Magnetometer"))
# How long a click wins over the engine's echo of the old state (the command is applied
# between two batches of samples, so a snapshot in flight may still show the old value).
USER_PRIORITY_S = 1.0
MIN_COMPARED = 50           # fewer ORI samples than this: the row shows "—"


class _FollowsEngine:
    """Remembers the user's recent clicks so the engine's echo does not undo them."""

    def __init__(self) -> None:
        self._last_user_change: dict[str, float] = {}

    def _user_changed(self, key: str) -> None:
        self._last_user_change[key] = time.monotonic()

    def _user_recently_changed(self, key: str) -> bool:
        return time.monotonic() - self._last_user_change.get(key, -math.inf) < USER_PRIORITY_S


def _estimator_combo() -> QtWidgets.QComboBox:
    combo = QtWidgets.QComboBox()
    for name, label in ESTIMATOR_CHOICES:
        combo.addItem(label, name)
    return combo


class FilterPanel(QtWidgets.QWidget, _FollowsEngine):
    """Switches and actions. Signals: uncertainty_toggled(bool) for the 3D view,
    sensor_toggled(str, bool) and estimator_changed(str) for the menus."""

    uncertainty_toggled = QtCore.Signal(bool)
    sensor_toggled = QtCore.Signal(str, bool)
    estimator_changed = QtCore.Signal(str)

    def __init__(self, send: Callable[[object], None],
                 parent: QtWidgets.QWidget | None = None) -> None:
        QtWidgets.QWidget.__init__(self, parent)
        _FollowsEngine.__init__(self)
        self._send = send
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
        # "no gyroscope in this stream" under the switches, while a sensor is absent
        self.sensor_note = QtWidgets.QLabel()
        self.sensor_note.setObjectName("sensor_note")
        self.sensor_note.setWordWrap(True)
        self.sensor_note.setStyleSheet("color: #555;")
        self.sensor_note.setVisible(False)
        layout.addWidget(self.sensor_note)
        self.absent: frozenset[str] = frozenset()

        filter_box = QtWidgets.QGroupBox("Estimator (OWN)")
        filter_layout = QtWidgets.QGridLayout(filter_box)
        self.estimator_combo = _estimator_combo()
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
        # a replayed recording: what of its set-up is yours, and the way back to it
        self.configuration_label = QtWidgets.QLabel()
        self.configuration_label.setObjectName("configuration_summary")
        self.configuration_label.setWordWrap(True)
        self.configuration_label.setStyleSheet("color: #555;")
        self.follow_button = QtWidgets.QPushButton("Back to the recording")
        self.follow_button.setObjectName("follow_recording")
        self.follow_button.setToolTip("Replay the recorded switches, estimator, settings and "
                                      "combinations again, from the start")
        self.follow_button.clicked.connect(lambda: self._send(SetFollowTimeline(True)))
        follow_row = QtWidgets.QHBoxLayout()
        follow_row.setContentsMargins(0, 0, 0, 0)
        follow_row.addWidget(self.configuration_label, 1)
        follow_row.addWidget(self.follow_button)
        self.configuration_row = QtWidgets.QWidget()
        self.configuration_row.setLayout(follow_row)
        self.configuration_row.setVisible(False)
        layout.addWidget(self.configuration_row)

    # ---- user intent -> commands ----------------------------------------------------------

    def _on_sensor_toggled(self, sensor: str, checked: bool) -> None:
        self._user_changed(sensor)
        self._send(SetSensorEnabled(sensor, bool(checked)))
        self.sensor_toggled.emit(sensor, bool(checked))

    def _on_estimator_changed(self, index: int) -> None:
        self._user_changed("estimator")
        name = self.estimator_combo.itemData(index)
        self._send(SetEstimator(name))
        self.estimator_changed.emit(name)

    def toggle_sensor(self, sensor: str) -> None:
        """Flip one sensor switch (keyboard shortcut, menu)."""
        checkbox = self.sensor_checkboxes[sensor]
        checkbox.setChecked(not checkbox.isChecked())

    def set_sensor(self, sensor: str, enabled: bool) -> None:
        checkbox = self.sensor_checkboxes[sensor]
        if checkbox.isChecked() != bool(enabled):
            checkbox.setChecked(bool(enabled))

    def estimator(self) -> str:
        return self.estimator_combo.currentData()

    def set_estimator(self, name: str) -> None:
        index = self.estimator_combo.findData(name)
        if index >= 0:
            self.estimator_combo.setCurrentIndex(index)

    # ---- engine state -> widgets ----------------------------------------------------------

    def set_absent(self, absent: frozenset[str]) -> None:
        """Sensors the stream does not deliver (app.engine.snapshot.absent_sensors): their
        switches greyed out, saying "no gyroscope in this stream"; the tick (the user's choice)
        stays as it is and applies when the sensor arrives."""
        absent = frozenset(absent)
        if absent == self.absent:
            return
        self.absent = absent
        for sensor, checkbox in self.sensor_checkboxes.items():
            missing = sensor in absent
            checkbox.setEnabled(not missing)
            checkbox.setToolTip(f"{absent_text(sensor)}: the switch applies when its samples "
                                "arrive" if missing else "")
        missing = [SENSOR_NAMES[sensor] for sensor in SENSOR_NAMES if sensor in absent]
        # one short line ("no gyroscope or magnetometer in this stream"): the panel's height
        # barely changes
        self.sensor_note.setText(f"no {' or '.join(missing)} in this stream" if missing else "")
        self.sensor_note.setVisible(bool(missing))

    def show_configuration(self, configuration: ConfigurationView | None) -> None:
        """A replayed recording: one line saying what of its set-up is yours ("settings: yours;
        switches, estimator, combinations: recorded") and, when something is, the way back."""
        recorded = configuration is not None and configuration.replaying \
            and configuration.recorded
        self.configuration_row.setVisible(recorded)
        if not recorded:
            return
        self.configuration_label.setText(f"Replay: {configuration.summary}")
        self.follow_button.setEnabled(configuration.yours)

    def update_status(self, status: FilterStatus) -> None:
        """Follow the engine's view of the switches without sending commands back."""
        for sensor, checkbox in self.sensor_checkboxes.items():
            enabled = status.sensors_enabled.get(sensor)
            if (enabled is not None and enabled != checkbox.isChecked()
                    and not self._user_recently_changed(sensor)):
                checkbox.blockSignals(True)
                checkbox.setChecked(enabled)
                checkbox.blockSignals(False)
                self.sensor_toggled.emit(sensor, bool(enabled))
        if status.estimator != self.estimator() and not self._user_recently_changed("estimator"):
            index = self.estimator_combo.findData(status.estimator)
            if index >= 0:
                self.estimator_combo.blockSignals(True)
                self.estimator_combo.setCurrentIndex(index)
                self.estimator_combo.blockSignals(False)
                self.estimator_changed.emit(status.estimator)


class ComparisonPanel(QtWidgets.QWidget, _FollowsEngine):
    """The 7 sensor combinations of a chosen estimator, run side by side (task 12): the RMSE of
    the total angle, heading and inclination against PHONE, compared at PHONE's time stamps."""

    COLUMNS = ("Sensors", "total (°)", "heading (°)", "inclination (°)")

    def __init__(self, send: Callable[[object], None],
                 parent: QtWidgets.QWidget | None = None) -> None:
        QtWidgets.QWidget.__init__(self, parent)
        _FollowsEngine.__init__(self)
        self._send = send
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        top = QtWidgets.QHBoxLayout()
        self.comparisons_checkbox = QtWidgets.QCheckBox("Run")
        self.comparisons_checkbox.setChecked(True)
        self.comparisons_checkbox.setToolTip("Run every sensor combination of the chosen "
                                             "estimator beside OWN")
        self.comparisons_checkbox.toggled.connect(self._on_changed)
        self.estimator_combo = _estimator_combo()
        self.estimator_combo.setToolTip("The estimator the combinations run")
        self.estimator_combo.currentIndexChanged.connect(self._on_changed)
        top.addWidget(self.comparisons_checkbox)
        top.addWidget(self.estimator_combo, 1)
        layout.addLayout(top)
        self.caption = QtWidgets.QLabel()
        self.caption.setWordWrap(True)
        self.caption.setStyleSheet("color: #555;")
        layout.addWidget(self.caption)
        self.table = QtWidgets.QTableWidget(0, len(self.COLUMNS))
        self.table.setObjectName("comparison_table")
        self.table.setHorizontalHeaderLabels(self.COLUMNS)
        self.table.horizontalHeaderItem(0).setToolTip("which sensors this filter uses")
        for column, text in ((1, "the whole rotation"), (2, "about up (what the magnetometer "
                                                              "gives)"),
                             (3, "the tilt (what the accelerometer gives)")):
            self.table.horizontalHeaderItem(column).setToolTip(f"RMSE against PHONE: {text}")
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QtWidgets.QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setSelectionMode(QtWidgets.QAbstractItemView.SelectionMode.NoSelection)
        # the names as wide as they are, the figures sharing the rest: a note spanning the
        # figures ("no gyroscope in this stream") never widens a column past the dock
        header = self.table.horizontalHeader()
        header.setSectionResizeMode(0, QtWidgets.QHeaderView.ResizeMode.ResizeToContents)
        for column in range(1, len(self.COLUMNS)):
            header.setSectionResizeMode(column, QtWidgets.QHeaderView.ResizeMode.Stretch)
        self.table.setHorizontalScrollBarPolicy(QtCore.Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.table.verticalHeader().setDefaultSectionSize(22)
        self.table.setMinimumHeight(7 * 22 + 28)
        layout.addWidget(self.table, 1)
        self._update_caption(self.estimator())

    def estimator(self) -> str:
        return self.estimator_combo.currentData()

    def _on_changed(self, *args) -> None:
        self._user_changed("comparisons")
        self._send(SetComparisonsEnabled(self.comparisons_checkbox.isChecked(), self.estimator()))
        self._update_caption(self.estimator())

    def _update_caption(self, estimator: str) -> None:
        self.caption.setText(f"{ESTIMATOR_LABELS.get(estimator, estimator)} with each sensor "
                             "combination: RMSE against PHONE, at PHONE's time stamps")

    def update_comparisons(self, comparisons: list[Comparison], estimator: str,
                           absent: frozenset[str] = frozenset()) -> None:
        """The rows; a combination using a sensor in `absent` (not in the stream) says "no
        gyroscope" across its figures instead of the other sensors' results."""
        if estimator != self.estimator() and not self._user_recently_changed("comparisons"):
            index = self.estimator_combo.findData(estimator)
            if index >= 0:
                self.estimator_combo.blockSignals(True)
                self.estimator_combo.setCurrentIndex(index)
                self.estimator_combo.blockSignals(False)
                self._update_caption(estimator)
        table = self.table
        if table.rowCount() != len(comparisons):
            table.setRowCount(len(comparisons))
        for row, comparison in enumerate(comparisons):
            enough = comparison.samples >= MIN_COMPARED
            # "YOURS (my_filter.py)" is too wide for the column: the file name in the tooltip
            yours = comparison.name.startswith("YOURS")
            name = "YOURS" if yours else comparison.name
            missing = () if yours else [sensor for sensor in SENSOR_NAMES
                                        if sensor in absent
                                        and sensor in comparison.name.split("+")]
            if missing:
                note = "no " + " or ".join(SENSOR_NAMES[sensor] for sensor in missing)
                texts = [name] + [note] * (len(self.COLUMNS) - 1)
            else:
                texts = [name] + [
                    _degrees(value) if enough else "—" for value in comparison.rmse_deg]
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
                    if not column:
                        item.setToolTip(comparison.name)
                    else:
                        item.setToolTip(f"{text} in this stream: the figures would be those of "
                                        "the other sensors alone" if missing else "")
            self._set_note_span(row, bool(missing))

    def _set_note_span(self, row: int, spanned: bool) -> None:
        """A row's note spans its three figure columns (one text, centred)."""
        table = self.table
        span = len(self.COLUMNS) - 1 if spanned else 1
        if table.columnSpan(row, 1) != span:
            table.setSpan(row, 1, 1, span)
            item = table.item(row, 1)
            if item is not None:
                item.setTextAlignment(
                    (QtCore.Qt.AlignmentFlag.AlignHCenter if spanned
                     else QtCore.Qt.AlignmentFlag.AlignRight)
                    | QtCore.Qt.AlignmentFlag.AlignVCenter)

    def rows(self) -> list[tuple[str, ...]]:
        """The table's text, row by row (for tests)."""
        table = self.table
        return [tuple(table.item(row, column).text() for column in range(table.columnCount()))
                for row in range(table.rowCount())]


def _degrees(value: float) -> str:
    return "—" if value is None or not math.isfinite(value) else f"{value:.1f}"
