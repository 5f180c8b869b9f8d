"""The offline path: a whole log through the same runner as the live engine.

`orientation-lab filter` and `evaluate` (and the examples) call these, so a file and its live
replay give the same estimates bit for bit, same-time and duplicated lines included.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

import ekf
from ekf.metrics import ErrorSummary, intervals_mask, rmse
from app.engine.runner import SENSORS, EstimatorRunner, Rows
from app.stream.logfile import LogData
from app.stream.protocol import Sample


def run_offline(samples: Iterable[Sample], estimator: str | ekf.Estimator = "ekf",
                settings: ekf.EKFSettings | None = None,
                sensors: Iterable[str] = SENSORS,
                session_starts: Iterable[int] = ()) -> Rows:
    """Run one estimator (a name, a user's FILE.py, or an estimator object, which is then
    advanced) over ordered samples (e.g. ``read_log(path).samples``, with its
    ``session_starts``: the estimators start afresh there): one row per distinct phone time,
    exactly as the live engine produces them."""
    runner = EstimatorRunner(estimator, settings, sensors)
    samples = list(samples)
    previous = 0
    for start in list(session_starts) + [len(samples)]:
        if start > previous or start == len(samples):
            runner.feed_many(samples[previous:start])
        if start < len(samples):
            runner.new_session()
        previous = start
    runner.finish()
    return runner.take_rows()


def filter_log(log: LogData, estimator: str | ekf.Estimator = "ekf",
               settings: ekf.EKFSettings | None = None, sensors: Iterable[str] = SENSORS) -> Rows:
    """The estimates of a whole log: the rows at which a GYR, ACC or MAG sample arrived."""
    rows = run_offline(log.samples, estimator, settings, sensors, log.session_starts)
    return rows.select(rows.has_sample)


def evaluate_log(log: LogData, estimator: str | ekf.Estimator = "ekf",
                 settings: ekf.EKFSettings | None = None, sensors: Iterable[str] = SENSORS,
                 intervals_ms: list | None = None, skip_s: float = 0.0) -> ErrorSummary:
    """RMSE (degrees) of the total, heading and inclination error against the log's ORI, at the
    ORI times (the estimate there is the latest at or before it, as a viewer sees it), over
    `intervals_ms` (None: everywhere) after the first `skip_s` seconds of estimates.

    Raises ValueError when the log has no ORI or no sensor samples."""
    rows = run_offline(log.samples, estimator, settings, sensors, log.session_starts)
    ori_times = np.unique(np.fromiter((s.t_ms for s in log.samples if s.tag == "ORI"),
                                      dtype=np.int64))
    return reference_errors(rows, ori_times, intervals_ms, skip_s).summary


@dataclass
class ReferenceErrors:
    """The estimate against ORI at the ORI times: t_ms (M,), the total, heading and inclination
    error angles (M,) degrees, `scored` (M,) bool: inside the intervals and after the skip, and
    the RMSE summary over the scored rows."""

    t_ms: np.ndarray
    total_deg: np.ndarray
    heading_deg: np.ndarray
    inclination_deg: np.ndarray
    scored: np.ndarray
    summary: ErrorSummary


def reference_errors(rows: Rows, ori_times: np.ndarray, intervals_ms: list | None = None,
                     skip_s: float = 0.0) -> ReferenceErrors:
    """Errors of `rows` (a whole run, :func:`run_offline`) at the distinct ORI times (the
    estimate there is the latest at or before it, as a viewer sees it), scored over
    `intervals_ms` (None: everywhere) after the first `skip_s` seconds of estimates.

    Raises ValueError when there is no ORI or no sensor sample."""
    if len(ori_times) == 0:
        raise ValueError("the log has no ORI lines to compare with")
    if not rows.has_sample.any():
        raise ValueError("the log has no GYR/ACC/MAG samples")
    first_estimate = rows.t_ms[np.argmax(rows.has_sample)]
    started = np.cumsum(rows.has_sample) > 0          # an estimate exists at or before the row
    at_ori = np.isin(rows.t_ms, ori_times) & started
    q_est = rows.quat[at_ori]
    q_ref = rows.phone_quat[at_ori]
    t_ref = rows.t_ms[at_ori]
    mask = intervals_mask(t_ref, intervals_ms) & (t_ref >= first_estimate + skip_s * 1000.0)
    ok = mask & np.isfinite(q_est).all(axis=1) & np.isfinite(q_ref).all(axis=1)
    total, heading, inclination = ekf.error_angles_deg(q_est, q_ref)
    # the figures of ekf.summarize(q_est, q_ref, mask), from the angles computed once
    summary = ErrorSummary(rmse(total[ok]), rmse(heading[ok]), rmse(inclination[ok]),
                           int(ok.sum()))
    return ReferenceErrors(t_ref, total, heading, inclination, mask, summary)
