"""Instant re-filter: a whole session run again with other settings, in the background, for an
A/B comparison with a kept "ghost" run.

The log is read into ordered sample arrays once (a :class:`~app.stream.logfile.LogData`, the
form `filter` takes too); each re-run is :func:`~app.engine.offline.filtering.run_offline` over
them: a fresh :class:`~app.engine.processing.runner.EstimatorRunner` fed through the compiled
batch path (the estimators' ``run_batch``, one nogil loop per chunk), so the rows are those of
`filter` and of a live replay, bit for bit, and a 10-minute 100 Hz session takes a few tens of
milliseconds (benchmarks/tuning.py). A re-run of a
:class:`~app.engine.processing.configuration.Setup` (the window's configuration over time)
applies its changes at their sample positions as a replay does, so Tune's figures are the
replay's. Errors against ORI are :func:`app.engine.offline.filtering.reference_errors`' (the
`evaluate` figures).

:class:`Refilterer` runs requests in a thread (latest request wins: a settings change while a
run is under way replaces the waiting one) and hands each result to a callback, from that
thread; a widget forwards it to the GUI thread (a queued signal). Qt-free.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import ekf
from app.engine.processing.configuration import Setup
from app.engine.offline.filtering import (ReferenceErrors, reference_errors, run_offline,
                                          session_row_starts, smoothed_quats)
from app.engine.processing.pipeline import Pipeline
from app.engine.processing.runner import SENSORS, EstimatorRunner, Rows
from app.stream.logfile import LogData

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


def refilter(log: LogData, settings: ekf.EKFSettings | None, estimator: str = "ekf",
             sensors: Iterable[str] = SENSORS, intervals_ms: list | None = None,
             skip_s: float = 0.0, label: str = "", smooth: bool = False,
             setup: Setup | None = None) -> RefilterResult:
    """Run the whole log with `settings` and score it against ORI (see the module's docstring).
    smooth: the estimates of the offline smoother instead (the EKF forward and a backward RTS
    pass, as `filter --smooth`; one session only, the EKF only). setup: run this
    configuration over time instead of `settings`, `estimator` and `sensors`."""
    started = time.perf_counter()
    if setup is not None:
        start = setup.start
        settings, estimator, sensors = start.settings, start.estimator, start.sensors
        if smooth and any(c.kind in ("sensor", "estimator", "settings") for c in setup.timeline):
            raise ValueError("the smoother runs one configuration over the whole session: this "
                             "one changes on the way (a recorded change or yours)")
    if smooth and estimator not in ("ekf", "course"):
        raise ValueError(f"the smoother needs the EKF (ekf or course), not {estimator!r}")
    if smooth and log.session_starts:
        raise ValueError("the smoother runs over one session: this log's clock restarts")
    rows = run_offline(log, estimator, settings, sensors, setup)
    if smooth:
        rows.quat[rows.has_sample] = smoothed_quats(log, estimator, settings, sensors).quat
    errors = None
    if len(log.ori_times) and rows.has_sample.any():
        errors = reference_errors(rows, log.ori_times, intervals_ms, skip_s,
                                  session_row_starts(log.t_ms, log.session_starts))
    return RefilterResult(settings if settings is not None else ekf.PRESETS["default"],
                          estimator, rows, errors, time.perf_counter() - started, label)


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

    log: the LogData to re-run; estimator, sensors, intervals_ms, skip_s: as for
    :func:`refilter`; on_result(result) is called from the worker thread after each run,
    on_error(exception) when a run fails. :meth:`submit` queues a run with new settings (a
    waiting request is replaced: the latest wins); :meth:`keep_ghost` keeps the current run as
    the ghost. Call :meth:`close` when done."""

    def __init__(self, log: LogData, estimator: str = "ekf",
                 sensors: Iterable[str] = SENSORS, intervals_ms: list | None = None,
                 skip_s: float = 0.0,
                 on_result: Callable[[RefilterResult], Any] | None = None,
                 on_error: Callable[[BaseException], Any] | None = None) -> None:
        self.log = log
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
                result = refilter(self.log, None if setup else settings, self.estimator,
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


def read_replayed(path: str | Path) -> LogData:
    """A log file or session folder, read whole (ConfigError when unusable). A recording that
    started mid-stream is read as its replay orders it: from the samples the time orderer held
    then (its session.json's start state), so positions are a replay's."""
    from app.engine.config import open_log, open_replay
    from app.engine.sessions.session import read_session, session_json_for

    log = open_log(path)
    found = session_json_for(log.path)
    start = read_session(found).start_state if found is not None else None
    if start is None:
        return log
    return ordered_from_state(open_replay(path), start)


def ordered_from_state(source: Any, start_state: dict) -> LogData:
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
    return LogData(str(getattr(source, "path", "")), np.asarray(t_ms, np.int64),
                   np.asarray(tag, np.int64), values, tuple(k for k in starts if k > 0))
