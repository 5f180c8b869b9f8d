"""The calibration figures, drawn with pyqtgraph: once for the workspace's plots and once for
the command line's PNG files (``--plots DIR``, rendered offscreen), from the same functions.

* :func:`draw_histogram`: one sensor axis, the probability density with the fitted Gaussian.
* :func:`draw_series`: the rest time series of one sensor, moving stretches shaded.
* :func:`draw_whole_series`: all of a log's (or a collection's) samples of one sensor, moving
  stretches shaded: the workspace's view to choose the stretch on.
* :func:`draw_allan`: Allan deviation log-log per gyro axis, the -1/2 line of the angle random
  walk and the bias-instability minimum marked.
* :func:`draw_projections`: the magnetometer readings as three 2D projections (x-y, x-z, y-z),
  raw and corrected, with the fitted circle.

The command line imports this module only for --plots; it needs Qt (PySide6, pyqtgraph).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets

from ekf.allan import AllanResult
from ekf.calibration import AXES, UNITS, Histogram
from ekf.magcal import MagCalibration
from ekf.noise import RestAnalysis

AXIS_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")     # x red, y green, z blue (the course's)
SENSOR_TITLES = {"acc": "Accelerometer", "gyr": "Gyroscope", "mag": "Magnetometer"}


def ensure_app() -> QtWidgets.QApplication:
    """The running QApplication, or a new offscreen one: the command line's figures are
    files, drawn the same with or without a screen (and a DISPLAY that does not answer cannot
    abort them)."""
    app = QtWidgets.QApplication.instance()
    if app is None:
        if not os.environ.get("QT_QPA_PLATFORM", "").startswith("offscreen"):
            os.environ["QT_QPA_PLATFORM"] = "offscreen"     # (keeps offscreen's own options)
        app = QtWidgets.QApplication([])
    return app


def draw_histogram(plot: pg.PlotItem, histogram: Histogram, colour: str = "#1f77b4") -> None:
    """Density bars and the Gaussian with the sample mean and std (the reports' figure 1)."""
    plot.clear()
    widths = np.diff(histogram.edges)
    plot.addItem(pg.BarGraphItem(x0=histogram.edges[:-1], width=widths,
                                 height=histogram.density, brush=pg.mkBrush(colour + "80"),
                                 pen=pg.mkPen(colour)))
    plot.plot(histogram.pdf_x, histogram.pdf, pen=pg.mkPen("k", width=2))
    unit = UNITS[histogram.sensor]
    plot.setTitle(f"{histogram.sensor} {histogram.axis}: μ={histogram.mean:.4g}, "
                  f"σ={histogram.std:.3g} {unit}", size="8pt")


def draw_series(plot: pg.PlotItem, analysis: RestAnalysis, sensor: str) -> None:
    """One sensor's rest samples (x, y, z about their means) against time from the start, with
    the stretches judged moving shaded."""
    plot.clear()
    if sensor not in analysis.series or len(analysis.series[sensor][0]) == 0:
        plot.setTitle(f"{sensor}: no samples", size="8pt")
        return
    t, values = analysis.series[sensor]
    origin = analysis.t_s[0] if len(analysis.t_s) else t[0]
    mean = values.mean(axis=0)
    for k, colour in enumerate(AXIS_COLOURS):
        plot.plot(t - origin, values[:, k] - mean[k], pen=pg.mkPen(colour), name=AXES[k])
    for warning in analysis.warnings:
        for start, end in warning.intervals_s:
            region = pg.LinearRegionItem((start - origin, end - origin), movable=False,
                                         brush=pg.mkBrush(255, 140, 0, 60))
            plot.addItem(region)
    plot.setTitle(f"{SENSOR_TITLES[sensor]} minus its mean [{UNITS[sensor]}]", size="8pt")
    plot.setLabel("bottom", "time", units="s")


def draw_whole_series(plot: pg.PlotItem, t_s: np.ndarray, values: np.ndarray, origin_s: float,
                      reference: np.ndarray | None, sensor: str,
                      moving_s: list[tuple[float, float]]) -> None:
    """All of a source's samples of one sensor (a log, or what was collected), in seconds from
    `origin_s`, about `reference` (the analysed stretch's mean; None: their own), with the
    stretches in which the phone moved shaded: the view to choose a stretch on."""
    plot.clear()
    if len(t_s) == 0:
        plot.setTitle(f"{sensor}: no samples", size="8pt")
        return
    centre = values.mean(axis=0) if reference is None else np.asarray(reference, float)
    for k, colour in enumerate(AXIS_COLOURS):
        plot.plot(t_s - origin_s, values[:, k] - centre[k], pen=pg.mkPen(colour), name=AXES[k])
    for start, end in moving_s:
        plot.addItem(pg.LinearRegionItem((start, end), movable=False,
                                         brush=pg.mkBrush(255, 140, 0, 60)), ignoreBounds=True)
    plot.setTitle(f"{SENSOR_TITLES[sensor]} minus the stretch's mean [{UNITS[sensor]}] "
                  "(orange: moved)", size="8pt")
    plot.setLabel("bottom", "time", units="s")


def draw_autocorrelation(plot: pg.PlotItem, analysis: RestAnalysis, sensor: str) -> None:
    plot.clear()
    for k, report in enumerate(analysis.axes.get(sensor, [])):
        lags = np.arange(len(report.acf)) * report.lag_s
        plot.plot(lags, report.acf, pen=pg.mkPen(AXIS_COLOURS[k]), name=report.axis)
    plot.addLine(y=np.exp(-1.0), pen=pg.mkPen("#888", style=QtCore.Qt.PenStyle.DashLine))
    plot.setTitle(f"{SENSOR_TITLES[sensor]}: autocorrelation", size="8pt")
    plot.setLabel("bottom", "lag", units="s")


class LogAxis(pg.AxisItem):
    """A log axis that labels 1, 2 and 5 of each decade where they fit, and only the decades
    where they do not (the plain axis labels every minor tick, and they overlap)."""

    LABEL_PX = {"horizontal": 52.0, "vertical": 18.0}

    def logTickStrings(self, values, scale, spacing):
        strings = super().logTickStrings(values, scale, spacing)
        low, high = self.range
        horizontal = self.orientation in ("top", "bottom")
        length = self.geometry().width() if horizontal else self.geometry().height()
        per_decade = length / max(high - low, 1e-9)
        room = self.LABEL_PX["horizontal" if horizontal else "vertical"]
        kept = (1, 2, 5) if np.log10(2.5) * per_decade >= room else (1,)
        return [text if self.labelled(value, kept) else ""
                for value, text in zip(values, strings)]

    @staticmethod
    def labelled(value: float, kept: tuple[int, ...]) -> bool:
        """Whether the tick at log10 value `value` is one of the mantissas `kept`."""
        mantissa = 10.0 ** (value - np.floor(value + 1e-9))
        return any(abs(mantissa - k) < 1e-6 * k for k in kept)


def log_axes() -> dict[str, LogAxis]:
    """axisItems for a log-log plot (pg.PlotWidget(axisItems=...), addPlot(axisItems=...))."""
    return {"bottom": LogAxis("bottom"), "left": LogAxis("left")}


def draw_allan(plot: pg.PlotItem, allan: AllanResult | None) -> None:
    """σ(τ) per axis on log-log axes; dashed: the ARW line N/√τ; dots: the bias-instability
    minimum; a dot at τ = 1 s on each ARW line (N is read there)."""
    plot.clear()
    plot.setLogMode(x=True, y=True)
    plot.getAxis("left").enableAutoSIPrefix(False)
    plot.setLabel("bottom", "τ", units="s")
    plot.setLabel("left", "Allan deviation [rad/s]")
    if allan is None:
        plot.setTitle("Allan deviation: no gyroscope samples", size="9pt")
        return
    plot.addLegend(offset=(-10, 10))
    for k, axis in enumerate(allan.axes):
        colour = AXIS_COLOURS[k]
        plot.plot(axis.taus, axis.adev, pen=pg.mkPen(colour, width=2), symbol="o",
                  symbolSize=4, symbolBrush=colour, name=f"{axis.axis}: N={axis.arw:.2e} "
                                                          f"B={axis.bias_instability:.2e}")
        taus = np.array([min(axis.taus[0], 1.0), max(axis.taus[-1], 1.0)])
        plot.plot(*axis.arw_line(taus), pen=pg.mkPen(colour, style=QtCore.Qt.PenStyle.DashLine))
        plot.plot([1.0], [axis.arw], pen=None, symbol="s", symbolBrush=colour, symbolSize=8)
        plot.plot([axis.bias_instability_tau_s], [axis.bias_instability * 0.664], pen=None,
                  symbol="t", symbolBrush=colour, symbolSize=10)
    plot.setTitle(f"Gyroscope Allan deviation ({allan.duration_s:.0f} s at "
                  f"{allan.rate_hz:.0f} Hz)", size="9pt")


PROJECTIONS = ((0, 1), (0, 2), (1, 2))


def draw_projections(plots: list[pg.PlotItem], raw: np.ndarray,
                     calibration: MagCalibration | None, max_points: int = 4000) -> None:
    """Three 2D views of the readings: raw (grey) and corrected (blue), with the fitted sphere's
    circle about the origin (the 3D cloud's fallback where there is no OpenGL)."""
    raw = np.asarray(raw, float).reshape(-1, 3)
    if len(raw) > max_points:
        raw = raw[np.linspace(0, len(raw) - 1, max_points).astype(int)]
    corrected = calibration.correct(raw) if calibration is not None else None
    angle = np.linspace(0, 2 * np.pi, 181)
    for plot, (i, j) in zip(plots, PROJECTIONS):
        plot.clear()
        plot.setAspectLocked(True)
        plot.addItem(pg.ScatterPlotItem(raw[:, i], raw[:, j], size=3, pen=None,
                                        brush=pg.mkBrush(120, 120, 120, 120)))
        if corrected is not None:
            plot.addItem(pg.ScatterPlotItem(corrected[:, i], corrected[:, j], size=3, pen=None,
                                            brush=pg.mkBrush(31, 119, 180, 160)))
            r = calibration.field_strength
            plot.plot(r * np.cos(angle), r * np.sin(angle), pen=pg.mkPen("k"))
        plot.setLabel("bottom", f"m{AXES[i]} [uT]")
        plot.setLabel("left", f"m{AXES[j]} [uT]")


# ---- PNG files ------------------------------------------------------------------------------------

def _export(widget: pg.GraphicsLayoutWidget, path: Path) -> Path:
    from pyqtgraph.exporters import ImageExporter

    widget.show()                          # lays the plots out at the widget's size
    QtWidgets.QApplication.processEvents()
    exporter = ImageExporter(widget.scene())
    exporter.parameters()["width"] = widget.width()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        exporter.export(str(path))
    finally:
        widget.close()
    if not path.is_file():
        raise OSError(f"{path} was not written")
    return path


def _layout(width: int, height: int) -> pg.GraphicsLayoutWidget:
    ensure_app()
    widget = pg.GraphicsLayoutWidget()
    widget.setBackground("w")
    widget.resize(width, height)
    return widget


def save_rest_figures(analysis: RestAnalysis, allan: AllanResult | None,
                      folder: str | Path) -> list[Path]:
    """rest_histograms.png, rest_timeseries.png, rest_autocorrelation.png and gyro_allan.png
    in `folder` (created); returns the files written."""
    folder = Path(folder)
    histograms = analysis.result.histograms()
    written = []
    grid = _layout(1500, 300 * max(len(histograms), 1))
    for row, (sensor, per_axis) in enumerate(histograms.items()):
        for col, histogram in enumerate(per_axis):
            draw_histogram(grid.addPlot(row=row, col=col), histogram, AXIS_COLOURS[col])
    written.append(_export(grid, folder / "rest_histograms.png"))
    for name, draw in (("rest_timeseries.png", draw_series),
                       ("rest_autocorrelation.png", draw_autocorrelation)):
        grid = _layout(1200, 800)
        for row, sensor in enumerate(("acc", "gyr", "mag")):
            draw(grid.addPlot(row=row, col=0), analysis, sensor)
        written.append(_export(grid, folder / name))
    grid = _layout(900, 650)
    draw_allan(grid.addPlot(axisItems=log_axes()), allan)
    written.append(_export(grid, folder / "gyro_allan.png"))
    return written


def save_mag_figures(calibration: MagCalibration, raw: np.ndarray,
                     folder: str | Path) -> list[Path]:
    """mag_cloud.png (three projections, raw and corrected) in `folder`."""
    grid = _layout(1500, 520)
    plots = [grid.addPlot(row=0, col=k) for k in range(3)]
    draw_projections(plots, raw, calibration)
    grid.addLabel(f"coverage {100 * calibration.coverage:.0f} %, fit error "
                  f"{calibration.fit_error_pct:.2f} %, |m| {calibration.norm_std_before:.2f} -> "
                  f"{calibration.norm_std_after:.2f} uT std", row=1, col=0, colspan=3)
    return [_export(grid, Path(folder) / "mag_cloud.png")]
