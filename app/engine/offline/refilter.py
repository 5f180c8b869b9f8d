"""Instant re-filter: a whole session run again with other settings, in the background, for an
A/B comparison with a kept "ghost" run.

The log is turned into ordered sample arrays once (:class:`PreparedLog`); each re-run feeds them
to a fresh :class:`~app.engine.processing.runner.EstimatorRunner` in one call, i.e. through the
compiled batch path (the estimators' ``run_batch``, one nogil loop), so the rows are those of
`filter` and of a live replay, bit for bit, and a 10-minute 100 Hz session takes a few tens of
milliseconds (benchmarks/tuning.py). A re-run of a
:class:`~app.engine.processing.configuration.Setup` (the window's configuration over time,
:func:`run_setup`) applies its changes at their sample positions as a replay does, in a few calls,
so Tune's figures are the replay's. Errors against ORI are
:func:`app.engine.offline.filtering.reference_errors`' (the `evaluate` figures).

:class:`Refilterer` runs requests in a thread (latest request wins: a settings change while a
run is under way replaces the waiting one) and hands each result to a callback, from that
thread; a widget forwards it to the GUI thread (a queued signal). Qt-free.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import ekf
from app.engine.processing.configuration import Setup
from app.engine.offline.filtering import (ReferenceErrors, reference_errors, session_row_starts,
                                          smooth_rows)
from app.engine.processing.pipeline import Pipeline
from app.engine.processing.runner import SENSORS, EstimatorRunner, Rows
from app.stream.logfile import LogData

ORI_CODE = 3


@dataclass
class PreparedLog:
    """A log's ordered filter-tag samples as arrays (t_ms int64, tag codes GYR 0, ACC 1, MAG 2,
    ORI 3, values (n, 4)), and its distinct ORI times."""

    t_ms: np.ndarray
    tag: np.ndarray
    values: np.ndarray
    ori_times: np.ndarray
    path: str = ""
    session_starts: tuple[int, ...] = ()

    @classmethod
    def from_log(cls, log: LogData) -> "PreparedLog":
        return cls(log.t_ms, log.tag, log.values, np.unique(log.t_ms[log.tag == ORI_CODE]),
                   log.path, tuple(int(k) for k in log.session_starts))

    @property
    def duration_s(self) -> float:
        return float(self.t_ms[-1] - self.t_ms[0]) / 1000.0 if len(self.t_ms) else 0.0

    @property
    def start_ms(self) -> int:
        return int(self.t_ms[0]) if len(self.t_ms) else 0

    def until(self, t_end_ms: float | None) -> "PreparedLog":
        """The samples up to and including t_end_ms (None: all): a run scored up to there needs
        nothing later."""
        if t_end_ms is None:
            return self
        n = int(np.searchsorted(self.t_ms, t_end_ms, side="right"))
        return PreparedLog(self.t_ms[:n], self.tag[:n], self.values[:n],
                           self.ori_times[self.ori_times <= t_end_ms], self.path,
                           tuple(k for k in self.session_starts if k < n))


def prepare(log: LogData | PreparedLog) -> PreparedLog:
    return log if isinstance(log, PreparedLog) else PreparedLog.from_log(log)


@dataclass
class RefilterResult:
    """One run: its settings, estimator, the rows (every distinct time), the errors against ORI
    (None when the log has no ORI), the wall time it took, and a label ("A", "ghost", ...)."""

    settings: ekf.EKFSettings
    estimator: str
    rows: Rows = field(repr=False)
    errors: ReferenceErrors | None = field(repr=False)
    elapsed_s: float
    label: str = ""

    @property
    def summary(self) -> ekf.metrics.ErrorSummary | None:
        return None if self.errors is None else self.errors.summary


def run_rows(prepared: PreparedLog, settings: ekf.EKFSettings | None, estimator: str = "ekf",
             sensors: Iterable[str] = SENSORS) -> Rows:
    """The rows of a whole run (one runner, one call through the batch path per stream; the
    estimators start afresh where the log's clock restarts, as in run_offline)."""
    runner = EstimatorRunner(estimator, settings, sensors)
    return _run_sessions(prepared, runner, runner.feed_arrays)


def run_setup(prepared: PreparedLog, setup: Setup) -> Rows:
    """The rows of a whole run of `setup`: its configuration at the start (a recording's start
    state too), its changes applied at their sample positions (the engine's
    :class:`~app.engine.processing.pipeline.Pipeline`, fed the ordered samples), the estimators
    afresh where the log's clock restarts; the comparisons are not run (they change no row)."""
    setup = dataclasses.replace(setup, comparisons=False, timeline=tuple(
        c for c in setup.timeline if c.kind != "comparisons"))
    runner = EstimatorRunner(collect_plot=False)
    pipeline = Pipeline(runner)
    pipeline.begin(pipeline.initial_checkpoint(setup), setup.timeline)
    return _run_sessions(prepared, runner, pipeline.feed_samples)


def _run_sessions(prepared: PreparedLog, runner: EstimatorRunner,
                  feed: Callable[[np.ndarray, np.ndarray, np.ndarray], Any]) -> Rows:
    """Feed the log's samples session by session through `feed(t_ms, tag, values)`, the
    estimators afresh where its clock restarts; the rows of the whole run."""
    previous = 0
    for start in list(prepared.session_starts) + [len(prepared.t_ms)]:
        if start > previous:
            feed(prepared.t_ms[previous:start], prepared.tag[previous:start],
                 prepared.values[previous:start])
        if start < len(prepared.t_ms):
            runner.new_session()
        previous = start
    runner.finish()
    return runner.take_rows()


def refilter(log: LogData | PreparedLog, settings: ekf.EKFSettings | None,
             estimator: str = "ekf", sensors: Iterable[str] = SENSORS,
             intervals_ms: list | None = None, skip_s: float = 0.0,
             label: str = "", smooth: bool = False, setup: Setup | None = None
             ) -> RefilterResult:
    """Run the whole log with `settings` and score it against ORI (see the module's docstring).
    smooth: the estimates of the offline smoother instead (the EKF forward and a backward RTS
    pass, as `filter --smooth`; one session only, the EKF only). setup: run this
    configuration over time instead of `settings`, `estimator` and `sensors`."""
    prepared = prepare(log)
    started = time.perf_counter()
    if setup is not None:
        start = setup.start
        settings, estimator, sensors = start.settings, start.estimator, start.sensors
        rows = run_setup(prepared, setup)
        if smooth and any(c.kind in ("sensor", "estimator", "settings") for c in setup.timeline):
            raise ValueError("the smoother runs one configuration over the whole session: this "
                             "one changes on the way (a recorded change or yours)")
    else:
        rows = run_rows(prepared, settings, estimator, sensors)
    if smooth:
        smooth_prepared(prepared, rows, estimator, settings, sensors)
    errors = None
    if len(prepared.ori_times) and rows.has_sample.any():
        errors = reference_errors(rows, prepared.ori_times, intervals_ms, skip_s,
                                  session_row_starts(prepared.t_ms, prepared.session_starts))
    return RefilterResult(settings if settings is not None else ekf.PRESETS["default"],
                          estimator, rows, errors, time.perf_counter() - started, label)


def smooth_prepared(prepared: PreparedLog, rows: Rows, estimator: str,
                    settings: ekf.EKFSettings | None, sensors: Iterable[str]) -> None:
    """Replace the estimates of `rows` (a whole run of `prepared`) by the smoother's."""
    if estimator not in ("ekf", "course"):
        raise ValueError(f"the smoother needs the EKF (ekf or course), not {estimator!r}")
    if prepared.session_starts:
        raise ValueError("the smoother runs over one session: this log's clock restarts")
    times = rows.t_ms[rows.has_sample]
    columns = []
    for code in (0, 1, 2):                          # GYR, ACC, MAG at each distinct time
        chosen = prepared.tag == code
        column = np.full((len(times), 3), np.nan)
        # the last of equal-time samples wins, as in the runner's rows
        column[np.searchsorted(times, prepared.t_ms[chosen])] = prepared.values[chosen, :3]
        columns.append(column)
    rows.quat[rows.has_sample] = smooth_rows(times, *columns, estimator, settings, sensors)


def ab_rows(current: RefilterResult | None,
            ghost: RefilterResult | None) -> list[tuple[str, float, float, float, int]]:
    """The A/B error table: (label, total, heading, inclination RMSE in degrees, samples) for the
    current run, the ghost and their difference (current - ghost), where available."""
    out = []
    for label, result in (("current", current), ("ghost", ghost)):
        if result is not None and result.summary is not None:
            s = result.summary
            out.append((label, s.total_rmse_deg, s.heading_rmse_deg, s.inclination_rmse_deg,
                        s.samples))
    if len(out) == 2:
        a, b = out
        out.append(("difference", a[1] - b[1], a[2] - b[2], a[3] - b[3], a[4] - b[4]))
    return out


def angle_between_runs_deg(current: RefilterResult, ghost: RefilterResult) -> np.ndarray:
    """Per row of the current run, the angle (degrees) between its estimate and the ghost's at
    the same time (NaN where the ghost has no row there): the "difference" curve."""
    index = np.searchsorted(ghost.rows.t_ms, current.rows.t_ms)
    index = np.clip(index, 0, max(len(ghost.rows) - 1, 0))
    out = np.full(len(current.rows), np.nan)
    if len(ghost.rows) == 0:
        return out
    same = ghost.rows.t_ms[index] == current.rows.t_ms
    out[same] = np.degrees(ekf.quaternion.angle_between(current.rows.quat[same],
                                                        ghost.rows.quat[index[same]]))
    return out


class Refilterer:
    """Background re-runs of one log for A/B comparison.

    log: LogData or PreparedLog; estimator, sensors, intervals_ms, skip_s: as for
    :func:`refilter`; on_result(result) is called from the worker thread after each run,
    on_error(exception) when a run fails. :meth:`submit` queues a run with new settings (a
    waiting request is replaced: the latest wins); :meth:`keep_ghost` keeps the current run as
    the ghost. Call :meth:`close` when done."""

    def __init__(self, log: LogData | PreparedLog, estimator: str = "ekf",
                 sensors: Iterable[str] = SENSORS, intervals_ms: list | None = None,
                 skip_s: float = 0.0,
                 on_result: Callable[[RefilterResult], Any] | None = None,
                 on_error: Callable[[BaseException], Any] | None = None) -> None:
        self.prepared = prepare(log)
        self.estimator = estimator
        self.sensors = tuple(sensors)
        self.intervals_ms = intervals_ms
        self.skip_s = skip_s
        self.on_result = on_result
        self.on_error = on_error
        self.smooth = False                 # the smoother's estimates (set, then submit)
        self.current: RefilterResult | None = None
        self.ghost: RefilterResult | None = None
        self.runs = 0
        self._pending: ekf.EKFSettings | Setup | None = None
        self._has_pending = False
        self._busy = False
        self._closed = False
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._loop, name="refilter", daemon=True)
        self._thread.start()

    def submit(self, settings: ekf.EKFSettings | Setup | None) -> None:
        """Re-run the whole log with `settings`, or with a configuration over time (a Setup),
        replacing a request not yet started."""
        with self._cond:
            self._pending, self._has_pending = settings, True
            self._cond.notify_all()

    def keep_ghost(self) -> RefilterResult | None:
        """Keep the current run as the ghost (returned); None when there is no run yet."""
        with self._cond:
            if self.current is not None:
                self.ghost = RefilterResult(self.current.settings, self.current.estimator,
                                            self.current.rows, self.current.errors,
                                            self.current.elapsed_s, "ghost")
            return self.ghost

    def clear_ghost(self) -> None:
        with self._cond:
            self.ghost = None

    def table(self) -> list[tuple[str, float, float, float, int]]:
        with self._cond:
            return ab_rows(self.current, self.ghost)

    def wait(self, timeout: float | None = None) -> bool:
        """Block until no run is waiting or under way (tests, the command line)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while self._has_pending or self._busy:
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return False
                self._cond.wait(remaining)
            return True

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join(timeout=5.0)

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._has_pending and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                settings, self._has_pending, self._busy = self._pending, False, True
            setup = settings if isinstance(settings, Setup) else None
            try:
                result = refilter(self.prepared, None if setup else settings, self.estimator,
                                  self.sensors, self.intervals_ms, self.skip_s,
                                  label="current", smooth=self.smooth, setup=setup)
            except Exception as error:   # reported, never lost: the caller shows it
                self._finish(None)
                if self.on_error is not None:
                    self.on_error(error)
                continue
            self._finish(result)
            if self.on_result is not None:
                self.on_result(result)

    def _finish(self, result: RefilterResult | None) -> None:
        with self._cond:
            if result is not None:
                self.current = result
                self.runs += 1
            self._busy = False
            self._cond.notify_all()


def prepare_path(path: str | Path) -> PreparedLog:
    """A log file or session folder, read and prepared (ConfigError when unusable). A recording
    that started mid-stream is prepared as its replay orders it: from the samples the time
    orderer held then (its session.json's start state), so positions are a replay's."""
    from app.engine.config import open_log, open_replay
    from app.engine.sessions.session import read_session, session_json_for

    log = open_log(path)
    found = session_json_for(log.path)
    start = read_session(found).start_state if found is not None else None
    if start is None:
        return PreparedLog.from_log(log)
    return prepare_from_state(open_replay(path), start)


def prepare_from_state(source: Any, start_state: dict) -> PreparedLog:
    """The ordered samples of a replay source (a LineReplaySource) as the engine's pipeline
    orders them from a recording's start state."""
    pieces: list[tuple[np.ndarray, ...]] = []
    starts: list[int] = []
    count = [0]

    def ordered(t_ms: np.ndarray, tag: np.ndarray, values: np.ndarray) -> None:
        pieces.append((t_ms, tag, values))
        count[0] += len(t_ms)

    pipeline = Pipeline(EstimatorRunner(collect_plot=False), on_ordered=ordered,
                        on_event=lambda kind, **data: starts.append(count[0]))
    pipeline.begin(pipeline.initial_checkpoint(Setup(start_state=start_state)), ())
    step = 1 << 16
    for first in range(0, source.line_count, step):
        pipeline.feed_bytes(source.lines_between(first, min(first + step, source.line_count)))
    pipeline.end_of_stream(partial_line_damaged=False)
    if not pieces:
        pieces.append((np.empty(0, np.int64), np.empty(0, np.int64), np.empty((0, 4))))
    t_ms, tag, values = (np.concatenate(column) for column in zip(*pieces))
    ori = np.unique(t_ms[tag == ORI_CODE])
    return PreparedLog(np.asarray(t_ms, np.int64), np.asarray(tag, np.int64), values, ori,
                       str(getattr(source, "path", "")), tuple(k for k in starts if k > 0))
