"""Batch API over arrays, for replays, commands and benchmarks.

``filter_batch`` gives exactly what the streaming API gives when the same samples are fed
row by row in the order gyroscope, accelerometer, magnetometer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ekf.estimators import make_estimator
from ekf.reference import SENSORS
from ekf.settings import EKFSettings


@dataclass
class BatchResult:
    """Per row: t_s (N,), quat (N, 4) w-first sensor->ENU w>=0, and the flags (N,) after the row."""

    t_s: np.ndarray
    quat: np.ndarray
    acc_rejected: np.ndarray
    mag_rejected: np.ndarray
    at_rest: np.ndarray
    gyro_bias: np.ndarray | None = None


def _rows(a: ArrayLike | None, n: int) -> np.ndarray:
    if a is None:
        return np.full((n, 3), np.nan)
    a = np.asarray(a, dtype=float)
    if a.shape != (n, 3):
        raise ValueError(f"sensor array must have shape ({n}, 3), got {a.shape}")
    return a


def filter_batch(t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
                 mag: ArrayLike | None, settings: EKFSettings | None = None,
                 estimator: str = "ekf", sensors: tuple[str, ...] | list[str] = SENSORS,
                 fast: bool = True) -> BatchResult:
    """Run an estimator over rows of samples.

    t_s: (N,) seconds, non-decreasing. gyr [rad/s], acc [m/s^2], mag [uT]: (N, 3) each, a NaN
    row where that sensor has no sample at that time (or None: no such sensor).
    """
    t = np.asarray(t_s, dtype=float).reshape(-1)
    n = t.shape[0]
    g, a, m = _rows(gyr, n), _rows(acc, n), _rows(mag, n)
    est = make_estimator(estimator, settings, sensors, fast=fast)
    if hasattr(est, "run_batch"):
        return est.run_batch(t, g, a, m)
    out_q = np.empty((n, 4))
    acc_rej = np.zeros(n, bool)
    mag_rej = np.zeros(n, bool)
    rest = np.zeros(n, bool)
    has_g = ~np.isnan(g).any(axis=1)
    has_a = ~np.isnan(a).any(axis=1)
    has_m = ~np.isnan(m).any(axis=1)
    for k in range(n):
        st = est.step(t[k], g[k] if has_g[k] else None, a[k] if has_a[k] else None,
                      m[k] if has_m[k] else None)
        out_q[k] = est.quat
        acc_rej[k] = st.acc_rejected
        mag_rej[k] = st.mag_rejected
        rest[k] = st.at_rest
    return BatchResult(t, out_q, acc_rej, mag_rej, rest)
