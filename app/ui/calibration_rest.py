"""The calibration workspace's At rest tab (course task 2): live samples collected for a
duration (Start) or a log (From log…, through the workspace), analysed as `calibrate` does:
histograms with the Gaussian, the time series, Table 1 (means, covariances) with the
normality verdict and the autocorrelation, and the warnings. The stretch analysed is chosen
on the Time series (a range to drag; Longest still and Whole: `calibrate`'s default and
`--whole`). Part of app/ui/calibration.py's CalibrationWorkspace.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets

from ekf.calibration import UNITS
from ekf.noise import VERDICT_RULE
from app.engine import config
from app.engine.tuning.calibration import (RestCalibration, RestSource, SampleCollector,
                                           analyse_series, analyse_still, analyse_stretch,
                                           collected_source)
from app.ui import figures
from app.ui.no_data import NoDataText

NO_REST_DATA = "no data"


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


