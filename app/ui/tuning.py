"""Auto-tune and A/B widgets: self-contained, for a workspace tab or a dock.

* :class:`TuningPanel`: parameters with their ranges, the tuning and check ranges, Start,
  Cancel and a progress bar, before/after figures for both ranges and the over-fitting warning;
  the result can be applied (``SetSettings(best, source="tuned")``) and kept as a new profile.
  The search runs in a thread (app.engine.tuning.autotune.TuningJob); its callbacks reach the GUI
  thread through queued signals.
* :class:`ABCompareView`: the error table of the current re-filter run and the kept ghost
  (app.engine.offline.refilter.Refilterer), "Keep as ghost" / "Clear ghost", and the run time.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from PySide6 import QtCore, QtWidgets

import ekf
from app.engine import config
from app.engine.tuning import autotune
from app.engine.commands import SetSettings
from app.engine.processing.configuration import Setup
from app.engine.tuning.profiles import Profile, ProfileStore
from app.engine.offline.refilter import PreparedLog, Refilterer, RefilterResult, ab_rows
from app.engine.snapshot import SENSOR_NAMES
from app.ui.elided import ElidedLabel

FIGURE_COLUMNS = ("", "total °", "heading °", "inclin. °", "samples")
FIGURE_TIPS = ("", "RMSE of the whole rotation against the reference",
               "RMSE about up (heading) against the reference",
               "RMSE of the tilt (inclination) against the reference",
               "reference samples compared")


def _figure_table(rows: int, visible_rows: int | None = None) -> QtWidgets.QTableWidget:
    """A figures table tall enough for `visible_rows` (default: rows) without scrolling: the
    row names as wide as they are, the figures sharing the rest."""
    table = QtWidgets.QTableWidget(rows, len(FIGURE_COLUMNS))
    table.setHorizontalHeaderLabels(FIGURE_COLUMNS)
    for column, tip in enumerate(FIGURE_TIPS):
        table.horizontalHeaderItem(column).setToolTip(tip)
    table.verticalHeader().setVisible(False)
    table.setEditTriggers(QtWidgets.QAbstractItemView.EditTrigger.NoEditTriggers)
    header = table.horizontalHeader()
    header.setSectionResizeMode(QtWidgets.QHeaderView.ResizeMode.Stretch)
    header.setSectionResizeMode(0, QtWidgets.QHeaderView.ResizeMode.ResizeToContents)
    table.setHorizontalScrollBarPolicy(QtCore.Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
    shown = visible_rows if visible_rows is not None else rows
    height = (table.horizontalHeader().sizeHint().height()
              + shown * table.verticalHeader().defaultSectionSize() + 2 * table.frameWidth() + 2)
    table.setFixedHeight(height)
    return table


def _set_row(table: QtWidgets.QTableWidget, row: int, label: str, values: tuple) -> None:
    table.setItem(row, 0, QtWidgets.QTableWidgetItem(label))
    for c, value in enumerate(values, start=1):
        text = f"{value:d}" if isinstance(value, int) else f"{value:.3f}"
        table.setItem(row, c, QtWidgets.QTableWidgetItem(text))


def _seconds_box(value: float, maximum: float) -> QtWidgets.QDoubleSpinBox:
    box = QtWidgets.QDoubleSpinBox()
    box.setRange(0.0, max(maximum, 0.1))
    box.setDecimals(1)
    box.setSuffix(" s")
    box.setValue(value)
    return box


class TuningPanel(QtWidgets.QWidget):
    """log: the PreparedLog to tune on (app.engine.offline.refilter.prepare / prepare_path); send:
    the engine's send; settings(): the settings to start from; store: profiles; setup(): the
    configuration over time the log is re-run with (a candidate overrides its settings; None:
    the EKF with every sensor)."""

    progressed = QtCore.Signal(object)          # autotune.Progress (from the worker thread)
    finished = QtCore.Signal(object, object)    # TuneResult | None, error | None

    def __init__(self, log: PreparedLog, send: Callable[[Any], None],
                 settings: Callable[[], ekf.EKFSettings | None] = lambda: None,
                 store: ProfileStore | None = None,
                 setup: Callable[[], Setup | None] = lambda: None,
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.log, self._send, self._settings = log, send, settings
        self._setup = setup
        self.store = store or ProfileStore()
        self.job: autotune.TuningJob | None = None
        self.result: autotune.TuneResult | None = None
        self.progressed.connect(self._on_progress, QtCore.Qt.ConnectionType.QueuedConnection)
        self.finished.connect(self._on_finished, QtCore.Qt.ConnectionType.QueuedConnection)
        self.parameters = self._parameter_table()
        half, whole = log.duration_s / 2.0, log.duration_s
        self.tune_start, self.tune_end = _seconds_box(0.0, whole), _seconds_box(half, whole)
        self.check_start, self.check_end = _seconds_box(half, whole), _seconds_box(whole, whole)
        self.max_evals = QtWidgets.QSpinBox()
        self.max_evals.setRange(2, 5000)
        self.max_evals.setValue(60)
        self.start_button = QtWidgets.QPushButton("Start")
        self.start_button.clicked.connect(self.start)
        self.cancel_button = QtWidgets.QPushButton("Cancel")
        self.cancel_button.setEnabled(False)
        self.cancel_button.clicked.connect(self.cancel)
        self.progress = QtWidgets.QProgressBar()
        self.figures = _figure_table(4)
        # what the search did ("60 runs in 3.4 s"), in the text's colour; a warning (a bound
        # reached, over-fitting, a refusal) in red beside it
        self.summary = QtWidgets.QLabel("")
        self.summary.setObjectName("tuning_summary")
        self.summary.setWordWrap(True)
        self.warning = QtWidgets.QLabel("")
        self.warning.setObjectName("tuning_warning")
        self.warning.setWordWrap(True)
        self.warning.setStyleSheet("color: #b00020")
        self.apply_button = QtWidgets.QPushButton("Apply tuned settings")
        self.apply_button.clicked.connect(self.apply)
        self.keep_button = QtWidgets.QPushButton("Keep as new profile")
        self.keep_button.clicked.connect(lambda: self.keep_as_profile())
        for button in (self.apply_button, self.keep_button):
            button.setEnabled(False)
        self._layout()

    def _parameter_table(self) -> QtWidgets.QTableWidget:
        """One row per searchable setting: tune it or not, its range, before and after. A
        setting of a sensor the session lacks is unticked and greyed out (it has no effect)."""
        names = list(autotune.RANGES)
        present = autotune.sensors_in(self.log)
        units = {row.name: row.unit for row in ekf.settings_rows()}
        table = QtWidgets.QTableWidget(len(names), 6)
        table.setHorizontalHeaderLabels(["tune", "low", "high", "before", "after", "unit"])
        table.setVerticalHeaderLabels(names)
        for r, name in enumerate(names):
            sensor = autotune.setting_sensor(name)
            usable = sensor is None or sensor in present
            check = QtWidgets.QTableWidgetItem()
            check.setFlags(QtCore.Qt.ItemFlag.ItemIsUserCheckable
                           | (QtCore.Qt.ItemFlag.ItemIsEnabled if usable
                              else QtCore.Qt.ItemFlag.NoItemFlags))
            check.setCheckState(QtCore.Qt.CheckState.Checked
                                if name in autotune.DEFAULT_PARAMETERS and usable
                                else QtCore.Qt.CheckState.Unchecked)
            table.setItem(r, 0, check)
            low, high = autotune.RANGES[name]
            table.setItem(r, 1, QtWidgets.QTableWidgetItem(f"{low:g}"))
            table.setItem(r, 2, QtWidgets.QTableWidgetItem(f"{high:g}"))
            unit = QtWidgets.QTableWidgetItem(units.get(name, "-"))
            unit.setFlags(QtCore.Qt.ItemFlag.ItemIsEnabled)
            table.setItem(r, 5, unit)
            tip = (f"{name} [{units.get(name, '-')}]" if usable else
                   f"{name}: no {SENSOR_NAMES[sensor]} in this session, so it has no effect")
            table.verticalHeaderItem(r).setToolTip(tip)
            for c in range(3):
                table.item(r, c).setToolTip(tip)
                if not usable:
                    table.item(r, c).setFlags(QtCore.Qt.ItemFlag.NoItemFlags)
        header = table.horizontalHeader()
        header.setSectionResizeMode(QtWidgets.QHeaderView.ResizeMode.Stretch)
        header.setSectionResizeMode(0, QtWidgets.QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(5, QtWidgets.QHeaderView.ResizeMode.ResizeToContents)
        return table

    def _layout(self) -> None:
        ranges = QtWidgets.QFormLayout()
        for label, lo, hi in (("Tune on", self.tune_start, self.tune_end),
                              ("Check on", self.check_start, self.check_end)):
            row = QtWidgets.QHBoxLayout()
            row.addWidget(lo)
            row.addWidget(QtWidgets.QLabel("to"))
            row.addWidget(hi)
            ranges.addRow(label, row)
        ranges.addRow("At most", self.max_evals)
        buttons = QtWidgets.QHBoxLayout()
        for w in (self.start_button, self.cancel_button, self.progress):
            buttons.addWidget(w)
        after = QtWidgets.QHBoxLayout()
        after.addWidget(self.apply_button)
        after.addWidget(self.keep_button)
        layout = QtWidgets.QVBoxLayout(self)
        layout.addWidget(self.parameters, 1)
        layout.addLayout(ranges)
        layout.addLayout(buttons)
        layout.addWidget(self.figures)
        layout.addWidget(self.summary)
        layout.addWidget(self.warning)
        layout.addLayout(after)

    # -- the search ---------------------------------------------------------------------------

    def chosen_parameters(self) -> list[autotune.Parameter]:
        """The checked rows with their (edited) ranges."""
        out = []
        for r in range(self.parameters.rowCount()):
            if self.parameters.item(r, 0).checkState() != QtCore.Qt.CheckState.Checked:
                continue
            name = self.parameters.verticalHeaderItem(r).text()
            low, high = (float(self.parameters.item(r, c).text()) for c in (1, 2))
            out.append(autotune.Parameter(name, low, high))
        return out

    def _target(self, start: QtWidgets.QDoubleSpinBox, end: QtWidgets.QDoubleSpinBox,
                label: str) -> autotune.Target:
        t0 = self.log.start_ms
        return autotune.Target(self.log, [[t0 + start.value() * 1000.0,
                                         t0 + end.value() * 1000.0]],
                             label=f"{label} {start.value():g}-{end.value():g} s",
                             setup=self._setup())

    def start(self) -> bool:
        if self.job is not None and self.job.running:
            return False
        try:
            parameters = self.chosen_parameters()
            if not parameters:
                raise config.ConfigError("choose at least one parameter to tune")
        except (ValueError, config.ConfigError) as error:
            self.summary.setText("")
            self.warning.setText(str(error))
            return False
        base = self._settings() or ekf.PRESETS["default"]
        check = (self._target(self.check_start, self.check_end, "check")
                 if self.check_end.value() > self.check_start.value() else None)
        self.job = autotune.TuningJob(
            self._target(self.tune_start, self.tune_end, "tune"), base, parameters, check,
            self.max_evals.value(), on_progress=self.progressed.emit,
            on_done=self.finished.emit)
        self.start_button.setEnabled(False)
        self.cancel_button.setEnabled(True)
        self.progress.setValue(0)
        self.summary.setText("tuning…")
        self.warning.setText("")
        self.job.start()
        return True

    def cancel(self) -> None:
        if self.job is not None:
            self.job.cancel()

    def _on_progress(self, progress: autotune.Progress) -> None:
        self.progress.setValue(int(round(100 * progress.fraction)))
        self.progress.setFormat(f"{progress.evaluations}/{progress.max_evaluations}, best "
                                f"{progress.best_deg:.2f}°")

    def _on_finished(self, result: autotune.TuneResult | None, error: BaseException | None) -> None:
        self.start_button.setEnabled(True)
        self.cancel_button.setEnabled(False)
        if error is not None or result is None:
            self.summary.setText("")
            self.warning.setText(f"tuning failed: {error}")
            return
        self.result = result
        self.progress.setValue(100)
        self._show_result(result)
        for button in (self.apply_button, self.keep_button):
            button.setEnabled(True)

    def _show_result(self, result: autotune.TuneResult) -> None:
        names = [self.parameters.verticalHeaderItem(r).text()
                 for r in range(self.parameters.rowCount())]
        for name, _, _, before, after in result.parameter_rows():
            r = names.index(name)
            self.parameters.setItem(r, 3, QtWidgets.QTableWidgetItem(f"{before:.4g}"))
            self.parameters.setItem(r, 4, QtWidgets.QTableWidgetItem(f"{after:.4g}"))
        rows = [("tune before", result.tune_before), ("tune after", result.tune_after),
                ("check before", result.check_before), ("check after", result.check_after)]
        rows = [(label, s) for label, s in rows if s is not None]
        self.figures.setRowCount(len(rows))
        for r, (label, s) in enumerate(rows):
            _set_row(self.figures, r, label, (s.total_rmse_deg, s.heading_rmse_deg,
                                              s.inclination_rmse_deg, s.samples))
        state = " (cancelled: best so far)" if result.cancelled else ""
        self.summary.setText(f"{result.evaluations} runs in {result.elapsed_s:.1f} s{state}")
        self.warning.setText(f"⚠ {result.overfit_warning}" if result.overfit_warning else "")

    def apply(self) -> None:
        if self.result is not None:
            self._send(SetSettings(self.result.best, source="tuned"))

    def keep_as_profile(self, name: str | None = None) -> Profile | None:
        """The tuned settings kept as a new profile beside the old ones."""
        if self.result is None:
            return None
        name = self.store.unique_name(name or "tuned")
        profile = Profile(name, settings=self.result.best.to_dict(),
                          tuning=self.result.to_dict())
        self.store.save(profile)
        self.summary.setText(f"kept as profile {name!r}")
        return profile


class ABCompareView(QtWidgets.QWidget):
    """The A/B error table of a Refilterer's current run and ghost. It hooks itself onto the
    refilterer's on_result (after any callback already there): each run's result reaches the
    GUI thread through a queued signal, :attr:`resultReady`, which a window can also use to
    redraw its plots and ghost curves."""

    resultReady = QtCore.Signal(object)      # RefilterResult, in the GUI thread

    def __init__(self, refilterer: Refilterer,
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.refilterer = refilterer
        self.table = _figure_table(0, visible_rows=3)
        self.timing = ElidedLabel("", minimum_text="…ms")
        self.keep_button = QtWidgets.QPushButton("Keep as ghost")
        self.keep_button.clicked.connect(self.keep_ghost)
        self.clear_button = QtWidgets.QPushButton("Clear ghost")
        self.clear_button.clicked.connect(self.clear_ghost)
        self.resultReady.connect(self._show, QtCore.Qt.ConnectionType.QueuedConnection)
        previous = refilterer.on_result

        def forward(result: RefilterResult) -> None:
            if previous is not None:
                previous(result)
            self.on_result(result)

        refilterer.on_result = forward
        buttons = QtWidgets.QHBoxLayout()
        for w in (self.keep_button, self.clear_button):
            buttons.addWidget(w)
        buttons.addStretch(1)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(0, 4, 0, 0)
        layout.addWidget(self.table)
        layout.addLayout(buttons)
        layout.addWidget(self.timing)

    def on_result(self, result: RefilterResult) -> None:
        self.resultReady.emit(result)

    def keep_ghost(self) -> None:
        self.refilterer.keep_ghost()
        self.refresh()

    def clear_ghost(self) -> None:
        self.refilterer.clear_ghost()
        self.refresh()

    def _show(self, result: RefilterResult) -> None:
        self.timing.setText(f"re-filtered in {1000 * result.elapsed_s:.0f} ms")
        self.refresh()

    def refresh(self) -> None:
        rows = ab_rows(self.refilterer.current, self.refilterer.ghost)
        self.table.setRowCount(len(rows))
        for r, (label, *values) in enumerate(rows):
            _set_row(self.table, r, label, tuple(values))
