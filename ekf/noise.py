"""The at-rest workspace's numbers (course task 2, beyond the table): per sensor and axis the
mean, the 3x3 covariance (the reports' Table 1), a normality check, the autocorrelation, and the
warnings a user needs before trusting them (the phone moved, and when; the field strength is not
the Earth's; a sensor is missing; too few samples).

Inputs are per sensor, each with its own time stamps (as the phone sends them and as the live
plot chunks carry them): t (N,) seconds and values (N, 3) in the sensor's unit (acc m/s², gyr
rad/s, mag µT). The statistics themselves are :func:`ekf.calibration.calibrate`'s.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ekf._optional import require
from ekf.calibration import AXES, REPORT_ORDER, UNITS, CalibrationResult, calibrate, rest_mask

FIELD_RANGE_UT = (25.0, 65.0)
"""The Earth's field strength anywhere on the surface is within about this range [µT]."""

MIN_SAMPLES = 100
"""Fewer samples of a sensor than this give covariances too rough to tune with."""

NAMES = {"acc": "accelerometer", "gyr": "gyroscope", "mag": "magnetometer"}


NORMALITY_LEVEL = 0.01
"""The significance level of both normality tests."""

VERDICT_RULE = ("Gaussian: neither test rejects normality at the 1 % level (D'Agostino–Pearson "
                "K² p ≥ 0.01 and Anderson–Darling A² below its 1 % critical value); not "
                "Gaussian: both reject; mixed: one rejects and the other does not")
"""How the verdict is reached, in words (the table's caption and the report's footnote)."""


@dataclass
class AxisReport:
    """One sensor axis at rest.

    normality_p: D'Agostino-Pearson K² test p-value (small: not Gaussian); anderson: the
    Anderson-Darling statistic A² and anderson_critical its critical value at NORMALITY_LEVEL
    (A² above it: not Gaussian); acf: autocorrelation at lags 0..len-1 samples (acf[0] = 1);
    lag_s: the sampling period [s] the lags are in; correlation_time_s: the first lag where the
    autocorrelation falls below 1/e (NaN: never within the lags computed)."""

    sensor: str
    axis: str
    mean: float
    std: float
    count: int
    normality_p: float
    anderson: float
    anderson_critical: float
    acf: np.ndarray = field(repr=False)
    lag_s: float
    correlation_time_s: float

    @property
    def verdict(self) -> str:
        """"Gaussian", "not Gaussian" or "mixed" (the two tests disagree), by VERDICT_RULE;
        "untested" with too few samples (or a constant axis)."""
        if not (np.isfinite(self.normality_p) and np.isfinite(self.anderson)
                and np.isfinite(self.anderson_critical)):
            return "untested"
        k2_rejects = self.normality_p < NORMALITY_LEVEL
        ad_rejects = self.anderson > self.anderson_critical
        if k2_rejects != ad_rejects:
            return "mixed"
        return "not Gaussian" if k2_rejects else "Gaussian"

    @property
    def gaussian(self) -> bool:
        """Neither normality test rejects at the 1 % level (verdict "Gaussian")."""
        return self.verdict == "Gaussian"

    @property
    def correlated(self) -> bool:
        """Consecutive samples are clearly correlated (lag-1 autocorrelation above 0.2 and
        beyond three standard errors of white noise)."""
        if len(self.acf) < 2:
            return False
        return bool(self.acf[1] > max(0.2, 3.0 / np.sqrt(max(self.count, 1))))


@dataclass
class RestWarning:
    """kind: "moved", "field_strength", "missing" or "too_few"; message: one line for the user;
    intervals_s: for "moved", the (start, end) times [s, the caller's time axis] of motion."""

    kind: str
    message: str
    intervals_s: list[tuple[float, float]] = field(default_factory=list)


@dataclass
class RestAnalysis:
    """result: the task-2 statistics (means, covariances, g, m0, bias); axes: per available
    sensor one :class:`AxisReport` per axis; warnings; moving: the rows of the common time axis
    `t_s` judged not still; duration_s: the span of the data; series: per sensor the (times,
    values) analysed (the time series to draw)."""

    result: CalibrationResult
    axes: dict[str, list[AxisReport]]
    warnings: list[RestWarning]
    t_s: np.ndarray = field(repr=False)
    moving: np.ndarray = field(repr=False)
    duration_s: float = 0.0
    series: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False)

    def warning_kinds(self) -> set[str]:
        return {w.kind for w in self.warnings}

    def format_report(self) -> str:
        """Per axis: normality and autocorrelation; then the warnings."""
        lines = [f"{'sensor':<7}{'axis':<5}{'K² p':>9}{'A-D A²':>9}{'1 % crit.':>10}"
                 f"{'acf(1)':>8}{'corr. time':>12}  verdict"]
        for name, reports in self.axes.items():
            for r in reports:
                lag1 = r.acf[1] if len(r.acf) > 1 else np.nan
                verdict = r.verdict + (", correlated in time" if r.correlated else "")
                longest = (len(r.acf) - 1) * r.lag_s
                time_text = (f"{r.correlation_time_s:>10.3f} s" if np.isfinite(
                    r.correlation_time_s) else f"{'> ' + format(longest, '.2f'):>10} s")
                lines.append(f"{name:<7}{r.axis:<5}{r.normality_p:>9.3g}{r.anderson:>9.2f}"
                             f"{r.anderson_critical:>10.2f}{lag1:>8.2f}{time_text}  {verdict}")
        lines.append(f"verdict: {VERDICT_RULE}")
        for w in self.warnings:
            lines.append(f"warning: {w.message}")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        axes = {name: [{"axis": r.axis, "normality_p": r.normality_p, "anderson": r.anderson,
                        "anderson_critical_1pct": r.anderson_critical,
                        "acf_lag1": float(r.acf[1]) if len(r.acf) > 1 else None,
                        "correlation_time_s": r.correlation_time_s, "gaussian": r.gaussian,
                        "normality_verdict": r.verdict, "correlated": r.correlated}
                       for r in reports]
                for name, reports in self.axes.items()}
        return {"statistics": self.result.to_dict(), "axes": axes,
                "warnings": [{"kind": w.kind, "message": w.message,
                              "intervals_s": [list(i) for i in w.intervals_s]}
                             for w in self.warnings],
                "duration_s": self.duration_s}


def autocorrelation(x: ArrayLike, max_lag: int) -> np.ndarray:
    """Normalised autocorrelation of a series (demeaned) at lags 0..max_lag (biased estimate,
    FFT); all NaN for a constant series."""
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    n = len(x)
    max_lag = int(min(max_lag, n - 1))
    if n < 2 or not np.any(x):
        return np.full(max(max_lag + 1, 1), np.nan)
    size = 1 << int(np.ceil(np.log2(2 * n)))
    spectrum = np.fft.rfft(x, size)
    acov = np.fft.irfft(spectrum * np.conj(spectrum), size)[:max_lag + 1]
    return acov / acov[0]


def _anderson(stats: Any, x: np.ndarray) -> tuple[float, float]:
    """Anderson-Darling statistic and its critical value at NORMALITY_LEVEL (scipy before and
    after 1.17)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)   # 1.17 asks for a p-value method
        ad = stats.anderson(x, dist="norm")
    levels = [float(level) for level in ad.significance_level]
    return float(ad.statistic), float(ad.critical_values[levels.index(100 * NORMALITY_LEVEL)])


def _axis_report(sensor: str, k: int, x: np.ndarray, lag_s: float, max_lag: int) -> AxisReport:
    stats = require("scipy.stats", "the normality check")
    n = len(x)
    std = float(x.std(ddof=1)) if n > 1 else float("nan")
    p = a2 = crit = float("nan")
    if n >= 20 and std > 0:
        p = float(stats.normaltest(x).pvalue)
        a2, crit = _anderson(stats, x)
    acf = autocorrelation(x, max_lag)
    below = np.flatnonzero(acf < np.exp(-1.0))
    corr_time = float(below[0] * lag_s) if len(below) else float("nan")
    return AxisReport(sensor, AXES[k], float(x.mean()) if n else float("nan"), std, n, p, a2,
                      crit, acf, lag_s, corr_time)


def merged_axis(series: dict[str, tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, dict]:
    """One time axis (the union of the sensors' times) with NaN rows where a sensor has no
    sample: the layout rest_mask reads."""
    times = [t for t, _ in series.values() if len(t)]
    t_all = np.unique(np.concatenate(times)) if times else np.empty(0)
    columns = {}
    for name, (t, v) in series.items():
        column = np.full((len(t_all), 3), np.nan)
        if len(t):
            column[np.searchsorted(t_all, t)] = v
        columns[name] = column
    return t_all, columns


def runs_of(t: np.ndarray, flag: np.ndarray) -> list[tuple[float, float]]:
    """(start, end) times of the runs where `flag` is true."""
    if not flag.any():
        return []
    edges = np.diff(np.concatenate([[0], flag.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(float(t[s]), float(t[e])) for s, e in zip(starts, ends)]


def _clean(t: ArrayLike | None, values: ArrayLike | None) -> tuple[np.ndarray, np.ndarray]:
    if t is None or values is None:
        return np.empty(0), np.empty((0, 3))
    t = np.asarray(t, dtype=float).reshape(-1)
    v = np.asarray(values, dtype=float).reshape(-1, 3)
    keep = np.isfinite(t) & np.all(np.isfinite(v), axis=1)
    t, v = t[keep], v[keep]
    order = np.argsort(t, kind="stable")
    return t[order], v[order]


def _motion_warning(t_all: np.ndarray, columns: dict, origin: float,
                    thresholds: dict[str, float]) -> tuple[np.ndarray, RestWarning | None]:
    if len(t_all) < 2 or (np.isnan(columns["gyr"]).all() and np.isnan(columns["acc"]).all()):
        return np.zeros(len(t_all), bool), None
    moving = ~rest_mask(t_all, columns["gyr"], columns["acc"], **thresholds)
    runs = runs_of(t_all, moving)
    if not runs:
        return moving, None
    where = ", ".join(_stretch_text(a - origin, b - origin) for a, b in runs[:4])
    more = f" and {len(runs) - 4} more" if len(runs) > 4 else ""
    share = 100.0 * moving.mean()
    return moving, RestWarning(
        "moved", f"the phone moved at {where}{more} from the start ({share:.0f} % of the "
                 "samples): lay it still, or analyse a still stretch only", runs)


def _stretch_text(start: float, end: float) -> str:
    """"3.2–4.0 s", or "0.6 s" for a moment (a stretch that rounds to no length)."""
    first, last = f"{start:.1f}", f"{end:.1f}"
    return f"{first} s" if first == last else f"{first}–{last} s"


def analyse_rest(t_acc: ArrayLike | None = None, acc: ArrayLike | None = None,
                 t_gyr: ArrayLike | None = None, gyr: ArrayLike | None = None,
                 t_mag: ArrayLike | None = None, mag: ArrayLike | None = None,
                 min_samples: int = MIN_SAMPLES, max_lag: int = 50,
                 field_range_ut: tuple[float, float] = FIELD_RANGE_UT,
                 **thresholds: float) -> RestAnalysis:
    """Analyse rest data (see the module's docstring for the inputs; a sensor may be None).

    The statistics use every sample given (a selection is the caller's); the motion check uses
    :func:`ekf.calibration.rest_mask` with `thresholds` (its keyword arguments). The lag unit of
    the autocorrelation is each sensor's median sampling period."""
    series = {"acc": _clean(t_acc, acc), "gyr": _clean(t_gyr, gyr), "mag": _clean(t_mag, mag)}
    result = calibrate(*(series[s][1] if len(series[s][1]) else None
                         for s in REPORT_ORDER))
    t_all, columns = merged_axis(series)
    origin = float(t_all[0]) if len(t_all) else 0.0
    warnings: list[RestWarning] = []
    axes: dict[str, list[AxisReport]] = {}
    for name in REPORT_ORDER:
        t, v = series[name]
        if len(t) < 2:
            warnings.append(RestWarning("missing", f"no {NAMES[name]} samples"))
            continue
        if len(t) < min_samples:
            warnings.append(RestWarning(
                "too_few", f"only {len(t)} {NAMES[name]} samples (at least {min_samples} "
                           "for covariances worth tuning with): record longer"))
        lag_s = float(np.median(np.diff(t))) if len(t) > 1 else float("nan")
        axes[name] = [_axis_report(name, k, v[:, k], lag_s, max_lag) for k in range(3)]
    moving, moved = _motion_warning(t_all, columns, origin, thresholds)
    if moved is not None:
        warnings.insert(0, moved)
    if result.field_strength is not None:
        low, high = field_range_ut
        if not low <= result.field_strength <= high:
            warnings.append(RestWarning(
                "field_strength",
                f"field strength {result.field_strength:.1f} {UNITS['mag']} is outside "
                f"{low:g}–{high:g} {UNITS['mag']} (the Earth's): iron or a magnet nearby, or "
                "an uncalibrated magnetometer (see the magnetometer calibration)"))
    duration = float(t_all[-1] - t_all[0]) if len(t_all) > 1 else 0.0
    return RestAnalysis(result, axes, warnings, t_all, moving, duration, series)
