"""The consistency view: is a Kalman filter's picture of its own errors right?

For one estimator (OWN: our EKF; YOURS: your filter, when it returns innovations) and one
sensor, from the innovations nu and their covariances S the engine publishes (PlotChunk's
innovation fields; see app.engine.processing.innovations):

* each innovation component over time with its +-2 sigma and +-3 sigma bands, sigma_i =
  sqrt(S_ii), the updates a gate rejected marked with a red x;
* the normalised innovation squared NIS = nu^T S^-1 nu over time, with the two-sided 95 %
  bounds of chi^2(k) (k = the innovation's dimension), and the fraction of the accepted updates
  inside them (a consistent filter: 95 %);
* a histogram of the normalised innovations (S^-1/2 nu, the components pooled, accepted
  updates) against the N(0, 1) density.

Mount: ``view = ConsistencyView(window.send)``; each frame ``view.apply_snapshot(snapshot)``
(it keeps its own history). While shown it asks the engine for our EKF's innovations
(SetConsistencyEnabled(True), sent on show, False on hide: they cost a little per sample).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets

from app.engine.commands import SetConsistencyEnabled
from app.engine.snapshot import INNOVATION_SENSORS, INNOVATION_SOURCES, PlotChunk, Snapshot

#: Two-sided 95 % interval of chi^2(k): (2.5 %, 97.5 %) quantiles.
CHI2_95 = {1: (0.000982069, 5.023886), 2: (0.05063562, 7.377759), 3: (0.2157953, 9.348404)}
COMPONENT_COLOURS = ((220, 50, 50), (40, 150, 40), (40, 90, 220))
SUMMARY_LINES = 3               # the summary's lines kept in view at least
REFRESH_S = 0.25
SENSOR_UNITS = ("m/s²", "µT", "rad/s")      # of the innovations, per INNOVATION_SENSORS


class InnovationSeries:
    """The latest `capacity` innovations of one estimator and sensor (a ring buffer)."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.clear()

    def clear(self) -> None:
        c = self.capacity
        self._t = np.empty(c)
        self._nu = np.empty((c, 3))
        self._S = np.empty((c, 3, 3))
        self._accepted = np.empty(c, bool)
        self.size = 0
        self._next = 0

    def extend(self, t: np.ndarray, nu: np.ndarray, S: np.ndarray, accepted: np.ndarray) -> None:
        n = len(t)
        if n > self.capacity:
            t, nu, S, accepted = t[-self.capacity:], nu[-self.capacity:], S[-self.capacity:], \
                accepted[-self.capacity:]
            n = self.capacity
        where = (self._next + np.arange(n)) % self.capacity
        self._t[where], self._nu[where], self._S[where] = t, nu, S
        self._accepted[where] = accepted
        self._next = (self._next + n) % self.capacity
        self.size = min(self.capacity, self.size + n)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """t, nu (n, 3), S (n, 3, 3), accepted, oldest first."""
        order = (self._next - self.size + np.arange(self.size)) % self.capacity
        return self._t[order], self._nu[order], self._S[order], self._accepted[order]


def consistency(nu: np.ndarray, S: np.ndarray, accepted: np.ndarray) -> dict:
    """The statistics the view shows, for innovations of one dimension k (the first k
    components finite): nis (n,), sigma (n, k), z (normalised innovations of the accepted
    updates, pooled), bounds (chi^2 95 %), inside (fraction of accepted NIS within them)."""
    n = len(nu)
    k = int(np.isfinite(nu[-1]).sum()) if n else 0
    out = {"k": k, "n": n, "rejected": int((~accepted).sum()), "nis": np.empty(0),
           "sigma": np.empty((0, max(k, 1))), "z": np.empty(0), "bounds": CHI2_95.get(k),
           "inside": math.nan, "mean_nis": math.nan}
    if not n or not k:
        return out
    nu, S = nu[:, :k], S[:, :k, :k]
    good = np.isfinite(nu).all(axis=1) & np.isfinite(S.reshape(n, -1)).all(axis=1)
    nis = np.full(n, np.nan)
    z = np.full((n, k), np.nan)
    try:
        L = np.linalg.cholesky(S[good])
        z[good] = np.linalg.solve(L, nu[good][..., None])[..., 0]
    except np.linalg.LinAlgError:      # a covariance that is not positive definite
        z[good] = nu[good] / np.sqrt(np.abs(np.diagonal(S[good], axis1=1, axis2=2)))
    nis[good] = np.sum(z[good] ** 2, axis=1)
    out["nis"] = nis
    out["sigma"] = np.sqrt(np.abs(np.diagonal(S, axis1=1, axis2=2)))
    used = good & accepted
    out["z"] = z[used].ravel()
    if used.any():
        low, high = out["bounds"]
        out["inside"] = float(np.mean((nis[used] >= low) & (nis[used] <= high)))
        out["mean_nis"] = float(np.mean(nis[used]))
    return out


class ConsistencyView(QtWidgets.QWidget):
    """Innovations with their sigma bands, the NIS with chi^2 bounds, a histogram against
    N(0, 1); one estimator (OWN / YOURS) and sensor at a time."""

    def __init__(self, send: Callable[[object], None] | None = None, capacity: int = 20_000,
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("consistency_view")
        self.send = send
        self.series = {(source, sensor): InnovationSeries(capacity)
                       for source in range(len(INNOVATION_SOURCES))
                       for sensor in range(len(INNOVATION_SENSORS))}
        self._user_generation: int | None = None
        self._dirty = True
        self.stats: dict = {}
        layout = QtWidgets.QVBoxLayout(self)
        layout.addLayout(self._controls())
        self.summary = QtWidgets.QLabel("")
        self.summary.setWordWrap(True)
        layout.addWidget(self.summary)
        self.graphics = pg.GraphicsLayoutWidget()
        self.graphics.setBackground((250, 250, 252))    # as the live plots
        layout.addWidget(self.graphics, 1)
        self._build_plots()
        self._timer = QtCore.QTimer(self)
        self._timer.timeout.connect(self._tick)
        self._asked = False          # innovations asked of the engine (while shown)
        self._timer.start(int(REFRESH_S * 1000))

    def _controls(self) -> QtWidgets.QHBoxLayout:
        row = QtWidgets.QHBoxLayout()
        self.source_combo = QtWidgets.QComboBox()
        self.source_combo.addItems(["OWN (our EKF)", "YOURS (your filter)"])
        self.sensor_combo = QtWidgets.QComboBox()
        self.sensor_combo.addItems(["accelerometer", "magnetometer", "gyroscope"])
        for combo in (self.source_combo, self.sensor_combo):
            combo.currentIndexChanged.connect(self._changed)
        self.clear_button = QtWidgets.QPushButton("Clear")
        self.clear_button.clicked.connect(self.clear)
        for widget in (QtWidgets.QLabel("Estimator"), self.source_combo,
                       QtWidgets.QLabel("Sensor"), self.sensor_combo):
            row.addWidget(widget)
        row.addStretch(1)
        row.addWidget(self.clear_button)
        return row

    def _build_plots(self) -> None:
        g = self.graphics
        self.component_plots, self.component_items = [], []
        for axis, colour in zip("xyz", COMPONENT_COLOURS):
            plot = g.addPlot(title=f"innovation {axis} with ±2σ, ±3σ")
            plot.getAxis("left").enableAutoSIPrefix(False)
            plot.getAxis("left").setWidth(64)
            items = {"nu": plot.plot(pen=pg.mkPen(colour, width=1)),
                     "rejected": pg.ScatterPlotItem(symbol="x", size=8, pen=pg.mkPen(200, 0, 0),
                                                    brush=pg.mkBrush(220, 0, 0))}
            for name, style, sign in (("+2", QtCore.Qt.PenStyle.DashLine, 2),
                                      ("-2", QtCore.Qt.PenStyle.DashLine, -2),
                                      ("+3", QtCore.Qt.PenStyle.DotLine, 3),
                                      ("-3", QtCore.Qt.PenStyle.DotLine, -3)):
                items[name] = plot.plot(pen=pg.mkPen((110, 110, 110), width=1, style=style))
            plot.addItem(items["rejected"])
            if self.component_plots:
                plot.setXLink(self.component_plots[0])
            self.component_plots.append(plot)
            self.component_items.append(items)
            g.nextRow()
        self.nis_plot = g.addPlot(title="NIS with the 95 % χ² bounds")
        self.nis_plot.setLabel("left", "NIS")
        self.nis_plot.getAxis("left").setWidth(64)
        self.nis_plot.setLabel("bottom", "time since the session's start", units="s")
        self.nis_plot.getAxis("bottom").enableAutoSIPrefix(False)
        self.nis_plot.setXLink(self.component_plots[0])
        self.nis_curve = self.nis_plot.plot(pen=pg.mkPen((60, 60, 60), width=1))
        self.nis_rejected = pg.ScatterPlotItem(symbol="x", size=8, pen=pg.mkPen(200, 0, 0))
        self.nis_plot.addItem(self.nis_rejected)
        bound_pen = pg.mkPen((200, 120, 0), width=1.5, style=QtCore.Qt.PenStyle.DashLine)
        self.nis_bounds = (pg.InfiniteLine(angle=0, pen=bound_pen),
                           pg.InfiniteLine(angle=0, pen=bound_pen))
        for line in self.nis_bounds:
            self.nis_plot.addItem(line)
        g.nextRow()
        self.hist_plot = g.addPlot(title="normalised innovations vs N(0, 1)")
        self.hist_plot.setLabel("left", "density")
        self.hist_plot.getAxis("left").setWidth(64)
        self.hist_plot.setLabel("bottom", "S^-1/2 ν (pooled components, no unit)")
        self.hist_curve = self.hist_plot.plot(stepMode="center", fillLevel=0,
                                              brush=(80, 130, 220, 120), pen=pg.mkPen(40, 80, 180))
        x = np.linspace(-5, 5, 201)
        self.hist_plot.plot(x, np.exp(-x * x / 2) / math.sqrt(2 * math.pi),
                            pen=pg.mkPen((200, 0, 0), width=2))

    # -- data -----------------------------------------------------------------------------------

    def add_chunk(self, plot: PlotChunk) -> None:
        """Keep the innovations of one snapshot's PlotChunk."""
        n = len(plot.t_innovation)
        if not n:
            return
        for key, series in self.series.items():
            chosen = (plot.innovation_source == key[0]) & (plot.innovation_sensor == key[1])
            if chosen.any():
                series.extend(plot.t_innovation[chosen], plot.innovation[chosen],
                              plot.innovation_cov[chosen], plot.innovation_accepted[chosen])
        self._dirty = True

    def apply_snapshot(self, snapshot: Snapshot) -> None:
        """A snapshot: its innovations; a reloaded user filter starts YOURS afresh."""
        generation = None if snapshot.user is None else snapshot.user.generation
        if generation != self._user_generation:
            self._user_generation = generation
            for (source, _), series in self.series.items():
                if source == INNOVATION_SOURCES.index("YOURS"):
                    series.clear()
            self._dirty = True
        self.add_chunk(snapshot.plot)

    def clear(self) -> None:
        for series in self.series.values():
            series.clear()
        self._dirty = True
        self.refresh()

    def selected(self) -> tuple[int, int]:
        return self.source_combo.currentIndex(), self.sensor_combo.currentIndex()

    def _changed(self) -> None:
        self._dirty = True
        self.refresh()

    # -- drawing --------------------------------------------------------------------------------

    def _tick(self) -> None:
        if self.isVisible():          # hidden (another workspace): drawn when shown again
            self.refresh()

    def refresh(self) -> None:
        """Redraw the selected series if anything changed."""
        if not self._dirty:
            return
        self._dirty = False
        t, nu, S, accepted = self.series[self.selected()].arrays()
        self.stats = stats = consistency(nu, S, accepted)
        self._show_summary(self._summary_text(stats))
        unit = SENSOR_UNITS[self.selected()[1]]
        for plot in self.component_plots:
            plot.setLabel("left", "ν", units=unit)
        k = stats["k"]
        for i, (plot, items) in enumerate(zip(self.component_plots, self.component_items)):
            shown = i < max(k, 1)
            plot.setVisible(shown)
            if not shown:
                continue
            self._draw_component(items, t, nu[:, i] if k else np.empty(0),
                                 stats["sigma"][:, i] if k else np.empty(0), accepted)
        self.nis_curve.setData(t, stats["nis"] if k else np.empty(0))
        rejected = ~accepted
        self.nis_rejected.setData(t[rejected], stats["nis"][rejected] if k else np.empty(0))
        bounds = stats["bounds"]
        for line, value in zip(self.nis_bounds, bounds or (math.nan, math.nan)):
            line.setVisible(bounds is not None)
            if bounds is not None:
                line.setValue(value)
        counts, edges = np.histogram(stats["z"], bins=50, range=(-5, 5), density=True) \
            if len(stats["z"]) else (np.zeros(50), np.linspace(-5, 5, 51))
        self.hist_curve.setData(edges, counts)

    def _show_summary(self, text: str) -> None:
        self.summary.setText(text)
        self._fit_summary()

    def _fit_summary(self) -> None:
        """Keep every line of the summary in view: the plots below give up the height. Three
        lines are kept at least, so the counts growing as the stream runs do not move the
        plots (a narrow view gets more)."""
        needed = self.summary.heightForWidth(max(self.summary.width(), 1))
        margins = self.summary.contentsMargins()
        lines = SUMMARY_LINES * self.summary.fontMetrics().lineSpacing() + margins.top() \
            + margins.bottom()
        if max(needed, lines) != self.summary.minimumHeight():
            self.summary.setMinimumHeight(max(needed, lines))

    def resizeEvent(self, event) -> None:  # noqa: N802 (Qt name)
        super().resizeEvent(event)
        self._fit_summary()

    @staticmethod
    def _draw_component(items: dict, t: np.ndarray, nu: np.ndarray, sigma: np.ndarray,
                        accepted: np.ndarray) -> None:
        items["nu"].setData(t, nu)
        for name, factor in (("+2", 2), ("-2", -2), ("+3", 3), ("-3", -3)):
            items[name].setData(t, factor * sigma)
        rejected = ~accepted
        items["rejected"].setData(t[rejected], nu[rejected])

    def _summary_text(self, stats: dict) -> str:
        source = INNOVATION_SOURCES[self.selected()[0]]
        sensor = self.sensor_combo.currentText()
        if not stats["n"]:
            hint = ("open this view while the stream runs: our EKF's innovations are computed "
                    "while it is shown" if source == "OWN" else
                    "your filter returns none for this sensor (return \"innovations\": "
                    "{\"acc\": (nu, S), ...} from step)")
            return f"{sensor} ({source}): no innovations yet; {hint}"
        low, high = stats["bounds"] or (math.nan, math.nan)
        return (f"{sensor} ({source}): {stats['n']} updates, {stats['rejected']} rejected by "
                f"the gate (×). NIS of the accepted ones inside the 95 % χ²({stats['k']}) "
                f"bounds [{low:.3g}, {high:.3g}]: {stats['inside']:.1%} (a consistent filter: "
                f"95 %); mean NIS {stats['mean_nis']:.2f} (expected {stats['k']})")

    # -- asking the engine -----------------------------------------------------------------------

    def showEvent(self, event) -> None:  # noqa: N802 (Qt name)
        super().showEvent(event)
        if self.send is not None and not self._asked:
            self._asked = True
            self.send(SetConsistencyEnabled(True))

    def hideEvent(self, event) -> None:  # noqa: N802 (Qt name)
        super().hideEvent(event)
        if self.send is not None and self._asked:
            self._asked = False
            self.send(SetConsistencyEnabled(False))
