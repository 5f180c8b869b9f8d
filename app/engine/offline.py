"""The offline path: a whole log through the same runner as the live engine.

`orientation-lab filter` and `evaluate` (and the examples) call these, so a file and its live
replay give the same estimates bit for bit, same-time and duplicated lines included.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

import ekf
from ekf.metrics import ErrorSummary, interpolate_quat, intervals_mask
from app.engine.runner import SENSORS, EstimatorRunner, Rows
from app.stream.logfile import LogData
from app.stream.protocol import Sample


def run_offline(samples: Iterable[Sample], estimator: str = "ekf",
                settings: ekf.EKFSettings | None = None,
                sensors: Iterable[str] = SENSORS) -> Rows:
    """Run one estimator over ordered samples (e.g. ``read_log(path).samples``): one row per
    distinct phone time, exactly as the live engine produces them."""
    runner = EstimatorRunner(estimator, settings, sensors)
    runner.feed_many(samples)
    runner.finish()
    return runner.take_rows()


def filter_log(log: LogData, estimator: str = "ekf", settings: ekf.EKFSettings | None = None,
               sensors: Iterable[str] = SENSORS, smooth: bool = False) -> Rows:
    """The estimates of a whole log: the rows at which a GYR, ACC or MAG sample arrived.

    smooth: the EKF forward, then the backward Rauch-Tung-Striebel pass (``ekf.smooth_batch``);
    only for the EKF (ValueError otherwise). The lights are the forward filter's."""
    rows = run_offline(log.samples, estimator, settings, sensors)
    rows = rows.select(rows.has_sample)
    if smooth:
        if estimator not in ("ekf", "course"):
            raise ValueError(f"--smooth needs the EKF (ekf or course), not {estimator!r}")
        a = log.to_arrays()
        has = ~(np.isnan(a.gyr).all(1) & np.isnan(a.acc).all(1) & np.isnan(a.mag).all(1))
        chosen = settings if settings is not None else (
            ekf.PRESETS["course"] if estimator == "course" else None)
        result = ekf.smooth_batch(a.t_s[has], a.gyr[has], a.acc[has], a.mag[has], chosen,
                                  sensors=tuple(sensors))
        if not np.array_equal(a.t_ms[has], rows.t_ms):
            raise ValueError("the smoother's rows do not match the runner's")   # not expected
        rows.quat = result.quat
    return rows


def sibling_truth(log_path: str | Path) -> Path | None:
    """``NAME.truth.txt`` beside ``NAME.txt`` (or a session folder's), when it exists."""
    path = Path(log_path)
    stem = path.name.split(".")[0] if path.is_file() else path.name
    candidate = path.with_name(stem + ".truth.txt")
    return candidate if candidate.is_file() else None


def orientation_series(log: LogData) -> tuple[np.ndarray, np.ndarray]:
    """The log's ORI samples: times [ms] (distinct, sorted; the last of equal times wins) and
    quaternions (N, 4). ValueError when there is none."""
    a = log.to_arrays()
    has = ~np.isnan(a.ori).any(axis=1)
    if not has.any():
        raise ValueError(f"{Path(log.path).name} has no ORI lines to compare with")
    return a.t_ms[has].astype(np.float64), a.ori[has]


def score_series(t_est_ms: np.ndarray, q_est: np.ndarray, t_ref_ms: np.ndarray,
                 q_ref: np.ndarray, intervals_ms: list | None, start_ms: float) -> ErrorSummary:
    """RMSE of an estimate series against a reference series, compared at the same instant:
    the estimate is slerp-interpolated to the reference's time stamps (``ekf.metrics``), over
    `intervals_ms` (None: everywhere) from `start_ms` on."""
    q = interpolate_quat(t_est_ms, q_est, t_ref_ms)
    mask = intervals_mask(t_ref_ms, intervals_ms) & (t_ref_ms >= start_ms)
    return ekf.summarize(q, q_ref, mask)


def evaluate_log(log: LogData, estimator: str = "ekf", settings: ekf.EKFSettings | None = None,
                 sensors: Iterable[str] = SENSORS, intervals_ms: list | None = None,
                 skip_s: float = 0.0, truth: LogData | None = None,
                 smooth: bool = False) -> ErrorSummary:
    """RMSE (degrees) of the total, heading and inclination error against the reference: the
    ORI of `truth` (an ORI-only log, e.g. ``NAME.truth.txt``) when given, else the log's own
    ORI. The estimate is interpolated to the reference's times (slerp), over `intervals_ms`
    (None: everywhere) after the first `skip_s` seconds of estimates.

    Raises ValueError when there is no reference ORI or no sensor samples."""
    t_ref, q_ref = orientation_series(truth if truth is not None else log)
    rows = filter_log(log, estimator, settings, sensors, smooth=smooth)
    if len(rows) == 0:
        raise ValueError("the log has no GYR/ACC/MAG samples")
    start = float(rows.t_ms[0]) + skip_s * 1000.0
    return score_series(rows.t_ms.astype(np.float64), rows.quat, t_ref, q_ref, intervals_ms,
                        start)


def evaluate_phone(log: LogData, truth: LogData, intervals_ms: list | None = None,
                   skip_s: float = 0.0) -> ErrorSummary:
    """The phone's own estimate (the log's ORI) against the truth, scored like
    :func:`evaluate_log` (the skip counts from the log's first GYR/ACC/MAG sample)."""
    t_phone, q_phone = orientation_series(log)
    t_ref, q_ref = orientation_series(truth)
    a = log.to_arrays()
    has = ~(np.isnan(a.gyr).all(1) & np.isnan(a.acc).all(1) & np.isnan(a.mag).all(1))
    first = float(a.t_ms[has][0]) if has.any() else float(t_phone[0])
    return score_series(t_phone, q_phone, t_ref, q_ref, intervals_ms, first + skip_s * 1000.0)
