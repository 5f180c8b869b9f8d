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

from app.snapshot import FilterStatus, PlotChunk

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

    @property
    def t(self) -> np.ndarray:
        return self._t[:self.size]

    @property
    def values(self) -> np.ndarray:
        return self._values[:self.size]

    def clear(self) -> None:
        self.size = 0

    def append(self, t: np.ndarray, values: np.ndarray) -> None:
        count = len(t)
        if count == 0:
            return
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


class _Stream:
    """One buffer and the curves drawn from its columns."""

    def __init__(self, columns: int) -> None:
        self.buffer = SampleBuffer(columns)
        self.curves: list[tuple[str, pg.PlotDataItem, int]] = []   # (label, curve, column)
        self.rejected_column: int | None = None
        self.rejected_scatter: pg.ScatterPlotItem | None = None
        self.norm_column: int | None = None


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
        layout.addWidget(self.graphics, 1)

        self.plots: dict[str, pg.PlotItem] = {}
        self.streams: dict[str, _Stream] = {}
        self.cursors: dict[str, pg.InfiniteLine] = {}
        self.gate_lines: dict[str, tuple[pg.InfiniteLine, pg.InfiniteLine]] = {}
        self._build_xyz_plot("acc", "acc", "m/s²", rejected=True)
        self._build_xyz_plot("gyr", "gyr", "rad/s", rejected=False)
        self._build_xyz_plot("mag", "mag", "µT", rejected=True)
        self._build_euler_plot()
        self._build_angle_plot()
        first = self.plots["acc"]
        for name, plot in self.plots.items():
            if plot is not first:
                plot.setXLink(first)
            plot.getViewBox().sigRangeChangedManually.connect(self._on_manual_range)
            plot.getViewBox().sigXRangeChanged.connect(self._on_x_range_changed)
        self.plots["angle"].setLabel("bottom", "phone time", units="s")

    # ---- construction ---------------------------------------------------------------------

    def _new_plot(self, key: str, title: str, units: str) -> pg.PlotItem:
        row = len(self.plots)
        plot = self.graphics.addPlot(row=row, col=0)
        # The title goes on the y axis: five stacked plots have no height to spare.
        plot.setLabel("left", title, units=units)
        plot.showGrid(x=False, y=False)
        # Plain units: "m°" or "ks" (SI prefixes on degrees and phone time) only confuse.
        for axis in ("left", "bottom"):
            plot.getAxis(axis).enableAutoSIPrefix(False)
        # Clipping to the view is done here (only the visible window is handed over) and the
        # peak-downsampling factor is set per frame from the visible count: pyqtgraph's
        # automatic versions redo their work on every view change, i.e. every frame.
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
        curve = plot.plot(pen=pg.mkPen(color, width=1), name=label, connect="finite",
                          skipFiniteCheck=False)
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
            self._append("euler", chunk.t_est, np.hstack([own, phone]))
            angle = np.asarray(chunk.angle_deg, float)
            angle = angle.reshape(count, 1) if angle.size == count else np.full((count, 1), np.nan)
            self._append("angle", chunk.t_est, angle)

    def _append(self, key: str, t: np.ndarray, values: np.ndarray) -> None:
        t = np.asarray(t, dtype=np.float64)
        buffer = self.streams[key].buffer
        # A replay that loops or seeks backwards restarts the phone's time: start afresh.
        if t[0] < buffer.last_time() - 1e-6:
            buffer.clear()
        buffer.append(t, values)
        self._dirty = True

    def set_status(self, status: FilterStatus) -> None:
        """Draw the gate limits on the norms: g ± acc_gate and L ± mag_gate."""
        for key, center, gate in (("acc", status.g, status.acc_gate),
                                  ("mag", status.mag_expected, status.mag_gate)):
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

    def _on_x_range_changed(self, *args) -> None:
        if not self._setting_range:
            self._dirty = True

    def _mark_dirty(self, *args) -> None:
        self._dirty = True

    # ---- drawing ---------------------------------------------------------------------------

    def refresh(self) -> None:
        """Redraw the visible window if anything changed. Call once per display frame."""
        latest = self.latest_time()
        if self.following and math.isfinite(latest):
            x_range = (latest - self.window_s, latest)
            if x_range != self._last_range:
                self._setting_range = True
                self.plots["acc"].setXRange(*x_range, padding=0.0)
                self._setting_range = False
                self._dirty = True
        if not self._dirty:
            return
        self._dirty = False
        t_start, t_end = self.x_range()
        self._last_range = (t_start, t_end) if self.following else None
        for key, stream in self.streams.items():
            window = stream.buffer.window(t_start, t_end)
            t = stream.buffer.t[window]
            values = stream.buffer.values[window]
            factor = max(1, len(t) // max(2 * int(self.plots[key].getViewBox().width()), 1))
            for _, curve, column in stream.curves:
                if curve.isVisible() or not len(t):
                    if curve.opts["downsample"] != factor:
                        curve.setDownsampling(ds=factor, auto=False, method="peak")
                    curve.setData(t, values[:, column])
            if stream.rejected_scatter is not None:
                mask = values[:, stream.rejected_column] > 0.5 if len(t) else np.zeros(0, bool)
                stream.rejected_scatter.setData(t[mask], values[mask, stream.norm_column])
            self._fit_y(key, stream, values)
        if self.cursor_checkbox.isChecked():
            self._update_readout()

    def _fit_y(self, key: str, stream: _Stream, values: np.ndarray) -> None:
        """Fit the y range to the visible curves (and gate lines), with hysteresis so the
        axis does not rescale, and re-layout, on every frame."""
        columns = [column for _, curve, column in stream.curves if curve.isVisible()]
        if not columns or not len(values):
            return
        shown = values[:, columns]
        finite = shown[np.isfinite(shown)]
        if not finite.size:
            return
        low, high = float(finite.min()), float(finite.max())
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
