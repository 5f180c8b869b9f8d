"""Live plots in the phone's time: accelerometer, gyroscope, magnetometer, Euler angles, angle.

Samples arrive in PlotChunks (one per display frame) and go into preallocated numpy buffers
of bounded size; the curves are redrawn at most once per display frame, only over the
visible window. Following shows the last `window_s` seconds; pausing (button, Space, or
dragging/zooming a plot) freezes the view while samples keep being stored, Follow resumes.
Clicking a legend entry hides/shows that curve. The cursor reads every visible curve.
"""

from __future__ import annotations

import math

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets

from app.engine.snapshot import FilterStatus, PlotChunk

DEFAULT_WINDOW_S = 10.0
MAX_WINDOW_S = 120.0
# Rows kept per stream: 2 minutes at 500 Hz. The buffer holds up to twice this before it
# drops the oldest half, so memory is bounded (about 6 MB for the widest stream).
BUFFER_ROWS = 60_000
XYZ_COLORS = ((220, 50, 50), (40, 170, 60), (50, 100, 230), (90, 90, 90))
# PHONE's Euler angles: the same hues, lighter. Solid 1-px pens only: wider or dashed pens
# take Qt's slow stroking path and cost several times the frame time at 500 Hz.
PHONE_COLORS = ((245, 150, 150), (140, 215, 150), (150, 180, 250))
EULER_NAMES = ("yaw", "pitch", "roll")
LEFT_AXIS_WIDTH = 62        # px, the same for every plot so their time axes line up


class SampleBuffer:
    """Time-stamped rows in one contiguous float64 array, bounded in size.

    Appending is amortised O(1): rows are written after the last one, and when the array
    is full the newest `capacity` rows move to the front. `t` and `values` are views of
    the stored rows, oldest first.
    """

    def __init__(self, columns: int, capacity: int = BUFFER_ROWS) -> None:
        self.capacity = int(capacity)
        self._t = np.empty(2 * self.capacity)
        self._values = np.empty((2 * self.capacity, columns))
        self.size = 0
        self.appended = 0           # rows ever appended since the last clear

    @property
    def first_index(self) -> int:
        """Running number of the oldest stored row (counts every row appended since clear)."""
        return self.appended - self.size

    @property
    def t(self) -> np.ndarray:
        return self._t[:self.size]

    @property
    def values(self) -> np.ndarray:
        return self._values[:self.size]

    def clear(self) -> None:
        self.size = 0
        self.appended = 0

    def append(self, t: np.ndarray, values: np.ndarray) -> None:
        count = len(t)
        if count == 0:
            return
        self.appended += count
        if count > self.capacity:
            t, values, count = t[-self.capacity:], values[-self.capacity:], self.capacity
        if self.size + count > len(self._t):
            keep = self.capacity - count
            self._t[:keep] = self._t[self.size - keep:self.size]
            self._values[:keep] = self._values[self.size - keep:self.size]
            self.size = keep
        self._t[self.size:self.size + count] = t
        self._values[self.size:self.size + count] = values
        self.size += count

    def last_time(self) -> float:
        return float(self._t[self.size - 1]) if self.size else -math.inf

    def window(self, t_start: float, t_end: float) -> slice:
        """Rows with t_start <= t <= t_end (times are increasing), plus one either side
        so lines run to the edge of the view."""
        t = self.t
        start = max(int(np.searchsorted(t, t_start, "left")) - 1, 0)
        end = min(int(np.searchsorted(t, t_end, "right")) + 1, self.size)
        return slice(start, end)


def same_turn(angles_deg: np.ndarray, reference_deg: np.ndarray) -> np.ndarray:
    """`angles_deg` moved by whole turns to within ±180° of `reference_deg`, element-wise.

    The engine unwraps OWN's and PHONE's Euler angles each on its own, so a single jump of
    more than 180° between samples (near gimbal lock, or across a gap in PHONE's data) can
    leave PHONE's unwrapped yaw whole turns away from OWN's although the two agree. Drawn
    relative to OWN, PHONE stays in OWN's turn and the curves can be compared. NaN (no
    PHONE sample yet, or no OWN estimate) stays as it is.
    """
    angles = np.asarray(angles_deg, dtype=np.float64)
    reference = np.asarray(reference_deg, dtype=np.float64)
    difference = angles - reference
    # Python's % is a floor modulo: the result lies in [-180, 180).
    moved = reference + (difference + 180.0) % 360.0 - 180.0
    return np.where(np.isfinite(difference), moved, angles)


def peak_downsample(t: np.ndarray, values: np.ndarray, first_index: int, max_points: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """At most about `max_points` points per column that keep every peak: the rows are cut
    into bins of `factor` samples and each bin becomes two points, its minimum and maximum
    (at the bin's first and last time). Bins are aligned to the running sample number
    (`first_index` is that of t[0]) so a scrolling window keeps the same bins frame after
    frame instead of flickering. Rows outside whole bins at either end are kept as they are.

    Args:
        t: (n,) times, increasing. values: (n, c). first_index: running number of row 0.
        max_points: budget, e.g. the plot's width in pixels.
    Returns:
        (t, values) unchanged when n <= max_points, else the reduced (m,), (m, c).
    """
    count = len(t)
    if count <= max_points or max_points < 4:
        return t, values
    factor = int(math.ceil(2.0 * count / max_points))
    start = (-first_index) % factor
    bins = (count - start) // factor
    if bins < 2:
        return t, values
    end = start + bins * factor
    binned = values[start:end].reshape(bins, factor, values.shape[1])
    peaks = np.empty((bins, 2, values.shape[1]))
    low, high = peaks[:, 0], peaks[:, 1]
    low[...] = binned[:, 0]
    high[...] = binned[:, 0]
    # Element-wise over the bins' k-th samples: three times faster than min(axis=1) on the
    # strided (bins, factor, columns) view. NaN propagates (a gap stays a gap).
    for k in range(1, factor):
        np.minimum(low, binned[:, k], out=low)
        np.maximum(high, binned[:, k], out=high)
    times = np.empty((bins, 2))
    times[:, 0] = t[start:end:factor]
    times[:, 1] = t[start + factor - 1:end:factor]
    return (np.concatenate([t[:start], times.reshape(-1), t[end:]]),
            np.concatenate([values[:start], peaks.reshape(-1, values.shape[1]), values[end:]]))


class _Curve(pg.PlotCurveItem):
    """A PlotCurveItem whose bounds come with the data (computed in numpy by the panel).

    pyqtgraph recomputes a curve's bounds, with pixel padding, every time the view moves,
    i.e. on every frame while following; here they are set once per setData.
    """

    def __init__(self, **options) -> None:
        self._rect = QtCore.QRectF()
        super().__init__(**options)

    def set_curve(self, x: np.ndarray, y: np.ndarray, finite: bool,
                  y_bounds: tuple[float, float] | None) -> None:
        """New points; `finite`: no NaN in y (the fast path); y_bounds: (min, max) of y."""
        if len(x) and y_bounds is not None:
            low, high = y_bounds
            x_pad = 0.01 * max(float(x[-1] - x[0]), 1e-9)
            y_pad = 0.02 * max(high - low, 1e-9)
            self._rect = QtCore.QRectF(float(x[0]) - x_pad, low - y_pad,
                                       float(x[-1] - x[0]) + 2 * x_pad, high - low + 2 * y_pad)
        else:
            self._rect = QtCore.QRectF()
        self.setData(x, y, connect="all" if finite else "finite", skipFiniteCheck=finite)

    def dataBounds(self, ax: int, frac: float = 1.0, orthoRange=None):  # noqa: N802 (pg name)
        if self._rect.isNull():
            return (None, None)
        if ax == 0:
            return (self._rect.left(), self._rect.right())
        return (self._rect.top(), self._rect.bottom())

    def boundingRect(self) -> QtCore.QRectF:  # noqa: N802 (Qt name)
        return self._rect


def _cache_painting(item: QtWidgets.QGraphicsItem) -> None:
    """Paint `item` and its children from pixmaps redrawn only when they call update():
    legends and axis titles are text, and laying out text is the slowest part of a frame."""
    item.setCacheMode(QtWidgets.QGraphicsItem.CacheMode.DeviceCoordinateCache)
    for child in item.childItems():
        _cache_painting(child)


class _Stream:
    """One buffer and the curves drawn from its columns."""

    def __init__(self, columns: int) -> None:
        self.buffer = SampleBuffer(columns)
        self.curves: list[tuple[str, _Curve, int]] = []   # (label, curve, column)
        self.rejected_column: int | None = None
        self.rejected_scatter: pg.ScatterPlotItem | None = None
        self.norm_column: int | None = None
        self.rejected_shown: np.ndarray = np.empty(0)     # times of the marks drawn now


class PlotPanel(QtWidgets.QWidget):
    """Toolbar (window length, Pause/Follow, Cursor, Clear), cursor readout, five plots."""

    paused_changed = QtCore.Signal(bool)

    def __init__(self, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.following = True
        self._dirty = True
        self._last_range: tuple[float, float] | None = None
        self._setting_range = False
        self._syncing_cursor = False

        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(2)
        toolbar = QtWidgets.QHBoxLayout()
        toolbar.addWidget(QtWidgets.QLabel("Window"))
        self.window_spin = QtWidgets.QDoubleSpinBox()
        self.window_spin.setRange(1.0, MAX_WINDOW_S)
        self.window_spin.setDecimals(0)
        self.window_spin.setSingleStep(5.0)
        self.window_spin.setSuffix(" s")
        self.window_spin.setValue(DEFAULT_WINDOW_S)
        self.window_spin.setToolTip("Length of the rolling window while following")
        self.window_spin.valueChanged.connect(self._mark_dirty)
        self.pause_button = QtWidgets.QPushButton("Pause")
        self.pause_button.setCheckable(True)
        self.pause_button.setToolTip("Freeze the view to inspect it; samples keep being stored "
                                     "(Space)")
        self.pause_button.toggled.connect(lambda checked: self.set_paused(checked))
        self.follow_button = QtWidgets.QPushButton("Follow")
        self.follow_button.setToolTip("Show the newest samples again")
        self.follow_button.clicked.connect(self.follow)
        self.cursor_checkbox = QtWidgets.QCheckBox("Cursor")
        self.cursor_checkbox.setToolTip("A draggable line reading every visible curve")
        self.cursor_checkbox.toggled.connect(self.set_cursor_visible)
        self.clear_button = QtWidgets.QPushButton("Clear")
        self.clear_button.setToolTip("Forget the plotted samples (Ctrl+L)")
        self.clear_button.clicked.connect(self.clear)
        for widget in (self.window_spin, self.pause_button, self.follow_button,
                       self.cursor_checkbox, self.clear_button):
            toolbar.addWidget(widget)
        toolbar.addStretch(1)
        layout.addLayout(toolbar)
        self.readout_label = QtWidgets.QLabel("")
        self.readout_label.setTextInteractionFlags(
            QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        self.readout_label.setWordWrap(True)
        self.readout_label.setVisible(False)
        layout.addWidget(self.readout_label)

        self.graphics = pg.GraphicsLayoutWidget()
        self.graphics.setBackground((250, 250, 252))
        # Every curve moves on every frame: keeping Qt's spatial index (a BSP tree) of the
        # items up to date costs more than it saves.
        self.graphics.scene().setItemIndexMethod(QtWidgets.QGraphicsScene.ItemIndexMethod.NoIndex)
        layout.addWidget(self.graphics, 1)

        self.plots: dict[str, pg.PlotItem] = {}
        self.streams: dict[str, _Stream] = {}
        self.cursors: dict[str, pg.InfiniteLine] = {}
        self.gate_lines: dict[str, tuple[pg.InfiniteLine, pg.InfiniteLine]] = {}
        self.legends: list[pg.LegendItem] = []
        self._build_xyz_plot("acc", "acc", "m/s²", rejected=True)
        self._build_xyz_plot("gyr", "gyr", "rad/s", rejected=False)
        self._build_xyz_plot("mag", "mag", "µT", rejected=True)
        self._build_euler_plot()
        self._build_angle_plot()
        # The plots share their time range. Not with pyqtgraph's setXLink: that re-maps every
        # change through each view's screen geometry and costs milliseconds per frame while
        # following; with y axes of one fixed width the views line up, and the range is
        # simply copied (set_x_range, _on_x_range_changed).
        for name, plot in self.plots.items():
            plot.getAxis("left").setWidth(LEFT_AXIS_WIDTH)
            view_box = plot.getViewBox()
            view_box.sigRangeChangedManually.connect(self._on_manual_range)
            view_box.sigXRangeChanged.connect(self._on_x_range_changed)
        self.plots["angle"].setLabel("bottom", "phone time", units="s")
        for legend in self.legends:          # complete now: every curve has its entry
            _cache_painting(legend)

    # ---- construction ---------------------------------------------------------------------

    def _new_plot(self, key: str, title: str, units: str) -> pg.PlotItem:
        row = len(self.plots)
        plot = self.graphics.addPlot(row=row, col=0)
        # The title goes on the y axis: five stacked plots have no height to spare.
        plot.setLabel("left", title, units=units)
        plot.showGrid(x=False, y=False)
        # Plain units: "m°" or "ks" (SI prefixes on degrees and phone time) only confuse. Off
        # on the hidden axes too: there it would re-lay out their labels on every frame.
        for axis in ("left", "bottom", "top", "right"):
            plot.getAxis(axis).enableAutoSIPrefix(False)
        # Fewer tick levels: the time axis is regenerated on every frame while following.
        for axis in ("left", "bottom"):
            plot.getAxis(axis).setStyle(maxTickLevel=1, maxTextLevel=1)
        # The y axis and its title change only when the y range does: paint them from a
        # cached pixmap instead of laying out their text on every frame.
        _cache_painting(plot.getAxis("left"))
        # Clipping to the view and peak downsampling are done here, in numpy, once per stream
        # and frame (peak_downsample): pyqtgraph's own versions redo their work per curve on
        # every view change, i.e. every frame while following.
        plot.setClipToView(False)
        plot.setDownsampling(ds=1, auto=False, mode="peak")
        # y follows the visible samples, computed in refresh(): pyqtgraph's own auto range
        # re-scans every curve at paint time and triggers a second paint per frame.
        plot.disableAutoRange()
        plot.getViewBox().setMouseEnabled(x=True, y=False)
        plot.setMenuEnabled(True)
        legend = plot.addLegend(offset=(4, 1), colCount=8, labelTextSize="8pt",
                                verSpacing=-6)
        legend.setBrush(pg.mkBrush(255, 255, 255, 200))
        self.legends.append(legend)
        # Clicking a legend entry toggles that curve (pyqtgraph); hidden curves are not
        # redrawn, so a shown-again curve needs a redraw even while paused.
        legend.sigSampleClicked.connect(self._mark_dirty)
        if row < 4:
            # Only the bottom plot shows time: the others share it, and an x axis redrawn
            # every frame on each plot costs more than all the curves.
            plot.hideAxis("bottom")
        cursor = pg.InfiniteLine(angle=90, movable=True, pen=pg.mkPen((120, 60, 160), width=1.5))
        cursor.setVisible(False)
        cursor.sigPositionChanged.connect(self._on_cursor_moved)
        plot.addItem(cursor, ignoreBounds=True)
        self.cursors[key] = cursor
        self.plots[key] = plot
        return plot

    def _add_curve(self, stream: _Stream, plot: pg.PlotItem, label: str, column: int,
                   color) -> None:
        # Solid 1-px pens without antialiasing: Qt's fast line path.
        curve = _Curve(pen=pg.mkPen(color, width=1), name=label, antialias=False)
        plot.addItem(curve)                  # named, so the legend lists it
        stream.curves.append((label, curve, column))

    def _build_xyz_plot(self, key: str, title: str, units: str, rejected: bool) -> None:
        plot = self._new_plot(key, title, units)
        stream = _Stream(5 if rejected else 4)
        for column, label in enumerate(("x", "y", "z", "norm")):
            self._add_curve(stream, plot, label, column, XYZ_COLORS[column])
        stream.norm_column = 3
        if rejected:
            stream.rejected_column = 4
            scatter = pg.ScatterPlotItem(symbol="x", size=8, pen=pg.mkPen(200, 0, 0),
                                         brush=pg.mkBrush(220, 0, 0), name="rejected")
            plot.addItem(scatter)            # named, so the legend lists it once
            stream.rejected_scatter = scatter
            pen = pg.mkPen((200, 120, 0), width=1, style=QtCore.Qt.PenStyle.DashLine)
            lines = (pg.InfiniteLine(angle=0, pen=pen), pg.InfiniteLine(angle=0, pen=pen))
            for line in lines:
                line.setVisible(False)
                plot.addItem(line, ignoreBounds=True)
            self.gate_lines[key] = lines
        self.streams[key] = stream

    def _build_euler_plot(self) -> None:
        plot = self._new_plot("euler", "Euler", "°")   # OWN dark, PHONE light
        stream = _Stream(6)
        for i, name in enumerate(EULER_NAMES):
            self._add_curve(stream, plot, f"OWN {name}", i, XYZ_COLORS[i])
        for i, name in enumerate(EULER_NAMES):
            self._add_curve(stream, plot, f"PHONE {name}", 3 + i, PHONE_COLORS[i])
        self.streams["euler"] = stream

    def _build_angle_plot(self) -> None:
        plot = self._new_plot("angle", "OWN vs PHONE", "°")
        stream = _Stream(1)
        self._add_curve(stream, plot, "∠(OWN, PHONE)", 0, (130, 40, 170))
        self.streams["angle"] = stream

    # ---- data in ---------------------------------------------------------------------------

    def append(self, chunk: PlotChunk) -> None:
        """Store the new samples; drawing waits for the next refresh()."""
        if len(chunk.t_acc):
            acc = np.asarray(chunk.acc, float)
            rejected = np.asarray(chunk.acc_rejected, float).reshape(-1, 1)
            if len(rejected) != len(acc):
                rejected = np.zeros((len(acc), 1))
            self._append("acc", chunk.t_acc, np.hstack(
                [acc, np.linalg.norm(acc, axis=1, keepdims=True), rejected]))
        if len(chunk.t_gyr):
            gyr = np.asarray(chunk.gyr, float)
            self._append("gyr", chunk.t_gyr,
                         np.hstack([gyr, np.linalg.norm(gyr, axis=1, keepdims=True)]))
        if len(chunk.t_mag):
            mag = np.asarray(chunk.mag, float)
            rejected = np.asarray(chunk.mag_rejected, float).reshape(-1, 1)
            if len(rejected) != len(mag):
                rejected = np.zeros((len(mag), 1))
            self._append("mag", chunk.t_mag, np.hstack(
                [mag, np.linalg.norm(mag, axis=1, keepdims=True), rejected]))
        if len(chunk.t_est):
            count = len(chunk.t_est)
            own = np.asarray(chunk.own_euler_deg, float).reshape(count, 3)
            phone = np.asarray(chunk.phone_euler_deg, float)
            phone = phone.reshape(count, 3) if phone.size == 3 * count else np.full((count, 3),
                                                                                     np.nan)
            self._append("euler", chunk.t_est, np.hstack([own, same_turn(phone, own)]))
            angle = np.asarray(chunk.angle_deg, float)
            angle = angle.reshape(count, 1) if angle.size == count else np.full((count, 1), np.nan)
            self._append("angle", chunk.t_est, angle)

    def _append(self, key: str, t: np.ndarray, values: np.ndarray) -> None:
        t = np.asarray(t, dtype=np.float64)
        buffer = self.streams[key].buffer
        # A replay that loops or seeks backwards restarts the phone's time: start afresh.
        if t[0] < buffer.last_time() - 1e-6:
            buffer.clear()
            self._dirty = True
        buffer.append(t, values)
        # While paused, samples after the frozen view change nothing on screen.
        if self.following or t[0] <= self.x_range()[1]:
            self._dirty = True

    def set_status(self, status: FilterStatus) -> None:
        """Draw the gate limits on the norms: g ± acc_gate and L ± mag_gate."""
        for key, center, gate in (("acc", status.diagnostics.g, status.diagnostics.acc_gate),
                                  ("mag", status.diagnostics.mag_expected, status.diagnostics.mag_gate)):
            lines = self.gate_lines[key]
            valid = math.isfinite(center) and math.isfinite(gate)
            for line, sign in zip(lines, (1.0, -1.0)):
                line.setVisible(valid)
                if valid and abs(line.value() - (center + sign * gate)) > 1e-9:
                    line.setValue(center + sign * gate)

    # ---- view state ------------------------------------------------------------------------

    @property
    def paused(self) -> bool:
        return not self.following

    @property
    def window_s(self) -> float:
        return float(self.window_spin.value())

    def set_window_s(self, seconds: float) -> None:
        self.window_spin.setValue(float(seconds))

    def set_paused(self, paused: bool) -> None:
        """Pause: the view stays where it is while samples keep being stored."""
        paused = bool(paused)
        if paused == self.paused:
            return
        self.following = not paused
        self.pause_button.blockSignals(True)
        self.pause_button.setChecked(paused)
        self.pause_button.blockSignals(False)
        self.pause_button.setText("Paused" if paused else "Pause")
        self._dirty = True
        self.paused_changed.emit(paused)

    def follow(self) -> None:
        self.set_paused(False)

    def toggle_paused(self) -> None:
        self.set_paused(not self.paused)

    def clear(self) -> None:
        for stream in self.streams.values():
            stream.buffer.clear()
        self._dirty = True
        self.refresh()

    def latest_time(self) -> float:
        return max(stream.buffer.last_time() for stream in self.streams.values())

    def x_range(self) -> tuple[float, float]:
        low, high = self.plots["acc"].getViewBox().viewRange()[0]
        return float(low), float(high)

    def _on_manual_range(self, *args) -> None:
        # The user dragged or zoomed a plot: they want to look at it, so stop following.
        if not self._setting_range:
            self.set_paused(True)

    def _on_x_range_changed(self, view_box, x_range) -> None:
        """A plot's time range changed by hand (drag, zoom, its menu): the others follow."""
        if self._setting_range:
            return
        self.set_x_range(*x_range, source=view_box)
        self._dirty = True

    def set_x_range(self, low: float, high: float, source=None) -> None:
        """Show phone times low..high (s) in every plot (but `source`, which already does)."""
        self._setting_range = True
        try:
            for plot in self.plots.values():
                view_box = plot.getViewBox()
                if view_box is not source:
                    view_box.setXRange(low, high, padding=0.0)
        finally:
            self._setting_range = False

    def _mark_dirty(self, *args) -> None:
        self._dirty = True

    # ---- drawing ---------------------------------------------------------------------------

    def refresh(self) -> None:
        """Redraw the visible window if anything changed. Call once per display frame."""
        latest = self.latest_time()
        if self.following and math.isfinite(latest):
            x_range = (latest - self.window_s, latest)
            if x_range != self._last_range:
                self.set_x_range(*x_range)
                self._dirty = True
        if not self._dirty:
            return
        self._dirty = False
        t_start, t_end = self.x_range()
        self._last_range = (t_start, t_end) if self.following else None
        for key, stream in self.streams.items():
            self._draw_stream(key, stream, t_start, t_end)
        # Apply the new ranges now: pyqtgraph would do it lazily at the start of the paint,
        # which moves every item once more and so asks for a second paint of each frame.
        for plot in self.plots.values():
            plot.getViewBox().prepareForPaint()
        if self.cursor_checkbox.isChecked():
            self._update_readout()

    def _draw_stream(self, key: str, stream: _Stream, t_start: float, t_end: float) -> None:
        """Hand one stream's visible window, peak-downsampled to the plot's width, to its curves."""
        buffer = stream.buffer
        window = buffer.window(t_start, t_end)
        t = buffer.t[window]
        values = buffer.values[window]
        width = max(int(self.plots[key].getViewBox().width()), 1)
        shown_t, shown = peak_downsample(t, values, buffer.first_index + window.start, width)
        visible = [(curve, column) for _, curve, column in stream.curves if curve.isVisible()]
        if len(shown_t):
            columns = [column for _, column in visible] or [0]
            finite_columns = np.isfinite(shown[:, columns]).all(axis=0)
            # fmin/fmax skip NaN (PHONE before its first ORI) without all-NaN warnings.
            lows = np.fmin.reduce(shown[:, columns], axis=0)
            highs = np.fmax.reduce(shown[:, columns], axis=0)
        for index, (curve, column) in enumerate(visible):
            if not len(shown_t):
                curve.set_curve(shown_t, shown[:, column], True, None)
                continue
            low, high = float(lows[index]), float(highs[index])
            bounds = (low, high) if math.isfinite(low) and math.isfinite(high) else None
            curve.set_curve(shown_t, shown[:, column], bool(finite_columns[index]), bounds)
        # A hidden curve keeps its old points; it gets the current ones when shown again
        # (the legend click marks the panel dirty).
        if stream.rejected_scatter is not None:
            mask = values[:, stream.rejected_column] > 0.5 if len(t) else np.zeros(0, bool)
            marked_t = t[mask]
            # Marks move with the data only when there are any; re-setting an unchanged
            # scatter costs a millisecond a frame.
            if not np.array_equal(marked_t, stream.rejected_shown):
                stream.rejected_shown = marked_t
                stream.rejected_scatter.setData(marked_t, values[mask, stream.norm_column])
        if len(shown_t) and visible:
            finite = np.isfinite(lows) & np.isfinite(highs)
            if finite.any():
                self._fit_y(key, float(lows[finite].min()), float(highs[finite].max()))

    def _fit_y(self, key: str, low: float, high: float) -> None:
        """Fit the y range to the visible curves' span (and gate lines), with hysteresis so the
        axis does not rescale, and re-layout, on every frame."""
        for line in self.gate_lines.get(key, ()):
            if line.isVisible():
                low, high = min(low, line.value()), max(high, line.value())
        span = max(high - low, 1e-6 * max(abs(high), 1.0), 1e-9)
        low, high = low - 0.08 * span, high + 0.08 * span
        view_low, view_high = self.plots[key].getViewBox().viewRange()[1]
        if low < view_low or high > view_high or (view_high - view_low) > 2.0 * (high - low):
            self.plots[key].setYRange(low, high, padding=0.0)

    # ---- cursor ----------------------------------------------------------------------------

    def set_cursor_visible(self, visible: bool) -> None:
        if visible:
            t_start, t_end = self.x_range()
            self.set_cursor_time(0.5 * (t_start + t_end))
        for cursor in self.cursors.values():
            cursor.setVisible(bool(visible))
        self.readout_label.setVisible(bool(visible))
        if self.cursor_checkbox.isChecked() != bool(visible):
            self.cursor_checkbox.setChecked(bool(visible))
        if visible:
            self._update_readout()

    def cursor_time(self) -> float:
        return float(self.cursors["acc"].value())

    def set_cursor_time(self, t: float) -> None:
        self._syncing_cursor = True
        for cursor in self.cursors.values():
            cursor.setValue(t)
        self._syncing_cursor = False
        self._update_readout()

    def _on_cursor_moved(self, line: pg.InfiniteLine) -> None:
        if self._syncing_cursor:
            return
        self.set_cursor_time(float(line.value()))

    def cursor_values(self) -> dict[str, float]:
        """Value of every visible curve at the cursor (nearest stored sample), by
        "plot/label"; NaN where a stream has no samples."""
        t_cursor = self.cursor_time()
        values: dict[str, float] = {}
        for key, stream in self.streams.items():
            t = stream.buffer.t
            index = None
            if len(t):
                index = int(np.clip(np.searchsorted(t, t_cursor), 1, len(t) - 1)) if len(t) > 1 else 0
                if len(t) > 1 and abs(t[index - 1] - t_cursor) <= abs(t[index] - t_cursor):
                    index -= 1
            for label, curve, column in stream.curves:
                if not curve.isVisible():
                    continue
                values[f"{key}/{label}"] = (float(stream.buffer.values[index, column])
                                            if index is not None else math.nan)
        return values

    def _update_readout(self) -> None:
        if not self.readout_label.isVisible() and not self.cursor_checkbox.isChecked():
            return
        parts = [f"<b>t = {self.cursor_time():.3f} s</b>"]
        grouped: dict[str, list[str]] = {}
        for name, value in self.cursor_values().items():
            key, label = name.split("/", 1)
            grouped.setdefault(key, []).append(f"{label} {value:.3f}" if math.isfinite(value)
                                               else f"{label} –")
        titles = {"acc": "acc", "gyr": "gyr", "mag": "mag", "euler": "Euler", "angle": "angle"}
        for key, items in grouped.items():
            parts.append(f"<b>{titles[key]}</b>: " + ", ".join(items))
        self.readout_label.setText(" &nbsp; ".join(parts))
