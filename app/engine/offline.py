"""The offline path: a whole log through the same runner as the live engine.

`orientation-lab filter` and `evaluate` (and the examples) call these, so a file and its live
replay give the same estimates bit for bit, same-time and duplicated lines included.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import ekf
from ekf import magcal
from ekf.metrics import ErrorSummary, interpolate_quat, intervals_mask, rmse
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
               settings: ekf.EKFSettings | None = None, sensors: Iterable[str] = SENSORS,
               smooth: bool = False) -> Rows:
    """The estimates of a whole log: the rows at which a GYR, ACC or MAG sample arrived.

    smooth: the EKF forward, then the backward Rauch-Tung-Striebel pass (``ekf.smooth_batch``);
    only for the EKF (ValueError otherwise). The lights are the forward filter's."""
    rows = run_offline(log.samples, estimator, settings, sensors, log.session_starts)
    rows = rows.select(rows.has_sample)
    if smooth:
        rows.quat = _smoothed(log, estimator, settings, sensors, rows.t_ms)
    return rows


def _smoothed(log: LogData, estimator: str | ekf.Estimator, settings: ekf.EKFSettings | None,
              sensors: Iterable[str], t_ms: np.ndarray) -> np.ndarray:
    """The smoother's quaternions at the log's GYR/ACC/MAG times (`t_ms`, the runner's)."""
    if estimator not in ("ekf", "course"):
        raise ValueError(f"--smooth needs the EKF (ekf or course), not {estimator!r}")
    if len(log.session_starts):
        raise ValueError("--smooth runs over one session: this log's clock restarts")
    a = log.to_arrays()
    has = ~(np.isnan(a.gyr).all(1) & np.isnan(a.acc).all(1) & np.isnan(a.mag).all(1))
    if not np.array_equal(a.t_ms[has], t_ms):
        raise ValueError("the smoother's rows do not match the runner's")   # not expected
    return smooth_rows(a.t_ms[has], a.gyr[has], a.acc[has], a.mag[has], estimator, settings,
                       sensors)


def smooth_rows(t_ms: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray,
                estimator: str, settings: ekf.EKFSettings | None,
                sensors: Iterable[str]) -> np.ndarray:
    """The smoother over rows of readings (NaN: no such sample), the magnetometer corrected as
    the runner corrects it for every estimator (settings mag_hard_iron, mag_soft_iron)."""
    chosen = settings if settings is not None else ekf.PRESETS[
        "course" if estimator == "course" else "default"]
    correction = magcal.settings_correction(chosen)
    if correction is not None:
        mag = magcal.correct(mag, *correction)
    result = ekf.smooth_batch(np.asarray(t_ms, np.float64) / 1000.0, gyr, acc, mag, chosen,
                              sensors=tuple(sensors))
    return result.quat


def session_row_starts(t_ms: Iterable[int] | np.ndarray,
                       session_starts: Iterable[int]) -> list[int]:
    """Where each session after the first starts in a run's rows, from the ordered samples'
    times and the sample indices where sessions start (the runner commits one row per run of
    equal times, and a new session always starts a row)."""
    starts = [int(k) for k in session_starts]
    t = np.asarray(list(t_ms) if not isinstance(t_ms, np.ndarray) else t_ms, dtype=np.int64)
    if not starts or not len(t):
        return []
    new_row = np.ones(len(t), bool)
    new_row[1:] = t[1:] != t[:-1]
    new_row[starts] = True
    row_of = np.cumsum(new_row) - 1
    return [int(row_of[k]) for k in starts]


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


def evaluate_log(log: LogData, estimator: str | ekf.Estimator = "ekf",
                 settings: ekf.EKFSettings | None = None, sensors: Iterable[str] = SENSORS,
                 intervals_ms: list | None = None, skip_s: float = 0.0,
                 truth: LogData | None = None, smooth: bool = False) -> ErrorSummary:
    """RMSE (degrees) of the total, heading and inclination error against the reference: the
    ORI of `truth` (an ORI-only log, e.g. ``NAME.truth.txt``) when given, else the log's own
    ORI. The estimate is interpolated to the reference's times (slerp), session by session
    where the log's clock restarts, over `intervals_ms` (None: everywhere) after the first
    `skip_s` seconds of each session's estimates (the figures re-filter and tune report).

    Raises ValueError when there is no reference ORI or no sensor samples."""
    reference = orientation_series(truth) if truth is not None else None
    ori_times = np.unique(np.fromiter((s.t_ms for s in log.samples if s.tag == "ORI"),
                                      dtype=np.int64))
    if reference is None and not len(ori_times):
        raise ValueError(f"{Path(log.path).name} has no ORI lines to compare with")
    rows = run_offline(log.samples, estimator, settings, sensors, log.session_starts)
    if smooth and rows.has_sample.any():
        rows.quat[rows.has_sample] = _smoothed(log, estimator, settings, sensors,
                                               rows.t_ms[rows.has_sample])
    starts = session_row_starts(np.fromiter((s.t_ms for s in log.samples), dtype=np.int64,
                                            count=len(log.samples)), log.session_starts)
    return reference_errors(rows, ori_times, intervals_ms, skip_s, starts, reference).summary


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


@dataclass
class ReferenceErrors:
    """The estimate against ORI at the ORI times (the estimate slerped to them, as
    :func:`evaluate_log` compares): t_ms (M,), the total, heading and inclination error angles
    (M,) degrees (NaN before the first estimate), `scored` (M,) bool: inside the intervals and
    after the skip, and the RMSE summary over the scored rows (the `evaluate` figures)."""

    t_ms: np.ndarray
    total_deg: np.ndarray
    heading_deg: np.ndarray
    inclination_deg: np.ndarray
    scored: np.ndarray
    summary: ErrorSummary


def reference_errors(rows: Rows, ori_times: np.ndarray, intervals_ms: list | None = None,
                     skip_s: float = 0.0, row_starts: Iterable[int] = (),
                     reference: tuple[np.ndarray, np.ndarray] | None = None) -> ReferenceErrors:
    """Errors of `rows` (a whole run, :func:`run_offline`) at the reference's times, the
    estimate interpolated to each (slerp between the estimates around it), session by session
    (`row_starts`: where later sessions start in the rows, :func:`session_row_starts`), scored
    over `intervals_ms` (None: everywhere) after the first `skip_s` seconds of each session's
    estimates. The reference: `reference` = (t_ms, q) of a truth file, else the rows' own ORI
    at the distinct `ori_times`.

    Raises ValueError when there is no reference or no sensor sample."""
    if reference is None and len(ori_times) == 0:
        raise ValueError("the log has no ORI lines to compare with")
    if not rows.has_sample.any():
        raise ValueError("the log has no GYR/ACC/MAG samples")
    bounds = [0, *[int(k) for k in row_starts], len(rows)]
    index = np.arange(len(rows))
    parts = []
    for first, last in zip(bounds[:-1], bounds[1:]):
        session = rows.select((index >= first) & (index < last))
        estimates = session.select(session.has_sample)
        if not len(estimates):
            continue
        if reference is None:
            at_ori = np.isin(session.t_ms, ori_times)
            t_ref, q_ref = session.t_ms[at_ori], session.phone_quat[at_ori]
        else:
            t_ref, q_ref = reference
        t_ref = np.asarray(t_ref, np.float64)
        q_est = interpolate_quat(estimates.t_ms.astype(np.float64), estimates.quat, t_ref)
        mask = intervals_mask(t_ref, intervals_ms) & (
            t_ref >= estimates.t_ms[0] + skip_s * 1000.0)
        parts.append((t_ref, q_est, np.asarray(q_ref, np.float64), mask))
    t_ref, q_est, q_ref, mask = (np.concatenate(column) for column in zip(*parts))
    ok = mask & np.isfinite(q_est).all(axis=1) & np.isfinite(q_ref).all(axis=1)
    total, heading, inclination = ekf.error_angles_deg(q_est, q_ref)
    # the figures of ekf.summarize(q_est, q_ref, mask), from the angles computed once
    summary = ErrorSummary(rmse(total[ok]), rmse(heading[ok]), rmse(inclination[ok]),
                           int(ok.sum()))
    return ReferenceErrors(t_ref, total, heading, inclination, mask, summary)
