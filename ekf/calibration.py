"""Calibration statistics from rest data (course task 2).

With the phone lying still, the sample means and covariances of the three sensors give the
filter's tuning: g = ||mean acc||, the gyroscope bias = mean gyr, R_w / R_a / R_m = the sample
covariances, and the Earth field m0 = (0, sqrt(mx² + my²), mz) in ENU. The course computes m0
from a reading taken flat; here the mean field is first turned into the level frame using the tilt
of the mean accelerometer vector, so a phone resting on a slope gives the same m0 (for a flat
phone the two agree exactly). Histograms with the matching Gaussian show whether the noise is
Gaussian.

`find_rest_segment` finds the longest still stretch of a log automatically, so a recording with
handling at its start or end can be calibrated without trimming it by hand.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from ekf.estimator import SENSORS as _FILTER_ORDER

if TYPE_CHECKING:
    from ekf.settings import EKFSettings

#: The sensors in the order calibration reports, tables and JSON list them: alphabetical
#: (acc, gyr, mag), not the filters' feeding order of :data:`ekf.SENSORS`.
REPORT_ORDER: tuple[str, ...] = tuple(sorted(_FILTER_ORDER))
UNITS = {"acc": "m/s^2", "gyr": "rad/s", "mag": "uT"}
AXES = ("x", "y", "z")


@dataclass
class SensorStatistics:
    """Rest statistics of one 3-axis sensor, sensor frame. Units: those of the sensor.

    samples: the rows used (N, 3), NaN rows dropped; mean (3,); cov (3, 3), unbiased (N - 1);
    std (3,) = sqrt(diag(cov)).
    """

    samples: np.ndarray = field(repr=False)
    mean: np.ndarray
    cov: np.ndarray
    std: np.ndarray

    @property
    def count(self) -> int:
        return int(len(self.samples))

    @classmethod
    def from_samples(cls, samples: ArrayLike) -> "SensorStatistics | None":
        """Statistics of the finite rows of `samples` (N, 3); None with fewer than 2 such rows."""
        a = np.asarray(samples, dtype=float).reshape(-1, 3)
        a = a[np.all(np.isfinite(a), axis=1)]
        if len(a) < 2:
            return None
        cov = np.cov(a, rowvar=False)
        return cls(samples=a, mean=a.mean(axis=0), cov=cov, std=np.sqrt(np.diag(cov)))


@dataclass
class Histogram:
    """One sensor axis: bin counts (bins,), bin edges (bins + 1,), the counts as a probability
    density (bins,) and the Gaussian with the sample mean/std on a fine grid (pdf_x, pdf) for the
    overlay (the student reports' figure 1)."""

    sensor: str
    axis: str
    counts: np.ndarray
    edges: np.ndarray
    density: np.ndarray
    pdf_x: np.ndarray
    pdf: np.ndarray
    mean: float
    std: float


def _level_rotation(acc_mean: np.ndarray) -> np.ndarray:
    """The smallest rotation R (3, 3) with R acc_mean ∝ (0, 0, 1): sensor frame -> a level frame
    with an unknown heading. Identity for a flat phone."""
    a = acc_mean / np.linalg.norm(acc_mean)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(a, z)
    s = float(np.linalg.norm(v))
    c = float(a @ z)
    if s < 1e-12:
        # Flat, or upside down: a half turn about x keeps the field's sign conventions simple.
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx * ((1.0 - c) / (s * s))


@dataclass
class CalibrationResult:
    """Task-2 statistics and the settings derived from them.

    acc / gyr / mag: per-sensor statistics, None when that sensor had fewer than 2 samples.
    g: ||mean acc|| [m/s^2]. gyr_bias: mean gyr (3,) [rad/s]. m0: Earth field (3,) in ENU [uT],
    (0, horizontal, vertical). field_strength: ||mean mag|| = ||m0|| [uT]. tilt_deg: angle between
    the mean acc and the screen normal [deg] (0 when flat). interval_s: the rest interval used
    (start, end) in seconds, when known.
    """

    acc: SensorStatistics | None
    gyr: SensorStatistics | None
    mag: SensorStatistics | None
    g: float | None
    gyr_bias: np.ndarray | None
    m0: np.ndarray | None
    field_strength: float | None
    tilt_deg: float | None
    interval_s: tuple[float, float] | None = None

    def sensor(self, name: str) -> SensorStatistics | None:
        return getattr(self, name)

    def constant_axes(self) -> list[tuple[str, str, float]]:
        """(sensor, axis, value) of every axis whose samples all hold one value: no noise to
        measure (a zero variance, a covariance no filter accepts, NaN normality statistics)."""
        out = []
        for name in REPORT_ORDER:
            stats = self.sensor(name)
            if stats is None:
                continue
            for k, axis in enumerate(AXES):
                column = stats.samples[:, k]
                if column.min() == column.max():
                    out.append((name, axis, float(column[0])))
        return out

    def histograms(self, bins: int = 40, pdf_points: int = 200) -> dict[str, list[Histogram]]:
        """Per available sensor ("acc", "gyr", "mag"), one :class:`Histogram` per axis x, y, z."""
        out: dict[str, list[Histogram]] = {}
        for name in REPORT_ORDER:
            stats = self.sensor(name)
            if stats is None:
                continue
            per_axis = []
            for k, axis in enumerate(AXES):
                x = stats.samples[:, k]
                mean, std = float(stats.mean[k]), float(stats.std[k])
                if std > 0:
                    value_range = (min(x.min(), mean - 4 * std), max(x.max(), mean + 4 * std))
                else:
                    value_range = (mean - 0.5, mean + 0.5)  # constant signal: one visible bar
                counts, edges = np.histogram(x, bins=bins, range=value_range)
                widths = np.diff(edges)
                density = counts / (counts.sum() * widths)
                pdf_x = np.linspace(edges[0], edges[-1], pdf_points)
                if std > 0:
                    pdf = np.exp(-0.5 * ((pdf_x - mean) / std) ** 2) / (std * np.sqrt(2 * np.pi))
                else:
                    pdf = np.zeros_like(pdf_x)
                per_axis.append(
                    Histogram(name, axis, counts, edges, density, pdf_x, pdf, mean, std))
            out[name] = per_axis
        return out

    def format_table(self) -> str:
        """The task-2 table as plain text (means, standard deviations, covariances, g, m0, bias)."""
        lines = []
        if self.interval_s is not None:
            start, end = self.interval_s
            lines.append(f"Rest interval: {start:.3f} s to {end:.3f} s ({end - start:.2f} s)")
        header = f"{'sensor':<7}{'samples':>8}  {'mean x':>12}{'mean y':>12}{'mean z':>12}" \
                 f"  {'std x':>11}{'std y':>11}{'std z':>11}  unit"
        lines += [header, "-" * len(header)]
        for name in REPORT_ORDER:
            stats = self.sensor(name)
            if stats is None:
                lines.append(f"{name:<7}{0:>8}  (no data)")
                continue
            means = "".join(f"{v:>12.5g}" for v in stats.mean)
            stds = "".join(f"{v:>11.3g}" for v in stats.std)
            lines.append(f"{name:<7}{stats.count:>8}  {means}  {stds}  {UNITS[name]}")
        for name in REPORT_ORDER:
            stats = self.sensor(name)
            if stats is None:
                continue
            lines.append("")
            lines.append(f"Covariance {name} [({UNITS[name]})^2]:")
            for row in stats.cov:
                lines.append("  " + "".join(f"{v:>13.4e}" for v in row))
        lines.append("")
        if self.g is not None:
            lines.append(
                f"g         = {self.g:.4f} m/s^2   (tilt {self.tilt_deg:.2f} deg from flat)")
        if self.gyr_bias is not None:
            lines.append("gyro bias = (" + ", ".join(f"{v:.3e}" for v in self.gyr_bias) + ") rad/s")
        if self.m0 is not None:
            lines.append("m0        = (" + ", ".join(f"{v:.3f}" for v in self.m0)
                         + f") uT ENU   |m0| = {self.field_strength:.3f} uT")
        return "\n".join(lines)

    def to_settings(self, base: "EKFSettings | None" = None,
                    replace_noise: bool | None = None) -> "EKFSettings":
        """`base` (default: the "default" preset) with g, m0 and gyr_bias replaced by the
        measured ones, and the three noise covariances too when `replace_noise` (task 2).

        replace_noise None: only for the plain course model (no accelerometer low-pass). The
        default preset's covariances are tuning values that absorb model errors (the averaged
        accelerometer, the heading pseudo-measurement), far above the sensors' own noise, so
        measured noise would make it overconfident. Fields of missing sensors stay as in `base`."""
        from ekf.settings import PRESETS

        settings = PRESETS["default"] if base is None else base
        if replace_noise is None:
            replace_noise = settings.acc_lowpass_s <= 0.0
        changes: dict[str, Any] = {}
        if self.acc is not None:
            changes["g"] = float(self.g)
            if replace_noise:
                changes["acc_noise_cov"] = self.acc.cov.tolist()
        if self.gyr is not None:
            changes["gyr_bias"] = tuple(float(v) for v in self.gyr_bias)
            if replace_noise:
                changes["gyr_noise_cov"] = self.gyr.cov.tolist()
        if self.mag is not None:
            changes["m0"] = tuple(float(v) for v in self.m0)
            if replace_noise:
                changes["mag_noise_cov"] = self.mag.cov.tolist()
        return replace(settings, **changes)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no raw samples): per sensor count/mean/std/cov, plus g, gyr_bias,
        m0, field_strength, tilt_deg, interval_s."""
        def vec(v: np.ndarray | None) -> list[float] | None:
            return None if v is None else [float(x) for x in v]

        out: dict[str, Any] = {}
        for name in REPORT_ORDER:
            stats = self.sensor(name)
            out[name] = None if stats is None else {
                "count": stats.count, "mean": vec(stats.mean), "std": vec(stats.std),
                "cov": stats.cov.tolist(), "unit": UNITS[name]}
        out.update(g=self.g, gyr_bias=vec(self.gyr_bias), m0=vec(self.m0),
                   field_strength=self.field_strength, tilt_deg=self.tilt_deg,
                   interval_s=None if self.interval_s is None else list(self.interval_s))
        return out


def calibrate(acc: ArrayLike | None, gyr: ArrayLike | None, mag: ArrayLike | None,
              interval_s: tuple[float, float] | None = None) -> CalibrationResult:
    """Task-2 statistics from rest data.

    acc [m/s^2], gyr [rad/s], mag [uT]: arrays (N, 3) in the sensor frame, any lengths; rows with a
    NaN are dropped; a sensor may be None (e.g. a phone without gyroscope). Without accelerometer
    data m0 is computed as if the phone lay flat (the course's formula).
    """
    acc_stats = SensorStatistics.from_samples(acc) if acc is not None else None
    gyr_stats = SensorStatistics.from_samples(gyr) if gyr is not None else None
    mag_stats = SensorStatistics.from_samples(mag) if mag is not None else None

    g = tilt = None
    level = np.eye(3)
    if acc_stats is not None:
        g = float(np.linalg.norm(acc_stats.mean))
        tilt = float(np.degrees(np.arccos(np.clip(acc_stats.mean[2] / g, -1.0, 1.0))))
        level = _level_rotation(acc_stats.mean)
    m0 = strength = None
    if mag_stats is not None:
        m_level = level @ mag_stats.mean
        m0 = np.array([0.0, float(np.hypot(m_level[0], m_level[1])), float(m_level[2])])
        strength = float(np.linalg.norm(mag_stats.mean))
    return CalibrationResult(
        acc=acc_stats, gyr=gyr_stats, mag=mag_stats, g=g,
        gyr_bias=None if gyr_stats is None else gyr_stats.mean.copy(),
        m0=m0, field_strength=strength, tilt_deg=tilt,
        interval_s=None if interval_s is None else (float(interval_s[0]), float(interval_s[1])))


# ---- finding the rest ---------------------------------------------------------------------------

class RestSegment(NamedTuple):
    """A still interval [start_s, end_s] (seconds, the caller's time axis); unpacks as a pair."""

    start_s: float
    end_s: float

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    def mask(self, t_s: ArrayLike) -> np.ndarray:
        """Boolean (N,): which times lie in the interval."""
        t = np.asarray(t_s, dtype=float)
        return (t >= self.start_s) & (t <= self.end_s)


def _moving_mean_and_spread(t: np.ndarray, x: np.ndarray,
                            window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Centred moving mean (N, 3) and RMS deviation (N,) = sqrt(trace of the window covariance)
    over [t - w/2, t + w/2], for irregular sample times t (N,) sorted."""
    x = x - np.median(x, axis=0)  # centring keeps the running sums well conditioned
    zero = np.zeros((1, 3))
    s1 = np.vstack([zero, np.cumsum(x, axis=0)])
    s2 = np.vstack([zero, np.cumsum(x * x, axis=0)])
    lo = np.searchsorted(t, t - 0.5 * window_s, side="left")
    hi = np.searchsorted(t, t + 0.5 * window_s, side="right")
    n = (hi - lo)[:, None].astype(float)
    mean = (s1[hi] - s1[lo]) / n
    var = np.maximum((s2[hi] - s2[lo]) / n - mean * mean, 0.0)
    return mean, np.sqrt(var.sum(axis=1))


def rest_mask(t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None, window_s: float = 0.5,
              gyr_threshold: float = 0.1, gyr_spread_threshold: float = 0.02,
              acc_spread_threshold: float = 0.15) -> np.ndarray:
    """Boolean (N,): the phone is still around each time of `t_s`.

    t_s (N,) seconds, increasing; gyr [rad/s] and acc [m/s^2] (N, 3) with NaN rows where the sensor
    has no sample (either may be None). Still means, over a centred window of `window_s`: the mean
    rate is below `gyr_threshold` (room for an uncalibrated bias), the gyro and accelerometer
    samples scatter (RMS over the three axes) less than their spread thresholds. Each time takes
    the verdict of the nearest sample of each sensor.
    """
    t = np.asarray(t_s, dtype=float)
    still = np.ones(len(t), dtype=bool)
    used_any = False
    for values, name in ((gyr, "gyr"), (acc, "acc")):
        if values is None:
            continue
        v = np.asarray(values, dtype=float).reshape(-1, 3)
        valid = np.all(np.isfinite(v), axis=1)
        if valid.sum() < 2:
            continue
        used_any = True
        tv, xv = t[valid], v[valid]
        mean, spread = _moving_mean_and_spread(tv, xv, window_s)
        if name == "gyr":
            # The moving mean was taken of median-centred values: add the median back.
            rate = np.linalg.norm(mean + np.median(xv, axis=0), axis=1)
            ok = (rate < gyr_threshold) & (spread < gyr_spread_threshold)
        else:
            ok = spread < acc_spread_threshold
        nearest = np.clip(np.searchsorted(tv, t), 1, len(tv) - 1)
        left_closer = (t - tv[nearest - 1]) <= (tv[nearest] - t)
        nearest = np.where(left_closer, nearest - 1, nearest)
        still &= ok[nearest]
    if not used_any:
        raise ValueError("rest detection needs gyroscope or accelerometer samples")
    return still


def find_rest_segment(t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
                      min_duration_s: float = 1.0, window_s: float = 0.5,
                      max_gap_s: float = 0.5, **thresholds: float) -> RestSegment | None:
    """The longest still interval of a recording (see :func:`rest_mask` for "still"), or None
    when no still run lasts `min_duration_s`.

    t_s (N,) seconds; gyr, acc (N, 3) with NaN rows (the `ekf.filter_batch` layout). A gap without
    samples longer than `max_gap_s` ends a still run. Samples within half a window of any motion are
    excluded by construction. Raises ValueError when neither gyr nor acc has samples.
    """
    t = np.asarray(t_s, dtype=float)
    if len(t) < 2:
        return None
    still = rest_mask(t, gyr, acc, window_s=window_s, **thresholds)
    # Runs of consecutive still rows, broken by gaps in time.
    breaks = np.concatenate([[True], ~still[1:] | ~still[:-1] | (np.diff(t) > max_gap_s)])
    run_id = np.cumsum(breaks)
    best: tuple[float, float] | None = None
    best_len = -1.0
    for rid in np.unique(run_id[still]):
        idx = np.flatnonzero((run_id == rid) & still)
        length = t[idx[-1]] - t[idx[0]]
        if length > best_len:
            best_len, best = length, (float(t[idx[0]]), float(t[idx[-1]]))
    if best is None or best_len < min_duration_s:
        return None
    return RestSegment(*best)


def calibrate_rest(t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
                   mag: ArrayLike | None, min_duration_s: float = 1.0) -> CalibrationResult:
    """`find_rest_segment` then `calibrate` on the rows inside it (arrays in the batch layout:
    t_s (N,) seconds, each sensor (N, 3) with NaN rows). The interval is kept in `interval_s`.
    Raises ValueError when there is no still interval of `min_duration_s`."""
    segment = find_rest_segment(t_s, gyr, acc, min_duration_s=min_duration_s)
    if segment is None:
        raise ValueError(f"no still interval of at least {min_duration_s:g} s found")
    inside = segment.mask(t_s)

    def pick(a: ArrayLike | None) -> np.ndarray | None:
        return None if a is None else np.asarray(a, dtype=float).reshape(-1, 3)[inside]

    return calibrate(pick(acc), pick(gyr), pick(mag), interval_s=(segment.start_s, segment.end_s))
