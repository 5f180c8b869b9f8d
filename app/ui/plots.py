"""Live plots in time since the session's start, in three tabs.

* Sensors: accelerometer, gyroscope and magnetometer (x, y, z, norm), the gates on the norms,
  the samples the filter rejected as a thin red band of ticks along the bottom and, where the
  sensor was switched off (its samples not used, no gate asked), a grey dashed band instead;
* Orientation: yaw, pitch and roll (z-y-x) of OWN (solid) and PHONE (dashed, same colour),
  wrapped to ±180° (±90° for pitch) with the line broken at a wrap, or unwrapped in one turn;
* Error vs PHONE: total angle, heading and inclination of OWN against PHONE, compared at
  PHONE's time stamps.

With your own filter loaded (YOURS) its Euler angles and errors join the last two tabs, dotted
in the same colours, with a YOURS toggle in their legends (shown only while YOURS has data).

Samples arrive in PlotChunks (one per display frame) and go into preallocated numpy buffers
of bounded size; the current tab's curves are redrawn at most once per display frame, only
over the visible window, peak-downsampled to the plot's width. Following shows the last
`window_s` seconds; pausing (button, Space, or dragging/zooming a plot) freezes the view while
samples keep being stored, and a note in the toolbar says so with the times shown; Follow
resumes (the window also calls follow() on a replay's seek or Play). The legend of each tab is a row of toggles above
its plots (never over the data); the cursor reads every visible curve into a small table.
A sensor the stream does not deliver has its plot say so ("no gyroscope in this stream").

The module in the order it is built: the numbers behind the plots in numpy (bounded sample
buffers, peak downsampling, Euler angles wrapped with their lines broken at a wrap or unwrapped
in one turn, rejected samples as spans, time labels); what is drawn (the tabs and their plots,
the curves of each with stream, column, colour, line style and the legend toggles that show it,
the legends, the cursor readout's table); the graphics items (a curve whose bounds come with its
data, the time axis, the legend icons, one tab's group of plots, a plot's no-data message); and
the panel (PlotPanel) that builds and draws them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.snapshot import FilterStatus, PlotChunk
from app.ui.elided import ElidedLabel


# ---- the numbers behind the plots (numpy, no Qt) -------------------------------------------

# Rows kept per stream: 2 minutes at 500 Hz. The buffer holds up to twice this before it
# drops the oldest half, so memory is bounded (about 6 MB for the widest stream).
BUFFER_ROWS = 60_000
WRAPPING_COLUMNS = (0, 2)   # yaw and roll wrap at ±180°; pitch stays within ±90°


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

    @classmethod
    def from_arrays(cls, t: np.ndarray, values: np.ndarray) -> SampleBuffer:
        """A read-only buffer over existing arrays (a replay's whole session: no copy)."""
        buffer = cls.__new__(cls)
        buffer.capacity = len(t)
        buffer._t = t
        buffer._values = values
        buffer.size = len(t)
        buffer.appended = len(t)
        return buffer

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

    def first_time(self) -> float:
        return float(self._t[0]) if self.size else math.inf

    def window(self, t_start: float, t_end: float) -> slice:
        """Rows with t_start <= t <= t_end (times are increasing), plus one either side
        so lines run to the edge of the view."""
        t = self.t
        start = max(int(np.searchsorted(t, t_start, "left")) - 1, 0)
        end = min(int(np.searchsorted(t, t_end, "right")) + 1, self.size)
        return slice(start, end)


def same_turn(angles_deg: np.ndarray, reference_deg: np.ndarray) -> np.ndarray:
    """`angles_deg` moved by whole turns to within ±180° of `reference_deg`, element-wise;
    NaN stays as it is."""
    angles = np.asarray(angles_deg, dtype=np.float64)
    reference = np.asarray(reference_deg, dtype=np.float64)
    difference = angles - reference
    # Python's % is a floor modulo: the result lies in [-180, 180).
    moved = reference + (difference + 180.0) % 360.0 - 180.0
    return np.where(np.isfinite(difference), moved, angles)


def break_at_wraps(t: np.ndarray, angles_deg: np.ndarray,
                   columns: tuple[int, ...] = WRAPPING_COLUMNS) -> tuple[np.ndarray, np.ndarray]:
    """Wrapped angles with a NaN row inserted wherever one of `columns` jumps by more than
    180° between two samples, so a line drawn through them breaks at the wrap instead of
    crossing the plot (the NaN survives peak downsampling: the bin holding it is a gap)."""
    if len(t) < 2:
        return t, angles_deg
    jumps = np.zeros(len(t) - 1, bool)
    for column in columns:
        with np.errstate(invalid="ignore"):
            jumps |= np.abs(np.diff(angles_deg[:, column])) > 180.0
    where = np.flatnonzero(jumps) + 1
    if not len(where):
        return t, angles_deg
    t_out = np.insert(t, where, 0.5 * (t[where - 1] + t[where]))
    values = np.insert(angles_deg, where, np.nan, axis=0)
    return t_out, values


def unwrap_deg(angles_deg: np.ndarray, columns: tuple[int, ...] = WRAPPING_COLUMNS) -> np.ndarray:
    """The wrapping columns unwrapped along time (NaN rows skipped and kept NaN)."""
    out = np.array(angles_deg, dtype=np.float64, copy=True)
    for column in columns:
        values = out[:, column]
        finite = np.isfinite(values)
        if finite.sum() > 1:
            values[finite] = np.degrees(np.unwrap(np.radians(values[finite])))
    return out


def unwrap_in_turn(reference_t: np.ndarray, reference_deg: np.ndarray, t: np.ndarray,
                   angles_deg: np.ndarray,
                   columns: tuple[int, ...] = WRAPPING_COLUMNS) -> np.ndarray:
    """`angles_deg` (at times t) moved by whole turns into the turn of the unwrapped
    `reference_deg` (at reference_t) at the same time, column by column."""
    out = np.array(angles_deg, dtype=np.float64, copy=True)
    if not len(reference_t) or not len(t):
        return out
    for column in columns:
        ref = reference_deg[:, column]
        finite = np.isfinite(ref)
        if not finite.any():
            continue
        near = np.interp(t, reference_t[finite], ref[finite])
        out[:, column] = same_turn(out[:, column], near)
    return out


class OffSpans:
    """Stretches of time [start, end] (s), in order, merged when one starts within `join_s`
    of the previous one's end: where a sensor was switched off."""

    def __init__(self, join_s: float) -> None:
        self.join_s = join_s
        self.spans: list[list[float]] = []

    def add(self, start: float, end: float) -> None:
        if self.spans and start <= self.spans[-1][1] + self.join_s:
            self.spans[-1][1] = max(self.spans[-1][1], end)
        else:
            self.spans.append([start, end])

    def clear(self) -> None:
        self.spans.clear()

    def mask(self, t: np.ndarray) -> np.ndarray:
        """Which of the times `t` fall in one of the stretches."""
        if not self.spans or not len(t):
            return np.zeros(len(t), bool)
        starts = np.array([a for a, _ in self.spans])
        ends = np.array([b for _, b in self.spans])
        index = np.searchsorted(starts, t, side="right") - 1
        inside = index >= 0
        inside[inside] = t[inside] <= ends[index[inside]]
        return inside


def rejected_spans(t: np.ndarray, rejected: np.ndarray) -> np.ndarray:
    """Runs of rejected samples as (n, 2) [start, end] times; a run is widened by half a
    sample period on each side so that a single rejected sample is still a visible tick."""
    mask = np.asarray(rejected, bool)
    if len(t) == 0 or not mask.any():
        return np.empty((0, 2))
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    half = 0.5 * (float(np.median(np.diff(t))) if len(t) > 1 else 0.01)
    return np.column_stack([t[starts] - half, t[ends] + half])


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


def time_text(seconds: float, span_s: float = 0.0, decimals: int = 1) -> str:
    """Seconds since the session's start as a label: "12.5" below two minutes of span,
    "m:ss" (or "h:mm:ss") for longer views and sessions; "–" for no time."""
    if seconds is None or not math.isfinite(seconds):
        return "–"
    if span_s < 120.0 and abs(seconds) < 120.0:
        return f"{seconds:.{decimals}f}"
    sign = "-" if seconds < 0 else ""
    seconds = abs(seconds)
    minutes, rest = divmod(seconds, 60.0)
    hours, minutes = divmod(int(minutes), 60)
    fraction = f"{rest:0{3 + decimals if decimals else 2}.{decimals}f}" if span_s < 600.0 \
        else f"{int(rest):02d}"
    return f"{sign}{hours}:{minutes:02d}:{fraction}" if hours else f"{sign}{minutes}:{fraction}"


# ---- what is drawn: tabs, plots, curves, legends, the readout ------------------------------

DEFAULT_WINDOW_S = 10.0
MAX_WINDOW_S = 600.0
AXIS_COLORS = ((220, 50, 50), (40, 160, 60), (50, 100, 230))    # x, y, z
NORM_COLOR = (90, 90, 90)
REJECTED_COLOR = (225, 40, 40)
OFF_COLOR = (130, 132, 140)      # a sensor switched off: its samples are not used
OFF_JOIN_S = 0.5                 # "off" samples closer than this are one stretch
GATE_COLOR = (200, 120, 0)
MARKER_COLOR = (230, 120, 0)
FIRST_PLOTS = ("acc", "yaw", "error")    # the top plot of each tab labels the markers
ERROR_COLORS = ((130, 40, 170), (230, 120, 0), (0, 150, 150))   # total, heading, inclination
EULER_NAMES = ("yaw", "pitch", "roll")
# yaw is about z, pitch about y, roll about x: each in its axis' colour
EULER_COLORS = (AXIS_COLORS[2], AXIS_COLORS[1], AXIS_COLORS[0])
EULER_TOOLTIP = ("Euler angles z-y-x (the course's q2euler intent, its errata fixed): "
                 "R = Rz(yaw) Ry(pitch) Rx(roll), sensor -> East-North-Up; yaw about up "
                 "(0 = the phone's y axis to the north, counter-clockwise positive), pitch about "
                 "the turned y axis (±90°), roll about the phone's x axis.")
# The toolbar's note while the plots do not follow (paused, or zoomed/dragged by hand)
FOLLOW_NOTE_STYLE = ("QLabel { background: #ffe8a8; color: #5a3c00; border: 1px solid #e0b040; "
                     "border-radius: 3px; padding: 1px 6px; }")
LEFT_AXIS_WIDTH = 64        # px, the same for every plot so their time axes line up
BAND_FRACTION = 0.035       # the rejected band: this much of the plot's height, at the bottom


@dataclass
class CurveSpec:
    stream: str
    column: int
    plot: str
    label: str           # the cursor readout's row/column name
    tags: frozenset[str]  # the legend toggles that show/hide it
    color: tuple[int, int, int]
    dashed: bool = False
    dotted: bool = False


@dataclass
class PlotSpec:
    key: str
    group: str
    title: str
    units: str
    tooltip: str = ""


GROUPS = (("sensors", "Sensors"), ("orientation", "Orientation"), ("error", "Error vs PHONE"))
PLOTS = (
    PlotSpec("acc", "sensors", "acc", "m/s²", "specific force, sensor frame"),
    PlotSpec("gyr", "sensors", "gyr", "rad/s", "angular rate, sensor frame"),
    PlotSpec("mag", "sensors", "mag", "µT", "magnetic field, sensor frame"),
    PlotSpec("yaw", "orientation", "yaw", "°", EULER_TOOLTIP),
    PlotSpec("pitch", "orientation", "pitch", "°", EULER_TOOLTIP),
    PlotSpec("roll", "orientation", "roll", "°", EULER_TOOLTIP),
    PlotSpec("error", "error", "OWN vs PHONE", "°",
              "e = q_OWN ⊗ conj(q_PHONE) at PHONE's time stamps (OWN slerped to them): total "
              "angle 2·acos|e_w|, heading 2·atan|e_z/e_w| (about up), inclination (tilt)"),
)
STREAM_COLUMNS = {"acc": 5, "gyr": 4, "mag": 5, "own": 3, "phone": 3, "error": 3, "user": 3,
                  "user_error": 3}
USER_STREAMS = ("user", "user_error")   # YOURS: replaced by a re-run's history, never clear others


def curve_specs() -> list[CurveSpec]:
    specs = []
    for key in ("acc", "gyr", "mag"):
        for column, name in enumerate(("x", "y", "z")):
            specs.append(CurveSpec(key, column, key, f"{key} {name}", frozenset({name}),
                                    AXIS_COLORS[column]))
        specs.append(CurveSpec(key, 3, key, f"{key} norm", frozenset({"norm"}), NORM_COLOR))
    for column, name in enumerate(EULER_NAMES):
        specs.append(CurveSpec("own", column, name, f"OWN {name}", frozenset({"OWN"}),
                                EULER_COLORS[column]))
        specs.append(CurveSpec("phone", column, name, f"PHONE {name}", frozenset({"PHONE"}),
                                EULER_COLORS[column], dashed=True))
        specs.append(CurveSpec("user", column, name, f"YOURS {name}", frozenset({"YOURS"}),
                                EULER_COLORS[column], dotted=True))
    for column, name in enumerate(("total", "heading", "inclination")):
        specs.append(CurveSpec("error", column, "error", name, frozenset({name, "OWN"}),
                                ERROR_COLORS[column]))
        specs.append(CurveSpec("user_error", column, "error", f"YOURS {name}",
                                frozenset({name, "YOURS"}), ERROR_COLORS[column], dotted=True))
    return specs


LEGENDS = {
    "sensors": (("x", AXIS_COLORS[0], "line"), ("y", AXIS_COLORS[1], "line"),
                ("z", AXIS_COLORS[2], "line"), ("norm", NORM_COLOR, "line"),
                ("rejected", REJECTED_COLOR, "band"), ("off", OFF_COLOR, "dashed band"),
                ("gates", GATE_COLOR, "dash")),
    "orientation": (("OWN", (60, 60, 60), "line"), ("PHONE", (60, 60, 60), "dash"),
                    ("YOURS", (60, 60, 60), "dot")),
    "error": (("total", ERROR_COLORS[0], "line"), ("heading", ERROR_COLORS[1], "line"),
              ("inclination", ERROR_COLORS[2], "line"), ("OWN", (60, 60, 60), "line"),
              ("YOURS", (60, 60, 60), "dot")),
}
LEGEND_TIPS = {
    "rejected": "samples the filter rejected (a gate fired): a red band along the bottom",
    "off": "the sensor was switched off: the filter did not use these samples (a grey dashed "
           "band; no gate was asked)",
}
USER_TOGGLES = (("orientation", "YOURS"), ("error", "YOURS"), ("error", "OWN"))


READOUT_ROWS = {
    "sensors": ((("acc", "m/s²"), ("gyr", "rad/s"), ("mag", "µT")), ("x", "y", "z", "norm")),
    "orientation": ((("OWN", "°"), ("PHONE", "°"), ("YOURS", "°")), EULER_NAMES),
    "error": (((None, "°"), ("YOURS", "°")), ("total", "heading", "inclination")),
}


def readout_table(values: dict[str, float], t: float, span: float, group: str) -> str:
    """The cursor's readout: a small HTML table of the tab's values with units."""
    rows, columns = READOUT_ROWS[group]
    head = "".join(f"<th align='right'>&nbsp;{c}&nbsp;</th>" for c in columns)
    lines = [f"<table cellspacing='0' cellpadding='1'><tr><th align='left'>t = "
             f"{time_text(t, span, 3)} s</th>{head}<th></th></tr>"]
    for name, unit in rows:
        labels = [column if name is None else f"{name} {column}" for column in columns]
        if name == "YOURS" and all(label not in values for label in labels):
            continue            # no YOURS loaded (or all its curves hidden)
        cells = []
        for label in labels:
            value = values.get(label)
            cells.append("–" if value is None or not math.isfinite(value) else f"{value:.3f}")
        title = name or "OWN vs PHONE"
        if group == "error" and name == "YOURS":
            title = "YOURS vs PHONE"
        lines.append(f"<tr><td>{title}</td>" + "".join(f"<td align='right'>&nbsp;{c}&nbsp;</td>"
                                                        for c in cells)
                     + f"<td>{unit}</td></tr>")
    return "".join(lines) + "</table>"


# ---- graphics items ------------------------------------------------------------------------

class Curve(pg.PlotCurveItem):
    """A PlotCurveItem whose bounds come with the data (computed in numpy by the panel).

    pyqtgraph recomputes a curve's bounds, with pixel padding, every time the view moves,
    i.e. on every frame while following; here they are set once per setData.
    """

    def __init__(self, **options) -> None:
        self._rect = QtCore.QRectF()
        super().__init__(**options)

    def set_curve(self, x: np.ndarray, y: np.ndarray, finite: bool,
                  y_bounds: tuple[float, float] | None, connect: str | None = None) -> None:
        """New points; `finite`: no NaN in y (the fast path); y_bounds: (min, max) of y."""
        if len(x) and y_bounds is not None:
            low, high = y_bounds
            x_pad = 0.01 * max(float(x[-1] - x[0]), 1e-9)
            y_pad = 0.02 * max(high - low, 1e-9)
            self._rect = QtCore.QRectF(float(x[0]) - x_pad, low - y_pad,
                                       float(x[-1] - x[0]) + 2 * x_pad, high - low + 2 * y_pad)
        else:
            self._rect = QtCore.QRectF()
        self.setData(x, y, connect=connect or ("all" if finite else "finite"),
                     skipFiniteCheck=finite)

    def dataBounds(self, ax: int, frac: float = 1.0, orthoRange=None):  # noqa: N802 (pg name)
        if self._rect.isNull():
            return (None, None)
        if ax == 0:
            return (self._rect.left(), self._rect.right())
        return (self._rect.top(), self._rect.bottom())

    def boundingRect(self) -> QtCore.QRectF:  # noqa: N802 (Qt name)
        return self._rect


class TimeAxis(pg.AxisItem):
    """Seconds since the session's start ("m:ss" for long views); the phone's clock on hover."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.origin_ms: int | None = None
        self.enableAutoSIPrefix(False)

    def tickStrings(self, values, scale, spacing):  # noqa: N802 (pg name)
        low, high = self.range
        span = abs(high - low)
        decimals = 0 if spacing >= 1.0 else (1 if spacing >= 0.1 else 2)
        return [time_text(v, span, decimals) for v in values]

    def set_origin(self, origin_ms: int | None) -> None:
        if origin_ms == self.origin_ms:
            return
        self.origin_ms = origin_ms
        self.setToolTip("" if origin_ms is None else
                        f"time since the session's start; 0 is {origin_ms / 1000.0:.3f} s on "
                        "the phone's clock")


def cache_painting(item: QtWidgets.QGraphicsItem) -> None:
    """Paint `item` and its children from pixmaps redrawn only when they call update():
    axis titles are text, and laying out text is the slowest part of a frame."""
    item.setCacheMode(QtWidgets.QGraphicsItem.CacheMode.DeviceCoordinateCache)
    for child in item.childItems():
        cache_painting(child)


def legend_icon(color: tuple[int, int, int], style: str) -> QtGui.QIcon:
    pixmap = QtGui.QPixmap(22, 12)
    pixmap.fill(QtCore.Qt.GlobalColor.transparent)
    painter = QtGui.QPainter(pixmap)
    if style == "band":
        painter.fillRect(QtCore.QRectF(1, 8, 20, 3), QtGui.QColor(*color))
    elif style == "dashed band":
        for x in (1, 9, 17):
            painter.fillRect(QtCore.QRectF(x, 8, 5, 3), QtGui.QColor(*color))
    else:
        pen = QtGui.QPen(QtGui.QColor(*color), 2)
        if style == "dash":
            pen.setStyle(QtCore.Qt.PenStyle.DashLine)
        elif style == "dot":
            pen.setStyle(QtCore.Qt.PenStyle.DotLine)
        painter.setPen(pen)
        painter.drawLine(1, 6, 21, 6)
    painter.end()
    return QtGui.QIcon(pixmap)


@dataclass
class PlotGroup:
    """One tab: its legend toggles and its plots in one graphics view."""

    key: str
    widget: QtWidgets.QWidget
    graphics: pg.GraphicsLayoutWidget
    legend: QtWidgets.QWidget
    toggles: dict[str, QtWidgets.QToolButton] = field(default_factory=dict)
    plots: list[str] = field(default_factory=list)


class NoDataText(QtWidgets.QGraphicsSimpleTextItem):
    """A plot's no-data message, centred in its view box (in the box's own pixels, so it stays
    put whatever range the plot shows)."""

    def __init__(self, view_box: pg.ViewBox) -> None:
        super().__init__(view_box)
        self.setBrush(QtGui.QBrush(QtGui.QColor(110, 112, 118)))
        font = self.font()
        if font.pointSizeF() > 0:
            font.setPointSizeF(font.pointSizeF() * 1.15)
            self.setFont(font)
        self.setZValue(1000)
        self.setVisible(False)
        self._view_box = view_box
        view_box.sigResized.connect(self._centre)

    def set_text(self, text: str) -> None:
        if text == self.text():
            return
        self.setText(text)
        self.setVisible(bool(text))
        self._centre()

    def _centre(self, *args) -> None:
        box = self._view_box.boundingRect()
        own = self.boundingRect()
        self.setPos(box.center().x() - own.width() / 2, box.center().y() - own.height() / 2)


# ---- the panel -----------------------------------------------------------------------------

class PlotPanel(QtWidgets.QWidget):
    """Toolbar (window length, Pause/Follow, Cursor, Unwrap, Clear), three tabs of plots and
    the cursor readout."""

    paused_changed = QtCore.Signal(bool)

    def __init__(self, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.following = True
        self.pause_reason = ""          # "paused" or "zoomed" while not following
        self.unwrapped = False
        self._dirty = True
        self._last_range: tuple[float, float] | None = None
        self._setting_range = False
        self._syncing_cursor = False
        self.origin_ms: int | None = None
        # the rolling buffers the snapshots fill; `buffers` is what is drawn: these, or a
        # replay's whole session (set_session)
        self.live_buffers = {key: SampleBuffer(columns)
                             for key, columns in STREAM_COLUMNS.items()}
        self.buffers = self.live_buffers
        self.session = None
        self._position: float | None = None
        self._marker_lines: dict[str, list[pg.InfiniteLine]] = {}
        self._markers_shown: tuple = ()
        self.plots: dict[str, pg.PlotItem] = {}
        self.curves: list[tuple[CurveSpec, Curve]] = []
        self.bands: dict[str, Curve] = {}
        self.off_bands: dict[str, Curve] = {}
        # per banded sensor: the stretches in which its samples arrived while it was switched
        # off (said by each snapshot's status)
        self.off_spans = {"acc": OffSpans(OFF_JOIN_S), "mag": OffSpans(OFF_JOIN_S)}
        self._off_band_spans: dict[str, np.ndarray] = {}
        self.gate_lines: dict[str, tuple[pg.InfiniteLine, pg.InfiniteLine]] = {}
        self.cursors: dict[str, pg.InfiniteLine] = {}
        self.groups: dict[str, PlotGroup] = {}
        self._band_spans: dict[str, np.ndarray] = {}
        self.no_data_items: dict[str, NoDataText] = {}
        self.user_present = False

        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(2)
        layout.addLayout(self._build_toolbar())
        self.readout_label = QtWidgets.QLabel("")
        self.readout_label.setObjectName("cursor_readout")
        self.readout_label.setTextFormat(QtCore.Qt.TextFormat.RichText)
        self.readout_label.setTextInteractionFlags(
            QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        self.readout_label.setVisible(False)
        layout.addWidget(self.readout_label)
        self.tabs = QtWidgets.QTabWidget()
        self.tabs.setObjectName("plot_tabs")
        self.tabs.setDocumentMode(True)
        for key, title in GROUPS:
            group = self._build_group(key)
            self.groups[key] = group
            self.tabs.addTab(group.widget, title)
        self.tabs.currentChanged.connect(self._on_tab_changed)
        layout.addWidget(self.tabs, 1)
        for spec in curve_specs():
            self._add_curve(spec)
        self.set_user_present(False)

    # ---- construction ----------------------------------------------------------------------

    def _build_toolbar(self) -> QtWidgets.QHBoxLayout:
        toolbar = QtWidgets.QHBoxLayout()
        toolbar.setContentsMargins(2, 0, 2, 0)
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
                                     "(Space when live)")
        self.pause_button.toggled.connect(lambda checked: self.set_paused(checked))
        self.follow_button = QtWidgets.QPushButton("Follow")
        self.follow_button.setObjectName("follow_button")
        self.follow_button.setToolTip("Show the newest samples again (a replay: its position; "
                                      "a seek, Home or Play follows it too)")
        self.follow_button.clicked.connect(self.follow)
        self.follow_button.setEnabled(False)        # following already
        # While not following: what the plots show instead, in a colour that stands out
        self.follow_note = ElidedLabel("", minimum_text="not following…")
        self.follow_note.setObjectName("follow_note")
        self.follow_note.setStyleSheet(FOLLOW_NOTE_STYLE)
        self.follow_note.setVisible(False)
        self.cursor_checkbox = QtWidgets.QCheckBox("Cursor")
        self.cursor_checkbox.setToolTip("A draggable line reading every visible curve")
        self.cursor_checkbox.toggled.connect(self.set_cursor_visible)
        self.unwrap_checkbox = QtWidgets.QCheckBox("Unwrap angles")
        self.unwrap_checkbox.setToolTip("Euler angles continuous over whole turns (OWN and PHONE "
                                        "in the same turn) instead of wrapped to ±180°")
        self.unwrap_checkbox.toggled.connect(self.set_unwrapped)
        self.clear_button = QtWidgets.QPushButton("Clear")
        self.clear_button.setToolTip("Forget the plotted samples (Ctrl+L)")
        self.clear_button.clicked.connect(self.clear)
        for widget in (self.window_spin, self.pause_button, self.follow_button,
                       self.cursor_checkbox, self.unwrap_checkbox, self.clear_button):
            toolbar.addWidget(widget)
        toolbar.addWidget(self.follow_note)
        toolbar.addStretch(1)
        return toolbar

    def _build_group(self, key: str) -> PlotGroup:
        widget = QtWidgets.QWidget()
        widget.setObjectName(f"plot_group_{key}")
        box = QtWidgets.QVBoxLayout(widget)
        box.setContentsMargins(0, 0, 0, 0)
        box.setSpacing(0)
        legend = QtWidgets.QWidget()
        legend.setObjectName(f"legend_{key}")
        row = QtWidgets.QHBoxLayout(legend)
        row.setContentsMargins(LEFT_AXIS_WIDTH, 0, 0, 0)
        row.setSpacing(4)
        graphics = pg.GraphicsLayoutWidget()
        graphics.setBackground((250, 250, 252))
        # Every curve moves on every frame: keeping Qt's spatial index (a BSP tree) of the
        # items up to date costs more than it saves.
        graphics.scene().setItemIndexMethod(QtWidgets.QGraphicsScene.ItemIndexMethod.NoIndex)
        group = PlotGroup(key, widget, graphics, legend)
        for name, color, style in LEGENDS[key]:
            button = QtWidgets.QToolButton()
            button.setText(name)
            button.setIcon(legend_icon(color, style))
            button.setToolButtonStyle(QtCore.Qt.ToolButtonStyle.ToolButtonTextBesideIcon)
            button.setCheckable(True)
            button.setChecked(True)
            button.setAutoRaise(True)
            button.setToolTip(f"Show or hide {LEGEND_TIPS.get(name, name)}")
            button.toggled.connect(lambda checked, g=key, n=name: self.set_shown(g, n, checked))
            row.addWidget(button)
            group.toggles[name] = button
        row.addStretch(1)
        box.addWidget(legend)
        box.addWidget(graphics, 1)
        specs = [spec for spec in PLOTS if spec.group == key]
        for index, spec in enumerate(specs):
            self._new_plot(group, spec, last=index == len(specs) - 1)
        return group

    def _new_plot(self, group: PlotGroup, spec: PlotSpec, last: bool) -> pg.PlotItem:
        axis = TimeAxis("bottom")
        plot = group.graphics.addPlot(row=len(group.plots), col=0, axisItems={"bottom": axis})
        plot.setLabel("left", spec.title, units=spec.units)
        left = plot.getAxis("left")
        left.enableAutoSIPrefix(False)
        left.setWidth(LEFT_AXIS_WIDTH)
        left.setToolTip(spec.tooltip)
        for name in ("left", "bottom"):
            # Fewer tick levels: the time axis is regenerated on every frame while following.
            plot.getAxis(name).setStyle(maxTickLevel=1, maxTextLevel=1)
        # The y axis changes only when the y range does: paint it from a cached pixmap.
        cache_painting(left)
        # Clipping and peak downsampling are done here, in numpy, once per stream and frame;
        # y follows the visible samples (computed in refresh()).
        plot.setClipToView(False)
        plot.setDownsampling(ds=1, auto=False, mode="peak")
        plot.disableAutoRange()
        plot.getViewBox().setMouseEnabled(x=True, y=False)
        plot.setMenuEnabled(True)
        if last:
            plot.setLabel("bottom", "time since start", units="s")
        else:
            # Only the bottom plot of a tab shows time: the others share it.
            plot.hideAxis("bottom")
        cursor = pg.InfiniteLine(angle=90, movable=True, pen=pg.mkPen((120, 60, 160), width=1.5))
        cursor.setVisible(False)
        cursor.sigPositionChanged.connect(self._on_cursor_moved)
        plot.addItem(cursor, ignoreBounds=True)
        self.cursors[spec.key] = cursor
        view_box = plot.getViewBox()
        view_box.sigRangeChangedManually.connect(self._on_manual_range)
        view_box.sigXRangeChanged.connect(self._on_x_range_changed)
        if spec.key in ("acc", "mag"):
            band = Curve(pen=pg.mkPen(REJECTED_COLOR, width=4), antialias=False)
            plot.addItem(band, ignoreBounds=True)
            self.bands[spec.key] = band
            off = Curve(pen=pg.mkPen(OFF_COLOR, width=4, style=QtCore.Qt.PenStyle.DashLine),
                        antialias=False)
            plot.addItem(off, ignoreBounds=True)
            self.off_bands[spec.key] = off
            pen = pg.mkPen(GATE_COLOR, width=1, style=QtCore.Qt.PenStyle.DashLine)
            lines = (pg.InfiniteLine(angle=0, pen=pen), pg.InfiniteLine(angle=0, pen=pen))
            for line in lines:
                line.setVisible(False)
                plot.addItem(line, ignoreBounds=True)
            self.gate_lines[spec.key] = lines
        group.plots.append(spec.key)
        self.plots[spec.key] = plot
        self.no_data_items[spec.key] = NoDataText(view_box)
        return plot

    def _add_curve(self, spec: CurveSpec) -> None:
        # 1-px pens without antialiasing: Qt's fast line path (dashes cost more: PHONE and
        # YOURS only).
        style = (QtCore.Qt.PenStyle.DashLine if spec.dashed else
                 QtCore.Qt.PenStyle.DotLine if spec.dotted else QtCore.Qt.PenStyle.SolidLine)
        curve = Curve(pen=pg.mkPen(spec.color, width=1, style=style), antialias=False)
        self.plots[spec.plot].addItem(curve)
        self.curves.append((spec, curve))

    # ---- data in ---------------------------------------------------------------------------

    def append(self, chunk: PlotChunk, enabled: dict[str, bool] | None = None) -> None:
        """Store the new samples; drawing waits for the next refresh(). enabled: the sensor
        switches these samples were filtered with (FilterStatus.sensors_enabled): the samples
        of a switched-off sensor are drawn as "off", not as rejected."""
        for key, t, values, rejected in (("acc", chunk.t_acc, chunk.acc, chunk.acc_rejected),
                                         ("gyr", chunk.t_gyr, chunk.gyr, None),
                                         ("mag", chunk.t_mag, chunk.mag, chunk.mag_rejected)):
            if not len(t):
                continue
            values = np.asarray(values, float).reshape(len(t), 3)
            columns = [values, np.linalg.norm(values, axis=1, keepdims=True)]
            if rejected is not None:
                flags = np.asarray(rejected, float).reshape(-1, 1)
                columns.append(flags if len(flags) == len(values) else np.zeros((len(t), 1)))
            self._append(key, t, np.hstack(columns))
        for key, t, values in (("own", chunk.t_est, chunk.own_euler_deg),
                               ("phone", chunk.t_ori, chunk.phone_euler_deg),
                               ("error", chunk.t_err, chunk.error_deg),
                               ("user", chunk.t_user, chunk.user_euler_deg),
                               ("user_error", chunk.t_user_err, chunk.user_error_deg)):
            if len(t):
                self._append(key, t, np.asarray(values, float).reshape(len(t), 3))
        for key, t in (("acc", chunk.t_acc), ("mag", chunk.t_mag)):
            if enabled is not None and enabled.get(key) is False and len(t):
                self.off_spans[key].add(float(t[0]), float(t[-1]))
                self._dirty = True

    def set_user_present(self, present: bool) -> None:
        """YOURS loaded or not: its legend toggles (and OWN's beside it in the error tab) show
        only while there is a YOURS to tell apart; unloading forgets its curves."""
        present = bool(present)
        if not present:
            for key in USER_STREAMS:
                self.live_buffers[key].clear()
        self.user_present = present
        for group, name in USER_TOGGLES:
            self.groups[group].toggles[name].setVisible(present)
        self.plots["error"].setLabel("left", "vs PHONE" if present else "OWN vs PHONE",
                                     units="°")
        self._dirty = True

    def replace_user_history(self, t_s: np.ndarray, euler_deg: np.ndarray, t_err_s: np.ndarray,
                             error_deg: np.ndarray) -> None:
        """YOURS re-run over the session after a reload: its curves drawn so far replaced."""
        for key, t, values in (("user", t_s, euler_deg), ("user_error", t_err_s, error_deg)):
            buffer = self.live_buffers[key]
            buffer.clear()
            t = np.asarray(t, np.float64)
            if len(t):
                buffer.append(t, np.asarray(values, float).reshape(len(t), 3))
        self._dirty = True

    def _append(self, key: str, t: np.ndarray, values: np.ndarray) -> None:
        t = np.asarray(t, dtype=np.float64)
        buffer = self.live_buffers[key]
        if key in USER_STREAMS:
            # After a re-run's history the live rows may overlap it: keep only the newer ones.
            newer = t > buffer.last_time() + 1e-9
            if not newer.all():
                if buffer.size and t[0] < buffer.last_time() - 5.0:
                    buffer.clear()     # far earlier: a new session (the others clear too)
                else:
                    t, values = t[newer], values[newer]
            if not len(t):
                return
        # A new session (a new connection, a replay that loops or seeks back) restarts the
        # time since the start: start the rolling plots afresh.
        if t[0] < buffer.last_time() - 1e-6:
            for other in self.live_buffers.values():
                other.clear()
            if self.session is None:
                self._clear_off_spans()
            self._dirty = self._dirty or self.session is None
        buffer.append(t, values)
        # While paused, samples after the frozen view change nothing on screen; a replay's
        # whole session is drawn from its own data.
        if self.session is None and (self.following or t[0] <= self.x_range()[1]):
            self._dirty = True

    def set_session(self, session) -> None:
        """Draw a replay's whole session (app.engine.sessions.index.SessionPlot: its arrays,
        not copied) instead of the rolling buffers; None: back to the rolling buffers. Paused,
        the user scrolls and zooms over the whole recording."""
        if session is self.session:
            return
        self.session = session
        if session is None:
            self.buffers = self.live_buffers
            self._position = None
        else:
            # YOURS is not in the session's index (it is the user's code, re-run on reload):
            # its curves stay the rolling ones.
            self.buffers = {key: SampleBuffer.from_arrays(*session.streams[key])
                            if key in session.streams else self.live_buffers[key]
                            for key in STREAM_COLUMNS}
        self._dirty = True

    def set_position(self, t_s: float | None) -> None:
        """The replay's position (s since the start): a whole session's plots follow it."""
        if t_s != self._position:
            self._position = t_s
            if self.session is not None and self.following:
                self._dirty = True

    def set_markers(self, markers) -> None:
        """Markers (app.engine.sessions.session.Marker) as labelled vertical lines in every plot."""
        shown = tuple((m.id, m.t_s, m.title) for m in markers if m.t_s is not None)
        if shown == self._markers_shown:
            return
        self._markers_shown = shown
        pen = pg.mkPen(MARKER_COLOR, width=1, style=QtCore.Qt.PenStyle.DashLine)
        for key, plot in self.plots.items():
            for line in self._marker_lines.pop(key, []):
                plot.removeItem(line)
            lines = []
            for number, t_s, title in shown:
                line = pg.InfiniteLine(pos=t_s, angle=90, movable=False, pen=pen,
                                       label=title if key in FIRST_PLOTS else None,
                                       labelOpts={"position": 0.95, "color": MARKER_COLOR})
                line.setToolTip(f"marker {title} at {time_text(t_s, 600.0, 1)}")
                plot.addItem(line, ignoreBounds=True)
                lines.append(line)
            self._marker_lines[key] = lines

    def set_no_data(self, key: str, text: str) -> None:
        """Say why a plot is empty ("no gyroscope in this stream"), centred over it instead of
        an empty axis (its y values hidden); "" when it has data to show."""
        item = self.no_data_items[key]
        if text != item.text():
            item.set_text(text)
            self.plots[key].getAxis("left").setStyle(showValues=not text)

    def no_data_text(self, key: str) -> str:
        """The plot's no-data text ("" when none is shown)."""
        return self.no_data_items[key].text()

    def set_status(self, status: FilterStatus) -> None:
        """Draw the gate limits on the norms: g ± acc_gate and L ± mag_gate."""
        diagnostics = status.diagnostics
        for key, center, gate in (("acc", diagnostics.g, diagnostics.acc_gate),
                                  ("mag", diagnostics.mag_expected, diagnostics.mag_gate)):
            shown = self.groups["sensors"].toggles["gates"].isChecked()
            valid = math.isfinite(center) and math.isfinite(gate) and shown
            for line, sign in zip(self.gate_lines[key], (1.0, -1.0)):
                line.setVisible(valid)
                if valid and abs(line.value() - (center + sign * gate)) > 1e-9:
                    line.setValue(center + sign * gate)

    def set_time_origin(self, origin_ms: int | None) -> None:
        """The phone's clock at time 0 (shown when hovering over the time axis)."""
        if origin_ms == self.origin_ms:
            return
        self.origin_ms = origin_ms
        for plot in self.plots.values():
            plot.getAxis("bottom").set_origin(origin_ms)

    # ---- view state ------------------------------------------------------------------------

    @property
    def paused(self) -> bool:
        return not self.following

    @property
    def window_s(self) -> float:
        return float(self.window_spin.value())

    def set_window_s(self, seconds: float) -> None:
        self.window_spin.setValue(float(seconds))

    def current_group(self) -> str:
        return GROUPS[self.tabs.currentIndex()][0]

    def set_current_group(self, key: str) -> None:
        self.tabs.setCurrentIndex([k for k, _ in GROUPS].index(key))

    def set_paused(self, paused: bool, reason: str = "paused") -> None:
        """Pause: the view stays where it is while samples keep being stored. `reason` ("paused"
        or "zoomed": a plot dragged or zoomed by hand) is said in the toolbar's note, with the
        time range shown, until the plots follow again (Follow; a replay's seek, Home or
        Play)."""
        paused = bool(paused)
        if paused:
            self.pause_reason = reason
        if paused == self.paused:
            self._show_follow_state()
            return
        self.following = not paused
        self.pause_button.blockSignals(True)
        self.pause_button.setChecked(paused)
        self.pause_button.blockSignals(False)
        self.pause_button.setText("Paused" if paused else "Pause")
        self.follow_button.setEnabled(paused)
        self._dirty = True
        self._show_follow_state()
        self.paused_changed.emit(paused)

    def follow_text(self) -> str:
        """The toolbar's note: "" while following, else why not and which times are shown."""
        if self.following:
            return ""
        low, high = self.x_range()
        span = high - low
        why = "zoomed by hand" if self.pause_reason == "zoomed" else "paused"
        low_text, high_text = time_text(low, span, 1), time_text(high, span, 1)
        unit = "" if ":" in high_text else " s"
        return f"not following ({why}): showing {low_text} – {high_text}{unit}"

    def _show_follow_state(self) -> None:
        text = self.follow_text()
        if self.follow_note.text() != text:
            self.follow_note.setText(text, (text.split(": showing ")[0],))
            self.follow_note.setToolTip(
                f"{text}\nThe plots stay on these times while samples keep arriving; Follow "
                "(or, in a replay, a seek, Home or Play) shows the newest again" if text else "")
        if self.follow_note.isVisible() != bool(text):
            self.follow_note.setVisible(bool(text))

    def follow(self) -> None:
        self.set_paused(False)

    def toggle_paused(self) -> None:
        self.set_paused(not self.paused)

    def set_unwrapped(self, unwrapped: bool) -> None:
        self.unwrapped = bool(unwrapped)
        if self.unwrap_checkbox.isChecked() != self.unwrapped:
            self.unwrap_checkbox.setChecked(self.unwrapped)
        self._dirty = True

    def set_shown(self, group: str, name: str, shown: bool) -> None:
        """A legend toggle: show or hide every curve (or the band, the gates) it names."""
        toggle = self.groups[group].toggles[name]
        if toggle.isChecked() != bool(shown):
            toggle.setChecked(bool(shown))
            return
        if name == "rejected":
            for band in self.bands.values():
                band.setVisible(bool(shown))
        elif name == "off":
            for band in self.off_bands.values():
                band.setVisible(bool(shown))
        elif name == "gates" and not shown:     # shown again with the next status
            for lines in self.gate_lines.values():
                for line in lines:
                    line.setVisible(False)
        toggles = self.groups[group].toggles
        for spec, curve in self.curves:
            if name in spec.tags and self.plots[spec.plot] in self._group_plots(group):
                # shown when every toggle naming it is on (a YOURS heading: YOURS and heading)
                curve.setVisible(all(toggles[tag].isChecked() for tag in spec.tags
                                     if tag in toggles))
        self._dirty = True

    def _group_plots(self, group: str) -> list[pg.PlotItem]:
        return [self.plots[key] for key in self.groups[group].plots]

    def clear(self) -> None:
        for buffer in self.live_buffers.values():
            buffer.clear()
        self._clear_off_spans()
        self._dirty = True
        self.refresh()

    def _clear_off_spans(self) -> None:
        for spans in self.off_spans.values():
            spans.clear()
        self._dirty = True

    def latest_time(self) -> float:
        if self.session is not None and self._position is not None:
            return self._position
        return max(buffer.last_time() for buffer in self.buffers.values())

    def x_range(self) -> tuple[float, float]:
        plot = self.plots[self.groups[self.current_group()].plots[0]]
        low, high = plot.getViewBox().viewRange()[0]
        return float(low), float(high)

    def _on_tab_changed(self, index: int) -> None:
        low, high = self._last_range or self.x_range_of_any()
        self.set_x_range(low, high)
        self._dirty = True
        if self.cursor_checkbox.isChecked():
            self.set_cursor_time(self.cursor_time())

    def x_range_of_any(self) -> tuple[float, float]:
        low, high = self.plots["acc"].getViewBox().viewRange()[0]
        return float(low), float(high)

    def _on_manual_range(self, *args) -> None:
        # The user dragged or zoomed a plot: they want to look at it, so stop following.
        if not self._setting_range:
            self.set_paused(True, "zoomed")

    def _on_x_range_changed(self, view_box, x_range) -> None:
        """A plot's time range changed by hand (drag, zoom, its menu): the others follow."""
        if self._setting_range:
            return
        self.set_x_range(*x_range, source=view_box)
        self._dirty = True

    def set_x_range(self, low: float, high: float, source=None) -> None:
        """Show times low..high (s since the start) in every plot (but `source`)."""
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
        """Redraw the current tab's visible window if anything changed (once per frame)."""
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
        if not self.following:
            self._show_follow_state()
        group = self.current_group()
        bounds: dict[str, list[tuple[float, float]]] = {key: [] for key in self.groups[group].plots}
        for stream in self._streams_of(group):
            self._draw_stream(stream, t_start, t_end, bounds)
        for key, spans in bounds.items():
            finite = [(low, high) for low, high in spans if math.isfinite(low)
                      and math.isfinite(high)]
            if finite:
                self._fit_y(key, min(low for low, _ in finite), max(high for _, high in finite))
        for key in self.bands:
            if key in bounds:
                self._draw_band(key)
        # Apply the new ranges now: pyqtgraph would do it lazily at the start of the paint,
        # which moves every item once more and so asks for a second paint of each frame.
        for key in self.groups[group].plots:
            self.plots[key].getViewBox().prepareForPaint()
        if self.cursor_checkbox.isChecked():
            self._update_readout()

    @staticmethod
    def _streams_of(group: str) -> tuple[str, ...]:
        return {"sensors": ("acc", "gyr", "mag"), "orientation": ("own", "phone", "user"),
                "error": ("error", "user_error")}[group]

    def _display_window(self, stream: str, t_start: float, t_end: float
                        ) -> tuple[np.ndarray, np.ndarray, int]:
        """The stream's samples in view as they are drawn (Euler: wrapped with breaks, or
        unwrapped; PHONE in OWN's turn) and the running index of the first."""
        buffer = self.buffers[stream]
        window = buffer.window(t_start, t_end)
        t, values = buffer.t[window], buffer.values[window]
        first = buffer.first_index + window.start
        if stream in ("own", "phone", "user") and len(t):
            if self.unwrapped:
                own = self.buffers["own"]
                own_window = own.window(t_start, t_end)
                own_t = own.t[own_window]
                own_values = unwrap_deg(own.values[own_window])
                values = own_values if stream == "own" else unwrap_in_turn(
                    own_t, own_values, t, values)
            else:
                t, values = break_at_wraps(t, values)
        return t, values, first

    def _draw_stream(self, stream: str, t_start: float, t_end: float,
                     bounds: dict[str, list[tuple[float, float]]]) -> None:
        """Hand one stream's visible window, peak-downsampled to the plot's width, to its
        curves; collect each plot's y span."""
        t, values, first = self._display_window(stream, t_start, t_end)
        curves = [(spec, curve) for spec, curve in self.curves if spec.stream == stream]
        width = max(int(self.plots[curves[0][0].plot].getViewBox().width()), 1)
        shown_t, shown = peak_downsample(t, values, first, width)
        for spec, curve in curves:
            if not curve.isVisible():
                continue    # a hidden curve gets the current points when shown (dirty)
            column = shown[:, spec.column] if len(shown_t) else np.empty(0)
            low = float(np.fmin.reduce(column)) if len(column) else math.nan
            high = float(np.fmax.reduce(column)) if len(column) else math.nan
            finite = bool(np.isfinite(column).all())
            valid = math.isfinite(low) and math.isfinite(high)
            curve.set_curve(shown_t, column, finite, (low, high) if valid else None)
            if valid:
                bounds[spec.plot].append((low, high))
        if stream in self.bands:
            off = self.off_spans[stream].mask(t)
            rejected = (values[:, 4] > 0.5) & ~off if len(t) else np.zeros(0, bool)
            self._band_spans[stream] = rejected_spans(t, rejected)
            self._off_band_spans[stream] = rejected_spans(t, off)

    def _draw_band(self, key: str) -> None:
        """The rejected samples as ticks along the bottom of the plot (the curves stay
        visible above them), and where the sensor was switched off a grey dashed band at the
        same height."""
        low, high = self.plots[key].getViewBox().viewRange()[1]
        level = low + BAND_FRACTION * (high - low)
        for bands, spans in ((self.bands, self._band_spans),
                             (self.off_bands, self._off_band_spans)):
            x = spans.get(key, np.empty((0, 2))).reshape(-1)
            bands[key].set_curve(x, np.full(len(x), level), True,
                                 (level, level) if len(x) else None, connect="pairs")

    def off_band_spans(self, key: str) -> np.ndarray:
        """The "off" stretches drawn in the plot's visible window, (n, 2) [start, end] s."""
        return self._off_band_spans.get(key, np.empty((0, 2)))

    def rejected_band_spans(self, key: str) -> np.ndarray:
        """The rejected stretches drawn in the plot's visible window, (n, 2) [start, end] s."""
        return self._band_spans.get(key, np.empty((0, 2)))

    def _fit_y(self, key: str, low: float, high: float) -> None:
        """Fit the y range to the visible curves' span (and gate lines), with hysteresis so the
        axis does not rescale, and re-layout, on every frame."""
        for line in self.gate_lines.get(key, ()):
            if line.isVisible():
                low, high = min(low, line.value()), max(high, line.value())
        if key in ("yaw", "roll") and not self.unwrapped:
            low, high = min(low, -180.0), max(high, 180.0)
        elif key == "pitch" and not self.unwrapped:
            low, high = min(low, -90.0), max(high, 90.0)
        span = max(high - low, 1e-6 * max(abs(high), 1.0), 1e-9)
        margin = 0.08 * span
        if key in self.bands:
            margin = max(margin, 1.5 * BAND_FRACTION * span)   # room for the band below
        low, high = low - margin, high + 0.08 * span
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
        """Value of every visible curve at the cursor (nearest stored sample, as drawn), by
        its label ("acc x", "OWN yaw", "total", ...); NaN where a stream has no samples."""
        t_cursor = self.cursor_time()
        values: dict[str, float] = {}
        for stream in STREAM_COLUMNS:
            if stream in USER_STREAMS and not self.user_present:
                continue
            buffer = self.buffers[stream]
            t = buffer.t
            index = None
            if len(t):
                index = int(np.clip(np.searchsorted(t, t_cursor), 0, len(t) - 1))
                if index > 0 and abs(t[index - 1] - t_cursor) <= abs(t[index] - t_cursor):
                    index -= 1
            for spec, curve in self.curves:
                if spec.stream == stream and curve.isVisible():
                    values[spec.label] = (float(buffer.values[index, spec.column])
                                          if index is not None else math.nan)
        return values

    def _update_readout(self) -> None:
        if not self.cursor_checkbox.isChecked():
            return
        values = self.cursor_values()
        span = self.x_range()[1] - self.x_range()[0]
        self.readout_label.setText(readout_table(values, self.cursor_time(), span,
                                                 self.current_group()))
