"""The numbers behind the plots, in numpy (no Qt): bounded sample buffers, peak downsampling,
Euler angles wrapped with their lines broken at a wrap or unwrapped in one turn, rejected
samples as spans, and time labels.
"""

from __future__ import annotations

import math

import numpy as np

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
