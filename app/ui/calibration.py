"""The calibration workspace: at rest (task 2), gyroscope noise (Allan), magnetometer hard and
soft iron; Apply, Save profile, Load profile. A self-contained widget for a workspace tab.

The At rest tab (RestTab, course task 2): live samples collected for a duration (Start) or a
log (From log…, through the workspace), analysed as `calibrate` does: histograms with the
Gaussian, the time series, Table 1 (means, covariances) with the normality verdict and the
autocorrelation, and the warnings. The stretch analysed is chosen on the Time series (a range
to drag; Longest still and Whole: `calibrate`'s default and `--whole`).

Mounting (docs/user-guide.md, "Calibration and tuning"):
``CalibrationWorkspace(send=engine.send, settings=lambda: current_settings)``, then call
:meth:`feed` with every snapshot the window polls (it reads only ``snapshot.plot``:
t_acc/acc, t_gyr/gyr, t_mag/mag). Apply sends ``SetSettings(settings,
calibration=profile_dict, source="calibration")``; the engine records the profile in the
session. A stretch of a loaded log is analysed with :meth:`analyse_log` (or "From log…").

The numbers come from app.engine.tuning.calibration (the one path of `calibrate` and
`calibrate-mag`) and the figures from app.ui.figures (the same drawings as their --plots PNGs).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets

import ekf
from ekf import magcal
from ekf.calibration import UNITS
from ekf.noise import VERDICT_RULE
from app.engine import config
from app.engine.tuning.calibration import (RestCalibration, RestSource, SampleCollector,
                                    analyse_series, analyse_still, analyse_stretch,
                                    collected_source, mag_from_log, rest_source)
from app.engine.commands import SetSettings
from app.engine.tuning.profiles import Profile, ProfileStore
from app.ui import figures
from app.ui.plots import NoDataText

NO_REST_DATA = "no data"
NO_MAG_DATA = "no readings"
MAG_FIT_EVERY = 25        # refit the magnetometer after this many new readings
MAG_FIT_POINTS = 3000     # at most this many readings (evenly thinned) in a live fit
TABLE_COLUMNS = (
    ("sensor", "the sensor and its unit (mean, std: that unit; cov: its square)"),
    ("axis", ""), ("mean", "mean of the stretch [unit]"), ("std", "standard deviation [unit]"),
    ("verdict", VERDICT_RULE),
    ("K² p", "D'Agostino–Pearson K² normality test: p-value (below 0.01: not Gaussian)"),
    ("A² (1 % crit.)", "Anderson–Darling normality test: A², and in brackets its critical "
                       "value at 1 % (above it: not Gaussian)"),
    ("acf(1)", "autocorrelation at one sample's lag (correlated: above 0.2 and beyond white "
               "noise's)"),
    ("cov x", "covariance with x [unit²]"), ("cov y", "covariance with y [unit²]"),
    ("cov z", "covariance with z [unit²]"))


def label(text: str = "") -> QtWidgets.QLabel:
    """A word-wrapped label whose text can be selected."""
    label = QtWidgets.QLabel(text)
    label.setWordWrap(True)
    label.setTextInteractionFlags(QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
    return label


class RestTab(QtWidgets.QWidget):
    """Start (duration, default 10 s) collects live samples, From log… reads a log; the result
    shows histograms with the Gaussian, time series, Table 1 (means, covariances), normality,
    autocorrelation, warnings. The stretch analysed is chosen on the Time series: the whole
    source is drawn there with the stretches in which the phone moved shaded and the analysed
    one as a range to drag (Longest still, Whole: the two choices of `calibrate`)."""

    analysed = QtCore.Signal(object)        # RestCalibration

    def __init__(self, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.collector: SampleCollector | None = None
        self.result: RestCalibration | None = None
        self.source: RestSource | None = None     # what the stretch is chosen from
        self._moving_regions = False
        self.duration = QtWidgets.QDoubleSpinBox()
        self.duration.setRange(1.0, 3600.0)
        self.duration.setValue(10.0)
        self.duration.setSuffix(" s")
        self.start_button = QtWidgets.QPushButton("Start")
        self.start_button.clicked.connect(self.toggle)
        self.from_log_button = QtWidgets.QPushButton("From log…")
        self.progress = QtWidgets.QProgressBar()
        self.status = label("Lay the phone still and press Start.")
        self.warnings = label()
        self.warnings.setStyleSheet("color: #b00020")
        controls = QtWidgets.QHBoxLayout()
        for w in (QtWidgets.QLabel("Duration"), self.duration, self.start_button,
                  self.from_log_button, self.progress):
            controls.addWidget(w)
        views = self._build_views()
        self._build_stretch_bar()
        layout = QtWidgets.QVBoxLayout(self)
        layout.addLayout(controls)
        layout.addWidget(self.status)
        layout.addWidget(self.stretch_bar)
        layout.addWidget(self.warnings)
        layout.addWidget(views, 1)

    def _build_views(self) -> QtWidgets.QTabWidget:
        """Histograms, Time series (with the range to drag), Autocorrelation, Table 1."""
        self.histograms = pg.GraphicsLayoutWidget()
        self.histograms.setBackground("w")
        self.histogram_plots = [[self.histograms.addPlot(row=r, col=c) for c in range(3)]
                                for r in range(3)]
        self.series = pg.GraphicsLayoutWidget()
        self.series.setBackground("w")
        self.series_plots = [self.series.addPlot(row=r, col=0) for r in range(3)]
        for plot in self.series_plots[1:]:
            plot.setXLink(self.series_plots[0])
        # the analysed stretch, dragged on any of the three plots (the others follow)
        self.regions = []
        for _ in self.series_plots:
            region = pg.LinearRegionItem(brush=pg.mkBrush(60, 120, 230, 45),
                                         hoverBrush=pg.mkBrush(60, 120, 230, 80))
            region.setZValue(20)
            region.setToolTip("the stretch analysed: drag it or its edges to analyse another")
            region.sigRegionChanged.connect(self._sync_regions)
            region.sigRegionChangeFinished.connect(self._on_region_dragged)
            self.regions.append(region)
        self.acf = pg.GraphicsLayoutWidget()
        self.acf.setBackground("w")
        self.acf_plots = [self.acf.addPlot(row=r, col=0) for r in range(3)]
        self.no_data = [NoDataText(plot.getViewBox()) for plot in
                        [*sum(self.histogram_plots, []), *self.series_plots, *self.acf_plots]]
        for text in self.no_data:
            text.set_text(NO_REST_DATA)
        self.table = QtWidgets.QTableWidget(0, len(TABLE_COLUMNS))
        self.table.setHorizontalHeaderLabels([name for name, _ in TABLE_COLUMNS])
        for column, (_, tip) in enumerate(TABLE_COLUMNS):
            self.table.horizontalHeaderItem(column).setToolTip(tip)
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QtWidgets.QAbstractItemView.EditTrigger.NoEditTriggers)
        self.verdict_rule = label(f"Verdict — {VERDICT_RULE}.")
        self.verdict_rule.setStyleSheet("color: #444;")
        table_page = QtWidgets.QWidget()
        table_layout = QtWidgets.QVBoxLayout(table_page)
        table_layout.setContentsMargins(0, 0, 0, 0)
        table_layout.addWidget(self.table, 1)
        table_layout.addWidget(self.verdict_rule)
        views = QtWidgets.QTabWidget()
        views.addTab(self.histograms, "Histograms")
        views.addTab(self.series, "Time series")
        views.addTab(self.acf, "Autocorrelation")
        views.addTab(table_page, "Table 1")
        self.views = views
        return views

    def _build_stretch_bar(self) -> None:
        """What was analysed, in words, with Longest still and Whole (shown once there is a
        log or a collection to choose from)."""
        self.stretch_label = label("")
        self.stretch_label.setObjectName("rest_stretch")
        self.still_button = QtWidgets.QPushButton("Longest still")
        self.still_button.setToolTip("analyse the longest stretch in which the phone lay still "
                                     "(what `calibrate` takes by default)")
        self.still_button.clicked.connect(self.analyse_still)
        self.whole_button = QtWidgets.QPushButton("Whole")
        self.whole_button.setToolTip("analyse every sample (`calibrate --whole`)")
        self.whole_button.clicked.connect(self.analyse_whole)
        self.stretch_bar = QtWidgets.QWidget()
        stretch = QtWidgets.QHBoxLayout(self.stretch_bar)
        stretch.setContentsMargins(0, 0, 0, 0)
        stretch.addWidget(self.stretch_label, 1)
        stretch.addWidget(self.still_button)
        stretch.addWidget(self.whole_button)
        self.stretch_bar.setVisible(False)

    @property
    def collecting(self) -> bool:
        return self.collector is not None

    def toggle(self) -> None:
        if self.collecting:
            self.stop()
        else:
            self.start()

    def start(self, duration_s: float | None = None) -> None:
        if duration_s is not None:
            self.duration.setValue(duration_s)
        self.collector = SampleCollector(self.duration.value())
        self.start_button.setText("Stop")
        self.progress.setValue(0)
        self.status.setText(f"collecting {self.duration.value():g} s of samples: keep the "
                            "phone still…")

    def stop(self) -> None:
        """Stop collecting and analyse what was collected (all of it; a stretch of it can then
        be dragged on the Time series)."""
        collector, self.collector = self.collector, None
        self.start_button.setText("Start")
        if collector is None:
            return
        series = collector.series()
        how = f"{collector.elapsed_s:.1f} s of live samples"
        try:
            source = collected_source(series, "the live samples")
        except (config.ConfigError, ValueError):
            self.source = None              # (no accelerometer: nothing to choose on)
            self.stretch_bar.setVisible(False)
            self.analyse(series, how)
            return
        self.load_source(source, whole=True, how="all of them")

    # -- the stretch analysed -------------------------------------------------------------------

    def load_source(self, source: RestSource, start_s: float | None = None,
                    end_s: float | None = None, whole: bool = False,
                    how: str | None = None) -> RestCalibration | None:
        """Choose stretches of `source` from now on and analyse one: [start_s, end_s] seconds
        from its start when given, all of it with `whole`, else its longest still interval (all
        of it when there is none)."""
        self.source = source
        self.stretch_bar.setVisible(True)
        if start_s is not None or end_s is not None:
            return self.analyse_range(start_s if start_s is not None else 0.0,
                                      end_s if end_s is not None else source.duration_s)
        if whole or source.still is None:
            return self.analyse_whole(how)
        return self.analyse_still()

    def analyse_still(self) -> RestCalibration | None:
        """The source's longest still interval."""
        return self._analyse_source(lambda source: analyse_still(source))

    def analyse_whole(self, how: str | None = None) -> RestCalibration | None:
        """Every sample of the source."""
        how = how if isinstance(how, str) else None       # (a button's "checked" argument)
        return self._analyse_source(lambda source: analyse_stretch(source, how=how))

    def analyse_range(self, start_s: float, end_s: float) -> RestCalibration | None:
        """[start_s, end_s] seconds from the source's start."""
        return self._analyse_source(lambda source: analyse_stretch(source, start_s, end_s))

    def _analyse_source(self, analyse) -> RestCalibration | None:
        if self.source is None:
            return None
        try:
            result = analyse(self.source)
        except config.ConfigError as error:
            self.status.setText(str(error))
            self._show_stretch(self.result)         # the range goes back to what is shown
            return None
        self.show_result(result)
        return result

    def _stretch_s(self, result: RestCalibration | None) -> tuple[float, float]:
        """The analysed stretch in seconds from the source's start."""
        source = self.source
        if result is None or result.interval_s is None:
            return (0.0, source.duration_s)
        low, high = result.interval_s
        return (low - source.origin_s, high - source.origin_s)

    def _show_stretch(self, result: RestCalibration | None) -> None:
        """The whole source on the Time series with the analysed stretch as the range, and
        what was analysed in words."""
        source = self.source
        if source is None:
            return
        reference = (None if result is None else
                     {name: np.asarray(result.analysis.series[name][1]).mean(axis=0)
                      for name in ("acc", "gyr", "mag")
                      if len(result.analysis.series.get(name, ((), ()))[0])})
        for plot, region, sensor in zip(self.series_plots, self.regions, ("acc", "gyr", "mag")):
            figures.draw_whole_series(plot, source.series["t_" + sensor],
                                      source.series[sensor], source.origin_s,
                                      (reference or {}).get(sensor), sensor, source.moving_s)
            plot.addItem(region, ignoreBounds=True)
            region.setBounds((0.0, max(source.duration_s, 1e-3)))
            # one time axis, under the three (their x is linked): room for the curves
            plot.showAxis("bottom", plot is self.series_plots[-1])
        low, high = self._stretch_s(result)
        self._moving_regions = True
        for region in self.regions:
            region.setRegion((low, high))
        self._moving_regions = False
        how = result.how if result is not None else "nothing analysed"
        moved = result is not None and "moved" in result.analysis.warning_kinds()
        hint = ("drag the blue range over a still stretch on the Time series, or take the "
                "longest still one" if moved else
                "drag the blue range on the Time series to analyse another stretch")
        self.stretch_label.setText(
            f"Analysed {low:.1f}–{high:.1f} s of {source.name} ({source.duration_s:.1f} s): "
            f"{how}; {hint}")
        self.still_button.setEnabled(source.still is not None)
        self.still_button.setToolTip(
            "analyse the longest stretch in which the phone lay still (what `calibrate` takes "
            "by default)" if source.still is not None else
            "the phone lay still for no stretch of 1 s")

    def _sync_regions(self, moved: pg.LinearRegionItem) -> None:
        if self._moving_regions:
            return
        self._moving_regions = True
        for region in self.regions:
            if region is not moved:
                region.setRegion(moved.getRegion())
        self._moving_regions = False

    def _on_region_dragged(self, region: pg.LinearRegionItem) -> None:
        if self._moving_regions or self.source is None:
            return
        low, high = region.getRegion()
        if (low, high) != tuple(self._stretch_s(self.result)):
            self.analyse_range(max(float(low), 0.0), min(float(high), self.source.duration_s))

    def feed(self, chunk: Any) -> None:
        if self.collector is None:
            return
        self.collector.add(chunk)
        self.progress.setValue(int(100 * min(1.0, self.collector.elapsed_s
                                              / max(self.duration.value(), 1e-9))))
        if self.collector.done:
            self.progress.setValue(100)
            self.stop()

    def analyse(self, series: dict[str, np.ndarray], how: str) -> RestCalibration | None:
        try:
            result = analyse_series(series, how=how)
        except config.ConfigError as error:
            self.status.setText(str(error))
            return None
        self.show_result(result)
        return result

    def show_result(self, result: RestCalibration) -> None:
        self.result = result
        analysis = result.analysis
        self.status.setText(f"{result.how}: {analysis.duration_s:.1f} s analysed")
        if self.source is not None and result.interval_s is not None:
            low, high = self._stretch_s(result)
            self.status.setText(f"{result.how}: {low:.1f}–{high:.1f} s from the start, "
                                f"{analysis.duration_s:.1f} s analysed")
        for text in self.no_data:
            text.set_text("")
        self.warnings.setText("\n".join("⚠ " + w.message for w in analysis.warnings))
        histograms = analysis.result.histograms()
        for r, sensor in enumerate(("acc", "gyr", "mag")):
            for c in range(3):
                plot = self.histogram_plots[r][c]
                if sensor in histograms:
                    figures.draw_histogram(plot, histograms[sensor][c], figures.AXIS_COLOURS[c])
                else:
                    plot.clear()
                    plot.setTitle(f"{sensor}: no samples", size="8pt")
            if self.source is None:
                figures.draw_series(self.series_plots[r], analysis, sensor)
                self.series_plots[r].showAxis("bottom", True)
            figures.draw_autocorrelation(self.acf_plots[r], analysis, sensor)
        self._show_stretch(result)
        self._fill_table(result)
        self.analysed.emit(result)

    def _fill_table(self, result: RestCalibration) -> None:
        stats = result.analysis.result
        rows = []
        for sensor, reports in result.analysis.axes.items():
            cov = stats.sensor(sensor).cov
            unit = UNITS[sensor]
            for k, report in enumerate(reports):
                verdict = report.verdict + (", correlated" if report.correlated else "")
                rows.append([f"{sensor} [{unit}]", report.axis, f"{report.mean:.6g}",
                             f"{report.std:.3g}", verdict, f"{report.normality_p:.3g}",
                             f"{report.anderson:.3g} ({report.anderson_critical:.3g})",
                             f"{report.acf[1]:.2f}" if len(report.acf) > 1 else "",
                             *(f"{v:.2e}" for v in cov[k])])
        self.table.setRowCount(len(rows))
        for r, row in enumerate(rows):
            for c, text in enumerate(row):
                item = QtWidgets.QTableWidgetItem(text)
                if TABLE_COLUMNS[c][0] == "verdict":
                    item.setToolTip(VERDICT_RULE)
                self.table.setItem(r, c, item)
        self.table.resizeColumnsToContents()


class AllanTab(QtWidgets.QWidget):
    """The Allan deviation of the rest recording's gyroscope (any length: a longer Start gives
    the bias instability), with ARW and bias instability read off and drawn."""

    def __init__(self, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.plot_widget = pg.PlotWidget(axisItems=figures.log_axes())
        self.plot_widget.setBackground("w")
        self.plot = self.plot_widget.getPlotItem()
        self.summary = label("Record at rest (the At rest tab; minutes for the bias "
                              "instability) to see the gyroscope's Allan deviation.")
        layout = QtWidgets.QVBoxLayout(self)
        layout.addWidget(self.summary)
        layout.addWidget(self.plot_widget, 1)
        self.allan = None
        self.no_data = NoDataText(self.plot.getViewBox())
        self.no_data.set_text("no data: record at rest first")

    def show_result(self, allan: Any) -> None:
        self.allan = allan
        figures.draw_allan(self.plot, allan)
        self.no_data.set_text("no gyroscope samples" if allan is None else "")
        if allan is None:
            self.summary.setText("too few gyroscope samples for an Allan deviation")
            return
        lines = []
        for a in allan.axes:
            bound = " (upper bound: record longer)" if a.bias_instability_is_bound else ""
            lines.append(f"{a.axis}: angle random walk {a.arw:.3e} rad/√s "
                         f"({np.degrees(a.arw) * 60:.3f} °/√h), bias instability "
                         f"{a.bias_instability:.3e} rad/s "
                         f"({np.degrees(a.bias_instability) * 3600:.2f} °/h){bound}")
        self.summary.setText("\n".join(lines))


class MagTab(QtWidgets.QWidget):
    """Start collects magnetometer readings while the user turns the phone; the cloud fills a
    sphere live (2D projections; a 3D view too with use_gl), with coverage, fit error and the
    ‖m‖ spread before/after updated as readings come in."""

    fitted = QtCore.Signal(object)          # MagCalibration

    def __init__(self, use_gl: bool = False, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.readings: list[np.ndarray] = []
        self.count = 0
        self._fitted_at = 0
        self.collecting = False
        self.result: magcal.MagCalibration | None = None
        self.start_button = QtWidgets.QPushButton("Start")
        self.start_button.clicked.connect(self.toggle)
        self.clear_button = QtWidgets.QPushButton("Clear")
        self.clear_button.clicked.connect(self.clear)
        self.from_log_button = QtWidgets.QPushButton("From log…")
        self.from_log_button.setToolTip("fit the magnetometer readings of a log in which the "
                                        "phone was turned in every direction")
        self.coverage_bar = QtWidgets.QProgressBar()
        self.coverage_bar.setFormat("coverage %p %")
        self.summary = label("Press Start and turn the phone slowly in every direction.")
        controls = QtWidgets.QHBoxLayout()
        for w in (self.start_button, self.clear_button, self.from_log_button, self.coverage_bar):
            controls.addWidget(w)
        self.cloud = pg.GraphicsLayoutWidget()
        self.cloud.setBackground("w")
        self.projection_plots = [self.cloud.addPlot(row=0, col=k) for k in range(3)]
        self.no_data = [NoDataText(plot.getViewBox()) for plot in self.projection_plots]
        self._show_no_data(True)
        self.view3d = self._make_3d() if use_gl else None
        layout = QtWidgets.QVBoxLayout(self)
        layout.addLayout(controls)
        layout.addWidget(self.summary)
        if self.view3d is not None:
            layout.addWidget(self.view3d, 2)
        layout.addWidget(self.cloud, 1)

    def _make_3d(self) -> QtWidgets.QWidget:
        import pyqtgraph.opengl as gl     # needs OpenGL: only with use_gl

        view = gl.GLViewWidget()
        view.setCameraPosition(distance=150)
        self.scatter3d = gl.GLScatterPlotItem(pos=np.zeros((1, 3)), size=3.0)
        view.addItem(self.scatter3d)
        return view

    def toggle(self) -> None:
        """Start a new cloud, or stop and fit it."""
        if not self.collecting:
            self.clear()
        self.collecting = not self.collecting
        self.start_button.setText("Stop" if self.collecting else "Start")
        if not self.collecting and self.count >= magcal.MIN_SAMPLES:
            self.refit()

    def clear(self) -> None:
        self.readings, self.count, self._fitted_at, self.result = [], 0, 0, None
        self.coverage_bar.setValue(0)
        figures.draw_projections(self.projection_plots, np.empty((0, 3)), None)
        self._show_no_data(True)
        self.summary.setText("cleared")

    def _show_no_data(self, empty: bool) -> None:
        for text in self.no_data:
            text.set_text(NO_MAG_DATA if empty else "")

    def all_readings(self) -> np.ndarray:
        return np.concatenate(self.readings) if self.readings else np.empty((0, 3))

    def feed(self, chunk: Any) -> None:
        if not self.collecting:
            return
        mag = np.asarray(chunk.mag, dtype=float).reshape(-1, 3)
        mag = mag[np.all(np.isfinite(mag), axis=1)]
        if len(mag) == 0:
            return
        self.readings.append(mag)
        self.count += len(mag)
        if self.count - self._fitted_at >= MAG_FIT_EVERY:
            self.refit()

    def refit(self) -> magcal.MagCalibration | None:
        readings = self.all_readings()
        self._fitted_at = self.count
        thinned = (readings if len(readings) <= MAG_FIT_POINTS else
                   readings[np.linspace(0, len(readings) - 1, MAG_FIT_POINTS).astype(int)])
        try:
            result = magcal.calibrate_magnetometer(thinned)
        except ValueError as error:
            self.summary.setText(str(error))
            return None
        self.show_result(result, readings)
        return result

    def show_result(self, result: magcal.MagCalibration, readings: np.ndarray) -> None:
        self.result = result
        self.coverage_bar.setValue(int(round(100 * result.coverage)))
        figures.draw_projections(self.projection_plots, readings, result)
        self._show_no_data(len(readings) == 0)
        if self.view3d is not None and len(readings):
            self.scatter3d.setData(pos=result.correct(readings))
        offset = ", ".join(f"{v:.1f}" for v in result.offset)
        self.summary.setText(
            f"{self.count} readings, {result.model} fit; coverage {100 * result.coverage:.0f} %; "
            f"fit error {result.fit_error_pct:.2f} %; offset ({offset}) µT; field "
            f"{result.field_strength:.1f} µT; ‖m‖ spread {result.norm_std_before:.2f} → "
            f"{result.norm_std_after:.2f} µT" + (f"\n{result.message}" if result.message else ""))
        self.fitted.emit(result)


class CalibrationWorkspace(QtWidgets.QWidget):
    """The three tabs and the profile bar. send(command): the engine's send; settings(): the
    settings in use (the base Apply completes); store: profiles (None: the data folder);
    use_gl: also a 3D view of the magnetometer cloud (needs OpenGL)."""

    applied = QtCore.Signal(object)      # the ekf.EKFSettings sent by Apply

    def __init__(self, send: Callable[[Any], None],
                 settings: Callable[[], ekf.EKFSettings | None] = lambda: None,
                 store: ProfileStore | None = None, use_gl: bool = False,
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self._send = send
        self._settings = settings
        self.store = store or ProfileStore()
        self.loaded: Profile | None = None
        self.rest = RestTab()
        self.allan = AllanTab()
        self.mag = MagTab(use_gl)
        self.rest.analysed.connect(lambda result: self.allan.show_result(result.allan))
        self.rest.from_log_button.clicked.connect(self._from_log_dialog)
        self.mag.from_log_button.clicked.connect(self._mag_from_log_dialog)
        self.tabs = QtWidgets.QTabWidget()
        self.tabs.addTab(self.rest, "At rest")
        self.tabs.addTab(self.allan, "Gyro noise")
        self.tabs.addTab(self.mag, "Magnetometer")
        self.name = QtWidgets.QLineEdit()
        self.name.setPlaceholderText("profile name, e.g. the phone")
        self.apply_button = QtWidgets.QPushButton("Apply")
        self.apply_button.clicked.connect(self.apply)
        self.save_button = QtWidgets.QPushButton("Save profile")
        self.save_button.clicked.connect(lambda: self.save_profile())
        self.profiles = QtWidgets.QComboBox()
        self.load_button = QtWidgets.QPushButton("Load profile")
        self.load_button.clicked.connect(lambda: self.load_profile(self.profiles.currentText()))
        self.message = label()
        bar = QtWidgets.QHBoxLayout()
        for w in (QtWidgets.QLabel("Profile"), self.name, self.apply_button, self.save_button,
                  self.profiles, self.load_button):
            bar.addWidget(w)
        layout = QtWidgets.QVBoxLayout(self)
        layout.addWidget(self.tabs, 1)
        layout.addLayout(bar)
        layout.addWidget(self.message)
        self.refresh_profiles()

    # -- data in ------------------------------------------------------------------------------

    def feed(self, snapshot: Any) -> None:
        """Every polled snapshot (only snapshot.plot is read)."""
        if snapshot is None:
            return
        self.rest.feed(snapshot.plot)
        self.mag.feed(snapshot.plot)

    def analyse_log(self, path: str | Path, start_s: float | None = None,
                    end_s: float | None = None, whole: bool = False) -> bool:
        """A stretch of a log (seconds from its start; all of it with `whole`; neither: its
        longest still interval) in the At rest tab, where another stretch can be dragged, and
        its magnetometer readings in the Magnetometer tab."""
        try:
            log = config.open_log(path)
            source = rest_source(log)
        except config.ConfigError as error:
            self.message.setText(str(error))
            return False
        rest = self.rest.load_source(source, start_s, end_s, whole)
        if rest is None:
            self.message.setText(self.rest.status.text())
            return False
        try:
            mag, raw = mag_from_log(log, start_s, end_s)
            self.mag.count = len(raw)
            self.mag.show_result(mag, raw)
        except config.ConfigError:
            pass    # a still stretch is no magnetometer fit (the tab keeps what it had)
        self.message.setText(f"{Path(path).name}: {rest.how}")
        return True

    def analyse_mag_log(self, path: str | Path, start_s: float | None = None,
                        end_s: float | None = None) -> bool:
        """The magnetometer readings of a log (or a stretch of it) fitted in the Magnetometer
        tab; a log in which the phone hardly turned says so there."""
        try:
            mag, raw = mag_from_log(config.open_log(path), start_s, end_s)
        except config.ConfigError as error:
            self.mag.summary.setText(str(error))
            return False
        self.mag.count = len(raw)
        self.mag.show_result(mag, raw)
        self.message.setText(f"{Path(path).name}: magnetometer fitted on {len(raw)} readings")
        return True

    def _mag_from_log_dialog(self) -> None:
        path, _ = QtWidgets.QFileDialog.getOpenFileName(self, "Magnetometer fit from a log", "",
                                                        "Logs (*.txt *.txt.gz *.json)")
        if path:
            self.analyse_mag_log(path)

    def _from_log_dialog(self) -> None:
        path, _ = QtWidgets.QFileDialog.getOpenFileName(self, "Calibrate from a log", "",
                                                        "Logs (*.txt *.txt.gz *.json)")
        if path:
            self.analyse_log(path)

    # -- profiles -----------------------------------------------------------------------------

    def profile(self) -> Profile:
        """What the tabs hold now as a profile (a loaded profile's parts fill the gaps)."""
        base = self.loaded
        name = self.name.text().strip() or (base.name if base else "unnamed phone")
        rest = self.rest.result
        return Profile(
            name,
            rest=rest.analysis.result.to_dict() if rest else (base.rest if base else None),
            allan=(rest.allan.to_dict() if rest and rest.allan else
                   (base.allan if base else None)),
            mag=self.mag.result.to_dict() if self.mag.result else (base.mag if base else None),
            settings=base.settings if base else None, tuning=base.tuning if base else None)

    def apply(self) -> ekf.EKFSettings | None:
        profile = self.profile()
        if not (profile.rest or profile.mag or profile.settings):
            self.message.setText("nothing to apply yet: calibrate first, or load a profile")
            return None
        settings = profile.to_settings(self._settings())
        self._send(SetSettings(settings, calibration=profile.to_dict(), source="calibration"))
        warnings = profile.warnings(settings)
        self.message.setText(f"applied {profile.name!r}: g, m0, gyro bias"
                             + (", magnetometer correction" if profile.mag else "")
                             + "".join(f"; warning: {text}" for text in warnings))
        self.applied.emit(settings)
        return settings

    def save_profile(self, name: str | None = None) -> Path | None:
        if name:
            self.name.setText(name)
        profile = self.profile()
        try:
            path = self.store.save(profile)
        except config.ConfigError as error:
            self.message.setText(str(error))
            return None
        self.refresh_profiles()
        self.message.setText(f"profile {profile.name!r} saved to {path}")
        return path

    def load_profile(self, name: str) -> Profile | None:
        try:
            profile = self.store.load(name)
        except config.ConfigError as error:
            self.message.setText(str(error))
            return None
        self.loaded = profile
        self.name.setText(profile.name)
        self.rest.result = None
        self.mag.result = None
        parts = [p for p in ("rest", "allan", "mag", "settings") if getattr(profile, p)]
        self.message.setText(f"profile {profile.name!r} loaded ({', '.join(parts) or 'empty'}): "
                             "Apply to use it")
        return profile

    def refresh_profiles(self) -> None:
        self.profiles.clear()
        self.profiles.addItems(self.store.names())
