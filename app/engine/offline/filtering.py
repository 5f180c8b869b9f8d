"""The offline path: a whole log through the same runner as the live engine, and our estimates
as CSV.

`orientation-lab filter` and `evaluate` (and the examples) call these, so a file and its live
replay give the same estimates bit for bit, same-time and duplicated lines included.

A log is a :class:`~app.stream.logfile.LogFile` (read chunk by chunk, one chunk in memory at a
time: each pass reads the file again) or a :class:`~app.stream.logfile.LogData` (in memory).
:func:`run_log` runs the runner over it chunk by chunk and hands on the rows as they are
committed, so memory does not grow with the log: :func:`filter_rows` for the estimates,
:func:`evaluate_log` keeps only the error angles of the ORI samples it scores. What a command
needs to know before it starts (which sensors a log holds, its ORI series) comes from a first
pass, :func:`scan_log`. The smoother needs a whole session's readings: :func:`smoothed_quats`
holds them as arrays (80 bytes a row) while it runs.

Our estimates as CSV (:class:`EstimatesWriter`, :func:`write_rows`): what `orientation-lab
filter` prints and what a recording keeps in ``estimates.csv`` (the same rows, so `filter` on a
recorded ``raw.txt`` reproduces the file). Columns: t_ms (the phone's aligned clock), qw qx qy qz
(sensor -> ENU, w >= 0, 9 decimals), acc_rejected, mag_rejected, at_rest (0/1). One row per
distinct time that has a GYR, ACC or MAG sample.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, TextIO

import numpy as np

import ekf
from ekf import magcal
from ekf.metrics import ErrorSummary, interpolate_quat, intervals_mask, rmse
from app.engine.processing.configuration import Setup
from app.engine.processing.pipeline import Pipeline
from app.engine.processing.runner import SENSORS, TAG_NAMES, EstimatorRunner, Rows
from app.stream.logfile import LogData, LogStats
from app.stream.protocol import REFERENCE_CODE, SENSOR_CODES



class OrderedLog(Protocol):
    """A log's ordered samples, chunk by chunk (LogFile or LogData): each call of chunks() is
    one pass from the start."""

    path: str

    def chunks(self) -> Iterator[LogData]: ...


def run_log(log: OrderedLog, estimator: str | ekf.Estimator = "ekf",
            settings: ekf.EKFSettings | None = None, sensors: Iterable[str] = SENSORS,
            setup: Setup | None = None) -> Iterator[tuple[Rows, bool]]:
    """Run one estimator (a name, a user's FILE.py, or an estimator object, which is then
    advanced) over a log's ordered samples, chunk by chunk: (the rows committed, whether a new
    session starts after them) as they come, one row per distinct phone time, exactly as the
    live engine produces them (the runner's result does not depend on the chunking); the
    estimators start afresh where the log's clock restarts.

    setup: run this configuration over time instead (Tune's re-run of what a replay shows): its
    configuration at the start (a recording's start state too), its changes applied at their
    sample positions by the engine's :class:`~app.engine.processing.pipeline.Pipeline`; the
    comparisons are not run (they change no row)."""
    if setup is None:
        runner = EstimatorRunner(estimator, settings, sensors)
        feed = runner.feed_arrays
    else:
        setup = dataclasses.replace(setup, comparisons=False, timeline=tuple(
            c for c in setup.timeline if c.kind != "comparisons"))
        runner = EstimatorRunner(collect_plot=False)
        pipeline = Pipeline(runner)
        pipeline.begin(pipeline.initial_checkpoint(setup), setup.timeline)
        feed = pipeline.feed_samples
    for chunk in log.chunks():
        previous = 0
        for start in chunk.session_starts:
            if start > previous:
                feed(chunk.t_ms[previous:start], chunk.tag[previous:start],
                     chunk.values[previous:start])
            runner.new_session()
            yield _taken(runner), True
            previous = start
        if previous < len(chunk):
            feed(chunk.t_ms[previous:], chunk.tag[previous:], chunk.values[previous:])
        rows = _taken(runner)
        if len(rows):
            yield rows, False
    runner.finish()
    yield _taken(runner), False


def _taken(runner: EstimatorRunner) -> Rows:
    """The rows committed so far; the runner's own comparisons with ORI (the window's error
    plots) are dropped as they come, so nothing piles up over a long log."""
    runner.take_errors()
    runner.take_user_errors()
    return runner.take_rows()


def run_offline(log: OrderedLog, estimator: str | ekf.Estimator = "ekf",
                settings: ekf.EKFSettings | None = None, sensors: Iterable[str] = SENSORS,
                setup: Setup | None = None) -> Rows:
    """:func:`run_log`'s rows of a whole log in one Rows (every distinct time)."""
    return Rows.concatenate([rows for rows, _ in run_log(log, estimator, settings, sensors,
                                                         setup)])


# ---- one pass to know a log --------------------------------------------------------------------

@dataclass
class LogScan:
    """What one pass over a log found: its stats (None for a LogData without them); per sensor
    (gyr, acc, mag) whether it has a finite sample; the first GYR/ACC/MAG time [ms]; how many
    times a new session starts; with ``ori``: the ORI series, distinct times (sorted, ms) and
    quaternions (M, 4) (the last sample of a time)."""

    path: str
    stats: LogStats | None
    present: dict[str, bool]
    first_sensor_ms: int | None
    session_starts: int
    ori_t_ms: np.ndarray | None = None
    ori_quat: np.ndarray | None = None


def scan_log(log: OrderedLog, ori: bool = False) -> LogScan:
    """One pass over the log (no estimator). Raises LogError for a file that cannot be read."""
    present = dict.fromkeys(TAG_NAMES[:3], False)
    first: int | None = None
    sessions = 0
    ori_t: list[np.ndarray] = []
    ori_q: list[np.ndarray] = []
    for chunk in log.chunks():
        sessions += len(chunk.session_starts)
        sensor = chunk.tag != REFERENCE_CODE
        if sensor.any():
            earliest = int(chunk.t_ms[sensor].min())
            first = earliest if first is None else min(first, earliest)
        for code in SENSOR_CODES:
            if not present[TAG_NAMES[code]]:
                present[TAG_NAMES[code]] = bool(
                    np.isfinite(chunk.values[chunk.tag == code, 0]).any())
        if ori:
            chosen = chunk.tag == REFERENCE_CODE
            ori_t.append(chunk.t_ms[chosen])
            ori_q.append(chunk.values[chosen])
    scan = LogScan(log.path, getattr(log, "stats", None), present, first, sessions)
    if ori:
        t = np.concatenate(ori_t) if ori_t else np.empty(0, np.int64)
        q = np.concatenate(ori_q) if ori_q else np.empty((0, 4))
        order = np.argsort(t, kind="stable")
        t, q = t[order], q[order]
        last = np.ones(len(t), bool)
        last[:-1] = t[1:] != t[:-1]           # the last sample of a time wins
        scan.ori_t_ms, scan.ori_quat = t[last], q[last]
    return scan


def orientation_series(scan: LogScan) -> tuple[np.ndarray, np.ndarray]:
    """A scanned log's ORI samples (``scan_log(log, ori=True)``): times [ms] (distinct, sorted;
    the last of equal times wins) as float and quaternions (N, 4). ValueError when there is
    none."""
    if scan.ori_t_ms is None or not len(scan.ori_t_ms):
        raise ValueError(f"{Path(scan.path).name} has no ORI lines to compare with")
    return scan.ori_t_ms.astype(np.float64), scan.ori_quat


# ---- filter --------------------------------------------------------------------------------------

def filter_rows(log: OrderedLog, estimator: str | ekf.Estimator = "ekf",
                settings: ekf.EKFSettings | None = None, sensors: Iterable[str] = SENSORS,
                smooth: bool = False) -> Iterator[Rows]:
    """The estimates of a whole log, piece by piece as the runner commits them: the rows at
    which a GYR, ACC or MAG sample arrived.

    smooth: the smoother (``ekf.smooth_batch``, :func:`smoothed_quats`, computed before the
    first piece): the filter as set, combined with the backward information of a
    Rauch-Tung-Striebel pass where a chi-square test says the two agree; only for the EKF over
    one session (ValueError otherwise). The lights are the forward filter's."""
    smoothed = smoothed_quats(log, estimator, settings, sensors) if smooth else None
    done = 0
    for rows, _ in run_log(log, estimator, settings, sensors):
        rows = rows.select(rows.has_sample)
        if smoothed is not None and len(rows):
            rows.quat = _take_smoothed(smoothed, done, rows.t_ms)
        done += len(rows)
        if len(rows):
            yield rows


def filter_log(log: OrderedLog, estimator: str | ekf.Estimator = "ekf",
               settings: ekf.EKFSettings | None = None, sensors: Iterable[str] = SENSORS,
               smooth: bool = False) -> Rows:
    """:func:`filter_rows` of a whole log in one Rows."""
    return Rows.concatenate(list(filter_rows(log, estimator, settings, sensors, smooth)))


@dataclass
class Smoothed:
    """The smoother's quaternions (N, 4) at its rows' times t_ms (N,)."""

    t_ms: np.ndarray
    quat: np.ndarray


def _take_smoothed(smoothed: Smoothed, done: int, t_ms: np.ndarray) -> np.ndarray:
    """The smoothed quaternions of the runner's next sensor rows (times `t_ms`)."""
    end = done + len(t_ms)
    if not np.array_equal(smoothed.t_ms[done:end], t_ms):
        raise ValueError("the smoother's rows do not match the runner's")   # not expected
    return smoothed.quat[done:end]


def smoothed_quats(log: OrderedLog, estimator: str | ekf.Estimator = "ekf",
                   settings: ekf.EKFSettings | None = None,
                   sensors: Iterable[str] = SENSORS) -> Smoothed:
    """The smoother over the log's GYR/ACC/MAG times (the runner's sensor rows): readings of
    one time at one row, the last of a sensor's equal-time samples winning. ValueError unless
    the estimator is the EKF and the log one session."""
    if estimator not in ("ekf", "course"):
        raise ValueError(f"--smooth needs the EKF (ekf or course), not {estimator!r}")
    t_ms, gyr, acc, mag = sensor_rows(log)
    return Smoothed(t_ms, smooth_rows(t_ms, gyr, acc, mag, estimator, settings, sensors))


def sensor_rows(log: OrderedLog) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A one-session log's distinct GYR/ACC/MAG times t_ms (N,) and the readings at each, gyr,
    acc, mag (N, 3) (NaN: none; the last of equal-time samples wins), in two passes: one counts
    the rows, the next fills arrays of that size (80 bytes a row). ValueError when the log's
    clock restarts."""
    count = 0
    for piece in _whole_times(log):
        count += len(_sensor_times(piece))
    t_ms = np.empty(count, np.int64)
    columns = [np.full((count, 3), np.nan) for _ in SENSOR_CODES]
    filled = 0
    for piece in _whole_times(log):
        times = _sensor_times(piece)
        end = filled + len(times)
        t_ms[filled:end] = times
        for code, column in zip(SENSOR_CODES, columns):
            chosen = piece.tag == code
            # fancy assignment: the last of duplicate rows wins
            column[filled + np.searchsorted(times, piece.t_ms[chosen])] = \
                piece.values[chosen, :3]
        filled = end
    return (t_ms, *columns)


def _sensor_times(piece: LogData) -> np.ndarray:
    return np.unique(piece.t_ms[piece.tag != REFERENCE_CODE])


def _whole_times(log: OrderedLog) -> Iterator[LogData]:
    """A one-session log's chunks re-cut so that no time is split between two pieces (the
    samples of a chunk's last time wait for the next chunk). ValueError when the clock
    restarts (times are not in order across sessions)."""
    held: LogData | None = None
    for chunk in log.chunks():
        if chunk.session_starts:
            raise ValueError("--smooth runs over one session: this log's clock restarts")
        if held is not None:
            chunk = LogData.concatenate(chunk.path, [held, chunk])
        if not len(chunk):
            continue
        cut = int(np.searchsorted(chunk.t_ms, chunk.t_ms[-1], side="left"))
        held = LogData(chunk.path, chunk.t_ms[cut:], chunk.tag[cut:], chunk.values[cut:])
        if cut:
            yield LogData(chunk.path, chunk.t_ms[:cut], chunk.tag[:cut], chunk.values[:cut])
    if held is not None and len(held):
        yield held


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


# ---- evaluate ------------------------------------------------------------------------------------

def sibling_truth(log_path: str | Path) -> Path | None:
    """``NAME.truth.txt`` beside ``NAME.txt`` (or a session folder's), when it exists."""
    path = Path(log_path)
    stem = path.name.split(".")[0] if path.is_file() else path.name
    candidate = path.with_name(stem + ".truth.txt")
    return candidate if candidate.is_file() else None


def score_series(t_est_ms: np.ndarray, q_est: np.ndarray, t_ref_ms: np.ndarray,
                 q_ref: np.ndarray, intervals_ms: list | None, start_ms: float) -> ErrorSummary:
    """RMSE of an estimate series against a reference series, compared at the same instant:
    the estimate is slerp-interpolated to the reference's time stamps (``ekf.metrics``), over
    `intervals_ms` (None: everywhere) from `start_ms` on."""
    q = interpolate_quat(t_est_ms, q_est, t_ref_ms)
    mask = intervals_mask(t_ref_ms, intervals_ms) & (t_ref_ms >= start_ms)
    return ekf.summarize(q, q_ref, mask)


def evaluate_log(log: OrderedLog, estimator: str | ekf.Estimator = "ekf",
                 settings: ekf.EKFSettings | None = None, sensors: Iterable[str] = SENSORS,
                 intervals_ms: list | None = None, skip_s: float = 0.0,
                 truth: OrderedLog | LogScan | None = None, smooth: bool = False,
                 scan: LogScan | None = None) -> ErrorSummary:
    """RMSE (degrees) of the total, heading and inclination error against the reference: the
    ORI of `truth` (an ORI-only log, e.g. ``NAME.truth.txt``, or its ``scan_log(.., ori=True)``)
    when given, else the log's own ORI. The estimate is interpolated to the reference's times
    (slerp), session by session where the log's clock restarts, over `intervals_ms` (None:
    everywhere) after the first `skip_s` seconds of each session's estimates (the figures
    re-filter and tune report). `scan`: the log's ``scan_log(log, ori=True)`` when known.
    The estimates are scored as the runner commits them; only the scored angles are kept.

    Raises ValueError when there is no reference ORI or no sensor samples."""
    reference = None
    if truth is not None:
        truth_scan = truth if isinstance(truth, LogScan) else scan_log(truth, ori=True)
        reference = orientation_series(truth_scan)
    if scan is None or scan.ori_t_ms is None:
        scan = scan_log(log, ori=True)
    if reference is None and not len(scan.ori_t_ms):
        raise ValueError(f"{Path(log.path).name} has no ORI lines to compare with")
    smoothed = smoothed_quats(log, estimator, settings, sensors) if smooth else None
    scorer = ReferenceScorer(scan.ori_t_ms, intervals_ms, skip_s, reference)
    done = 0
    for rows, new_session in run_log(log, estimator, settings, sensors):
        if smoothed is not None and rows.has_sample.any():
            k = int(rows.has_sample.sum())
            rows.quat[rows.has_sample] = _take_smoothed(smoothed, done,
                                                        rows.t_ms[rows.has_sample])
            done += k
        scorer.add(rows)
        if new_session:
            scorer.end_session()
    return scorer.summary()


def evaluate_phone(log: LogScan, truth: LogScan, intervals_ms: list | None = None,
                   skip_s: float = 0.0) -> ErrorSummary:
    """The phone's own estimate (the log's ORI) against the truth, scored like
    :func:`evaluate_log` (the skip counts from the log's first GYR/ACC/MAG sample). Both are
    ``scan_log(.., ori=True)``'s."""
    t_phone, q_phone = orientation_series(log)
    t_ref, q_ref = orientation_series(truth)
    first = float(log.first_sensor_ms) if log.first_sensor_ms is not None else float(t_phone[0])
    return score_series(t_phone, q_phone, t_ref, q_ref, intervals_ms, first + skip_s * 1000.0)


class ReferenceScorer:
    """:func:`reference_errors`' summary of rows that come piece by piece (:func:`run_log`),
    session by session (:meth:`end_session` between two): each reference time is scored once
    the estimates around it exist, and only the angles that count are kept (three numbers per
    scored ORI sample). The angles, and so the figures, are those of reference_errors over the
    whole run, bit for bit."""

    def __init__(self, ori_times: np.ndarray, intervals_ms: list | None = None,
                 skip_s: float = 0.0,
                 reference: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self.ori_times = np.unique(np.asarray(ori_times, np.int64))     # sorted
        self.intervals_ms = intervals_ms
        self.skip_s = skip_s
        self.reference = reference
        self.estimates = 0
        self._angles: list[np.ndarray] = []      # (k, 3) scored total, heading, inclination
        self.end_session()

    def end_session(self) -> None:
        """The rows after this belong to a new session (its estimates start afresh)."""
        self._first_ms: int | None = None             # the session's first estimate
        self._last: tuple[int, np.ndarray] | None = None   # its latest estimate
        self._pending_t = np.empty(0, np.int64)       # its ORI rows not scored yet
        self._pending_q = np.empty((0, 4))

    def add(self, rows: Rows) -> None:
        """The next rows of the current session."""
        if self.reference is None:
            # the rows at ORI times (np.isin would sort the ORI times again for every piece)
            where = np.minimum(np.searchsorted(self.ori_times, rows.t_ms),
                               max(len(self.ori_times) - 1, 0))
            at_ori = (self.ori_times[where] == rows.t_ms) if len(self.ori_times) \
                else np.zeros(len(rows), bool)
            if at_ori.any():
                self._pending_t = np.concatenate([self._pending_t, rows.t_ms[at_ori]])
                self._pending_q = np.concatenate([self._pending_q, rows.phone_quat[at_ori]])
        estimates = rows.select(rows.has_sample)
        if not len(estimates):
            return
        self.estimates += len(estimates)
        t_est, q_est = estimates.t_ms, estimates.quat
        if self._first_ms is None:
            self._first_ms = int(t_est[0])
        if self._last is not None:
            t_est = np.concatenate([[self._last[0]], t_est])
            q_est = np.concatenate([self._last[1][None], q_est])
        newest = int(t_est[-1])
        if self.reference is None:
            ready = self._pending_t <= newest
            t_ref, q_ref = self._pending_t[ready], self._pending_q[ready]
            self._pending_t, self._pending_q = self._pending_t[~ready], self._pending_q[~ready]
        else:
            times, quats = self.reference
            low = np.searchsorted(times, self._last[0], side="right") if self._last is not None \
                else np.searchsorted(times, self._first_ms, side="left")
            high = np.searchsorted(times, newest, side="right")
            t_ref, q_ref = times[low:high], quats[low:high]
        self._last = (newest, q_est[-1].copy())
        if len(t_ref):
            self._score(t_est, q_est, np.asarray(t_ref, np.float64), np.asarray(q_ref, float))

    def _score(self, t_est: np.ndarray, q_est: np.ndarray, t_ref: np.ndarray,
               q_ref: np.ndarray) -> None:
        q = interpolate_quat(t_est.astype(np.float64), q_est, t_ref)
        mask = intervals_mask(t_ref, self.intervals_ms) & (
            t_ref >= self._first_ms + self.skip_s * 1000.0)
        ok = mask & np.isfinite(q).all(axis=1) & np.isfinite(q_ref).all(axis=1)
        if ok.any():
            angles = ekf.error_angles_deg(q, q_ref)
            self._angles.append(np.column_stack([angle[ok] for angle in angles]))

    def summary(self) -> ErrorSummary:
        """The RMSE figures of everything scored. ValueError when no row had an estimate."""
        if not self.estimates:
            raise ValueError("the log has no GYR/ACC/MAG samples")
        angles = np.concatenate(self._angles) if self._angles else np.empty((0, 3))
        return ErrorSummary(rmse(angles[:, 0]), rmse(angles[:, 1]), rmse(angles[:, 2]),
                            len(angles))


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


HEADER = "t_ms,qw,qx,qy,qz,acc_rejected,mag_rejected,at_rest"


def csv_lines(rows: Rows) -> list[str]:
    """The CSV lines (without LF) of the rows that have a sensor sample."""
    rows = rows.select(rows.has_sample)
    out = []
    for t, q, acc, mag, rest in zip(rows.t_ms.tolist(), rows.quat.tolist(),
                                    rows.acc_rejected.tolist(), rows.mag_rejected.tolist(),
                                    rows.at_rest.tolist()):
        out.append(f"{t},{q[0]:.9f},{q[1]:.9f},{q[2]:.9f},{q[3]:.9f},"
                   f"{int(acc)},{int(mag)},{int(rest)}")
    return out


def write_csv(rows: Rows, stream: TextIO) -> None:
    """Header and rows to an open text stream."""
    stream.write(HEADER + "\n")
    write_rows(rows, stream)


def write_rows(rows: Rows, stream: TextIO) -> int:
    """The CSV lines of `rows` (a piece of a run: call it piece after piece, after the
    header) to an open text stream; returns the number of lines."""
    lines = csv_lines(rows)
    if lines:
        stream.write("\n".join(lines) + "\n")
    return len(lines)


class EstimatesWriter:
    """Appends rows to ``estimates.csv`` as they are produced (the engine calls :meth:`write`
    at every publish). Write errors are not raised: they stop the file and are kept in
    :attr:`error` for the caller to report, so a full disk never stops the estimates."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.rows_written = 0
        self.error: str | None = None
        self._stream: TextIO | None = open(self.path, "w", encoding="ascii", newline="\n")
        self._stream.write(HEADER + "\n")

    def write(self, rows: Rows) -> None:
        if self._stream is None or not len(rows):
            return
        try:
            written = write_rows(rows, self._stream)
        except OSError as error:
            self.error = f"{self.path}: {error.strerror or error}"
            self._close_quietly()
            return
        self.rows_written += written

    def flush(self) -> None:
        if self._stream is not None:
            try:
                self._stream.flush()
            except OSError as error:
                self.error = f"{self.path}: {error.strerror or error}"
                self._close_quietly()

    def close(self) -> None:
        if self._stream is not None:
            self.flush()
            self._close_quietly()

    def _close_quietly(self) -> None:
        stream, self._stream = self._stream, None
        if stream is not None:
            try:
                stream.close()
            except OSError:
                pass
