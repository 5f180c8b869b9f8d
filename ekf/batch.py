"""Batch API over arrays, for replays, commands and benchmarks.

``filter_batch`` gives exactly what the streaming API gives when the same samples are fed
row by row in the order gyroscope, accelerometer, magnetometer: it is the estimator's own
``run_batch`` (one compiled loop for the compiled EKF, a loop over ``step`` for the others).
"""

from __future__ import annotations

from numpy.typing import ArrayLike

from ekf.estimator import SENSORS, BatchResult, batch_rows
from ekf.estimators import make_estimator
from ekf.settings import EKFSettings

__all__ = ["BatchResult", "filter_batch"]


def filter_batch(t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
                 mag: ArrayLike | None, settings: EKFSettings | str | None = None,
                 estimator: str = "ekf", sensors: tuple[str, ...] | list[str] = SENSORS,
                 fast: bool = True) -> BatchResult:
    """Run a fresh estimator (see ``ekf.make_estimator``) over rows of samples.

    t_s: (N,) seconds, non-decreasing. gyr [rad/s], acc [m/s^2], mag [uT]: (N, 3) each, a NaN
    row where that sensor has no sample at that time (or None: no such sensor).
    """
    t, g, a, m = batch_rows(t_s, gyr, acc, mag)
    return make_estimator(estimator, settings, sensors, fast=fast).run_batch(t, g, a, m)
