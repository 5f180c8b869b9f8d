"""The Tune workspace: every filter setting live, the whole session re-filtered at each change
with the previous run kept as a ghost (A/B), and auto-tune against the session's reference.

* Left: the settings panel (app.ui.settings_panel). A change goes to the engine, which makes it
  part of its configuration (app.engine.processing.configuration: on a replay, your settings for
  the whole replay; live, from the next sample); the configuration comes back with the next
  snapshot and the session shown here is re-run with it in the background
  (app.engine.offline.refilter.Refilterer): the replayed session with its configuration over
  time, so its figures are the replay's; another log with the configuration running now.
* Right, "A/B re-filter": the current run's and the ghost's errors against PHONE over the whole
  session (total and heading; the ghost dashed), the angle between the two runs at the same
  instants (ABPlots), and the A/B error table (ABCompareView: the current run and the kept
  ghost, "Keep as ghost" / "Clear ghost", and the run time).
* Right, "Auto-tune": TuningPanel on the same session: parameters with their ranges, the
  tuning and check ranges, Start, Cancel and a progress bar, before/after figures for both
  ranges and the over-fitting warning; the result can be applied
  (``SetSettings(best, source="tuned")``) and kept as a new profile. The search runs in a
  thread (app.engine.tuning.autotune.TuningJob); its callbacks reach the GUI thread through
  queued signals.

The session is the log the window replays (or the demo), or one chosen with "Open log…"; it is
read when the workspace is first shown. Draws and forwards intent only: the runs are the
engine's (Qt-free) code.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets

import ekf
from app.engine import config
from app.engine.commands import SetSettings
from app.engine.processing.configuration import ConfigurationView, Setup, setup_for_log
from app.engine.tuning import autotune
from app.engine.tuning.profiles import Profile, ProfileStore
from app.engine.offline.refilter import (Refilterer, RefilterResult, ab_rows,
                                         angle_between_runs_deg, read_replayed)
from app.engine.snapshot import SENSOR_NAMES
from app.stream.logfile import LogData
from app.ui.elided import ElidedLabel
from app.ui.plots import NoDataText
from app.ui.settings_panel import SettingsPanel

FIGURE_COLUMNS = ("", "total °", "heading °", "inclin. °", "samples")
FIGURE_TIPS = ("", "RMSE of the whole rotation against the reference",
               "RMSE about up (heading) against the reference",
               "RMSE of the tilt (inclination) against the reference",
               "reference samples compared")
CURRENT_COLOR = (130, 40, 170)
GHOST_COLOR = (110, 110, 110)
DIFFERENCE_COLOR = (0, 130, 130)
MIN_DIFFERENCE_SPAN_DEG = 0.1    # the Δ plot's smallest y range
RUNS_MIN_WIDTH = 300         # px the A/B plots and table keep beside the settings
SETTINGS_PANE_MARGIN = 34    # the group box's frame and margins around the settings table
NO_SESSION_TEXT = ("No session to re-filter.\nReplay a log (orientation-lab --replay LOG) or "
                   "choose one with Open log…")


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
    """log: the LogData to tune on (app.engine.config.open_log,
    app.engine.offline.refilter.read_replayed); send: the engine's send; settings(): the settings to
    start from; store: profiles; setup(): the configuration over time the log is re-run with (a
    candidate overrides its settings; None: the EKF with every sensor)."""

    progressed = QtCore.Signal(object)          # autotune.Progress (from the worker thread)
    finished = QtCore.Signal(object, object)    # TuneResult | None, error | None

    def __init__(self, log: LogData, send: Callable[[Any], None],
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
        setting of a sensor the session lacks is unticked and greyed out (it has no effect). The
        default parameters come first, in the order `tune` searches them, so the window's search
        is the command line's."""
        names = [*autotune.DEFAULT_PARAMETERS,
                 *(name for name in autotune.RANGES if name not in autotune.DEFAULT_PARAMETERS)]
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


class ABPlots(QtWidgets.QWidget):
    """The current run and the ghost over the whole session: error against PHONE (total,
    heading) and the angle between the runs, in seconds from the session's start."""

    def __init__(self, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.legend = QtWidgets.QLabel(
            f"<span style='color: rgb{CURRENT_COLOR}'>━ current run</span>&nbsp;&nbsp; "
            f"<span style='color: rgb{GHOST_COLOR}'>╍ ghost (kept run)</span>&nbsp;&nbsp; "
            f"<span style='color: rgb{DIFFERENCE_COLOR}'>━ Δ: current vs ghost</span>")
        self.legend.setTextFormat(QtCore.Qt.TextFormat.RichText)
        self.legend.setWordWrap(True)
        self.message = QtWidgets.QLabel(NO_SESSION_TEXT)
        self.message.setObjectName("ab_message")
        self.message.setWordWrap(True)
        self.graphics = pg.GraphicsLayoutWidget()
        self.graphics.setBackground((250, 250, 252))
        self.plots: dict[str, pg.PlotItem] = {}
        self.curves: dict[tuple[str, str], pg.PlotDataItem] = {}
        titles = (("total", "total", "°"), ("heading", "heading", "°"),
                  ("difference", "Δ", "°"))
        for row, (key, title, units) in enumerate(titles):
            plot = self.graphics.addPlot(row=row, col=0)
            plot.setLabel("left", title, units=units, **{"font-size": "8pt"})
            plot.getAxis("left").enableAutoSIPrefix(False)
            plot.getAxis("left").setWidth(64)
            plot.setClipToView(True)
            plot.setDownsampling(auto=True, mode="peak")
            plot.showGrid(x=True, y=True, alpha=0.2)
            if row:
                plot.setXLink(self.plots["total"])
            self.plots[key] = plot
        self.plots["difference"].setLabel("bottom", "time since the session's start", units="s")
        self.plots["difference"].getAxis("bottom").enableAutoSIPrefix(False)
        for key in ("total", "heading"):
            self.curves[(key, "ghost")] = self.plots[key].plot(
                pen=pg.mkPen(GHOST_COLOR, width=1, style=QtCore.Qt.PenStyle.DashLine))
            self.curves[(key, "current")] = self.plots[key].plot(
                pen=pg.mkPen(CURRENT_COLOR, width=1))
        self.curves[("difference", "current")] = self.plots["difference"].plot(
            pen=pg.mkPen(DIFFERENCE_COLOR, width=1))
        self.no_data = {key: NoDataText(plot.getViewBox()) for key, plot in self.plots.items()}
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.legend)
        layout.addWidget(self.message)
        layout.addWidget(self.graphics, 1)
        self.show_runs(None, None, None)

    def show_runs(self, current: RefilterResult | None, ghost: RefilterResult | None,
                  start_ms: int | None) -> None:
        """Draw the current run and the ghost (either may be None); start_ms: the session's
        first time on the phone's clock (None: no session)."""
        loaded = start_ms is not None
        start_ms = start_ms or 0
        for key, run in (("current", current), ("ghost", ghost)):
            errors = None if run is None else run.errors
            for plot in ("total", "heading"):
                curve = self.curves[(plot, key)]
                if errors is None:
                    curve.setData([], [])
                    continue
                t = (errors.t_ms - start_ms) / 1000.0
                values = errors.total_deg if plot == "total" else errors.heading_deg
                curve.setData(t, values)
        for plot in ("total", "heading"):
            self._fit_errors(plot, [run.errors for run in (current, ghost)
                                    if run is not None and run.errors is not None])
        difference = self.curves[("difference", "current")]
        if current is not None and ghost is not None and len(current.rows):
            t = (current.rows.t_ms - start_ms) / 1000.0
            angles = angle_between_runs_deg(current, ghost)
            difference.setData(t, angles, connect="finite")
            self._fit_difference(angles)
        else:
            difference.setData([], [])
        has_errors = current is not None and current.errors is not None
        for key in ("total", "heading"):
            self.no_data[key].set_text("" if has_errors else
                                       "no ORI in this session" if current is not None
                                       else "no data")
        self.no_data["difference"].set_text(
            "" if current is not None and ghost is not None else "no ghost: Keep as ghost first"
            if current is not None else "no data")
        if current is None:
            text = "re-filtering…" if loaded else NO_SESSION_TEXT
        elif current.errors is None:
            text = ("This session has no ORI (the phone's own estimate): no error to draw; the "
                    "angle between the current run and the ghost is still shown.")
        elif ghost is None:
            text = "Keep as ghost to compare the next change with this run."
        else:
            text = ""
        self.message.setText(text)
        self.message.setVisible(bool(text))

    def _fit_difference(self, angles: np.ndarray) -> None:
        """y from 0 to a little above the largest angle, at least MIN_DIFFERENCE_SPAN_DEG: two
        runs that agree draw a line along zero, not rounding noise blown up to fill the plot."""
        finite = angles[np.isfinite(angles)]
        top = float(finite.max()) if len(finite) else 0.0
        self.plots["difference"].setYRange(0.0, max(1.1 * top, MIN_DIFFERENCE_SPAN_DEG),
                                           padding=0.0)

    def _fit_errors(self, plot: str, errors: list) -> None:
        """y from 0 to a little above the 99th percentile of both runs: the start, before the
        filter has settled, does not flatten the rest (the "A" button shows everything)."""
        values = [e.total_deg if plot == "total" else e.heading_deg for e in errors]
        values = [v[np.isfinite(v)] for v in values if len(v)]
        values = [v for v in values if len(v)]
        if not values:
            return
        top = max(float(np.percentile(v, 99.0)) for v in values)
        self.plots[plot].setYRange(0.0, max(1.25 * top, 0.5), padding=0.0)


class TuneWorkspace(QtWidgets.QWidget):
    """See the module's docstring. send: the window's send (SetSettings reach the engine; its
    configuration comes back through :meth:`configuration_changed`); settings(): the settings
    in use; log: the session to re-filter (read on the first show); store: profiles (None: the
    data folder)."""

    def __init__(self, send: Callable[[Any], None],
                 settings: Callable[[], ekf.EKFSettings | None] = lambda: None,
                 log: str | Path | None = None, store: ProfileStore | None = None,
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self._send = send
        self._settings = settings
        self.store = store
        self.pending_log: str | Path | None = log
        self.prepared: LogData | None = None
        self.refilterer: Refilterer | None = None
        self.ab_view: ABCompareView | None = None
        self.tuning_panel: TuningPanel | None = None
        self._submitted: Setup | None = None
        self.configuration: ConfigurationView | None = None   # the engine's, last seen

        self.log_label = QtWidgets.QLabel("no session")
        self.log_label.setObjectName("tune_log")
        self.log_label.setWordWrap(True)
        open_button = QtWidgets.QPushButton("Open log…")
        open_button.setToolTip("Re-filter and tune on another log or recorded session")
        open_button.clicked.connect(self._open_dialog)
        header = QtWidgets.QHBoxLayout()
        header.addWidget(self.log_label, 1)
        header.addWidget(open_button)

        self.settings_panel = SettingsPanel(send, settings(), store=store)
        settings_box = QtWidgets.QGroupBox("Filter settings (live: the filter and the re-run)")
        QtWidgets.QVBoxLayout(settings_box).addWidget(self.settings_panel)
        self.settings_box = settings_box
        self.ab_plots = ABPlots()
        self.smooth_checkbox = QtWidgets.QCheckBox("Smoothed (forward + backward RTS pass)")
        self.smooth_checkbox.setToolTip("The offline smoother of `filter --smooth`: our EKF "
                                        "forward, then a backward Rauch-Tung-Striebel pass, so "
                                        "each estimate uses the whole session. Keep the forward "
                                        "run as the ghost to see what smoothing gives.")
        self.smooth_checkbox.toggled.connect(self.set_smoothed)
        # A/B: the settings beside the runs they give; the ab_page holds the runs' side
        self.ab_page = QtWidgets.QWidget()
        ab_layout = QtWidgets.QVBoxLayout(self.ab_page)
        ab_layout.setContentsMargins(0, 0, 0, 0)
        ab_layout.addWidget(self.smooth_checkbox)
        ab_layout.addWidget(self.ab_plots, 1)
        self.splitter = QtWidgets.QSplitter(QtCore.Qt.Orientation.Horizontal)
        self.splitter.setObjectName("tune_splitter")
        self.splitter.setChildrenCollapsible(False)
        self.splitter.addWidget(self.settings_box)
        self.splitter.addWidget(self.ab_page)
        self.splitter.setStretchFactor(0, 0)
        self.splitter.setStretchFactor(1, 1)
        # the panes follow the window's size until the user drags the handle between them
        self._panes_by_user = False
        self.splitter.splitterMoved.connect(lambda *_: setattr(self, "_panes_by_user", True))
        # Auto-tune: its parameters, ranges and figures over the whole width
        self.tune_page = QtWidgets.QWidget()
        self.tune_message = QtWidgets.QLabel(NO_SESSION_TEXT)
        self.tune_message.setWordWrap(True)
        QtWidgets.QVBoxLayout(self.tune_page).addWidget(self.tune_message)
        self.tabs = QtWidgets.QTabWidget()
        self.tabs.setDocumentMode(True)
        self.tabs.addTab(self.splitter, "A/B re-filter")
        self.tabs.addTab(self.tune_page, "Auto-tune")
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(4, 4, 4, 4)
        layout.addLayout(header)
        layout.addWidget(self.tabs, 1)

    # -- the session --------------------------------------------------------------------------

    def showEvent(self, event) -> None:  # noqa: N802 (Qt name)
        super().showEvent(event)
        self.size_panes()
        if self.pending_log is not None and self.prepared is None:
            # Reading a long log takes a moment: after the tab has been drawn.
            QtCore.QTimer.singleShot(0, self._load_pending)

    def resizeEvent(self, event) -> None:  # noqa: N802 (Qt name)
        super().resizeEvent(event)
        self.size_panes()

    def size_panes(self) -> None:
        """The settings pane as wide as its table's columns, the runs the rest, never narrower
        than RUNS_MIN_WIDTH."""
        total = self.splitter.width()
        if total <= 0 or self._panes_by_user:
            return
        table = self.settings_panel.table
        around = (self.settings_box.width() - table.width() if table.width() > 0
                  and self.settings_box.width() > table.width() else SETTINGS_PANE_MARGIN)
        wanted = self.settings_panel.columns_width() + around
        left = max(min(wanted, total - RUNS_MIN_WIDTH), 0)
        self.splitter.setSizes([left, max(total - left, 0)])

    def _load_pending(self) -> None:
        if self.pending_log is not None and self.prepared is None:
            self.set_log(self.pending_log)

    def use_session(self, path: str | Path | None) -> None:
        """The window replays another session: re-filter that one (read now if the workspace is
        shown, else when it is next shown); None: keep the current one."""
        if path is None:
            return
        self.close_runs()
        self.prepared = None
        self.pending_log = path
        self.ab_plots.show_runs(None, None, None)
        if self.isVisible():
            QtCore.QTimer.singleShot(0, self._load_pending)

    def _open_dialog(self) -> None:
        path, _ = QtWidgets.QFileDialog.getOpenFileName(
            self, "Re-filter and tune on a log", "", "Logs and sessions (*.txt *.txt.gz *.json)")
        if path:
            self.set_log(path)

    def set_log(self, path: str | Path) -> bool:
        """Re-filter and tune on this log or session (False with a message when unusable)."""
        self.pending_log = None
        QtWidgets.QApplication.setOverrideCursor(QtCore.Qt.CursorShape.WaitCursor)
        try:
            prepared = read_replayed(path)
        except config.ConfigError as error:
            self.log_label.setText(f"cannot use {Path(path).name}: {error}")
            return False
        finally:
            QtWidgets.QApplication.restoreOverrideCursor()
        if not len(prepared.t_ms):
            self.log_label.setText(f"{Path(path).name}: no samples to filter")
            return False
        self.close_runs()
        self.prepared = prepared
        has_ori = len(prepared.ori_times) > 0
        self.log_label.setText(
            f"Session: <b>{Path(path).name}</b>, {prepared.duration_s:.1f} s, "
            f"{len(prepared.t_ms)} samples; re-filtered with the filter's configuration at "
            "every change"
            + ("" if has_ori else " (no ORI: nothing to score against)"))
        self.refilterer = Refilterer(prepared, on_error=self._on_error)
        self.refilterer.smooth = self.smooth_checkbox.isChecked()
        self.ab_view = ABCompareView(self.refilterer)
        self.ab_view.resultReady.connect(lambda _result: self.redraw())
        self.ab_view.keep_button.clicked.connect(self.redraw)
        self.ab_view.clear_button.clicked.connect(self.redraw)
        self.ab_page.layout().addWidget(self.ab_view)
        self._replace_tuning(prepared, has_ori)
        self._submitted = None
        self.submit()
        return True

    def _replace_tuning(self, prepared: LogData, has_ori: bool) -> None:
        layout = self.tune_page.layout()
        if self.tuning_panel is not None:
            layout.removeWidget(self.tuning_panel)
            self.tuning_panel.deleteLater()
            self.tuning_panel = None
        if has_ori:
            self.tuning_panel = TuningPanel(prepared, self._send, settings=self._settings,
                                            store=self.store, setup=self.setup)
            layout.addWidget(self.tuning_panel, 1)
        self.tune_message.setText("" if has_ori else "Auto-tune needs a reference: this "
                                  "session has no ORI (the phone's own estimate).")
        self.tune_message.setVisible(not has_ori)

    def setup(self) -> Setup:
        """The configuration a re-run of this workspace's session applies (see
        app.engine.processing.configuration.setup_for_log)."""
        return setup_for_log(self.configuration, self.prepared.path if self.prepared else None,
                             self._settings())

    def submit(self) -> None:
        """Re-run the session with the configuration (not again for the same one)."""
        if self.refilterer is None:
            return
        setup = self.setup()
        if setup == self._submitted:
            return
        self._submitted = setup
        self.refilterer.submit(setup)
        self.ab_plots.show_runs(self.refilterer.current, self.refilterer.ghost,
                                self.prepared.start_ms if self.prepared else None)

    def set_smoothed(self, smoothed: bool) -> None:
        """Re-filter with the smoother (True) or the forward filter (False)."""
        if self.smooth_checkbox.isChecked() != bool(smoothed):
            self.smooth_checkbox.setChecked(bool(smoothed))
            return
        if self.refilterer is not None:
            self.refilterer.smooth = bool(smoothed)
            self._submitted = None
            self.submit()

    def configuration_changed(self, configuration: ConfigurationView | None,
                              settings: ekf.EKFSettings | None) -> None:
        """The engine's configuration (a snapshot's) and the settings it runs now: show them
        and re-run the session with the configuration."""
        self.configuration = configuration
        if settings is not None:
            self.settings_panel.set_settings(settings)
        self.submit()

    def redraw(self) -> None:
        if self.refilterer is not None and self.prepared is not None:
            self.ab_plots.show_runs(self.refilterer.current, self.refilterer.ghost,
                                    self.prepared.start_ms)

    def _on_error(self, error: BaseException) -> None:
        # from the refilter thread: a queued call to show it
        QtCore.QMetaObject.invokeMethod(self.log_label, "setText",
                                        QtCore.Qt.ConnectionType.QueuedConnection,
                                        QtCore.Q_ARG(str, f"re-filter failed: {error}"))

    def close_runs(self) -> None:
        """Stop the background runs (the refilter thread, a tuning search)."""
        if self.tuning_panel is not None and self.tuning_panel.job is not None:
            self.tuning_panel.job.cancel()
            self.tuning_panel.job.wait(5.0)
        if self.refilterer is not None:
            self.refilterer.close()
            self.refilterer = None
        if self.ab_view is not None:
            self.ab_page.layout().removeWidget(self.ab_view)
            self.ab_view.deleteLater()
            self.ab_view = None

    def difference_deg(self) -> np.ndarray:
        """The angle between the current run and the ghost per row (empty without both)."""
        current = self.refilterer.current if self.refilterer else None
        ghost = self.refilterer.ghost if self.refilterer else None
        if current is None or ghost is None:
            return np.empty(0)
        return angle_between_runs_deg(current, ghost)
