"""The engine's side of your filter (YOURS): load and unload it, watch its file, reload it when
it is saved, catch up after a reload, and say what it is doing in every snapshot.

Edit and see: the file is checked every WATCH_INTERVAL_S; when it was saved (its modification
time or size changed) it is loaded again, even with the same content, which is how a paused
filter is resumed. What happens to the session so far:

* a replay (a log file, the demo): the log is re-filtered with the new code from the start of
  the current pass up to exactly the sample the engine has reached, in a background thread;
  rows arriving meanwhile are buffered and run after it, then the new filter takes over
  (:class:`~app.engine.userfilter.lane.UserLane`), and the whole session's YOURS curve is published
  once (UserFilterStatus.history);
* a live phone: the new code continues from now (there is nothing to re-run it on; the
  session recordings issue brings checkpoints) and the status says so.

After a seek the same happens: the engine restores a checkpoint of its own estimators before the
target (app.engine.replay), and your filter, which is not part of a checkpoint (it is your
object), re-runs the log from the pass's start up to that checkpoint in the background, then the
re-sync lines, so it is exactly where playing would have brought it and is never decimated by a
seek. A new pass of a replay (a loop) starts your filter afresh, as it starts ours. A re-run
applies the configuration over time as the engine does (:mod:`app.engine.configuration`): the
sensors switched off at a sample reach your filter as None there, new settings restart it,
resets reset it.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path
from typing import Callable

import numpy as np

import ekf
from app.engine.compare import ErrorSums
from app.engine.configuration import Config, Setup
from app.engine.pipeline import Pipeline
from app.engine.runner import EstimatorRunner
from app.engine.snapshot import Comparison, UserFilterStatus, UserHistory, UserProblem
from app.engine.userfilter.code import FilterCode, UserFilterError, load_code, unload_code
from app.engine.userfilter.filter import UserFilterEstimator
from app.engine.userfilter.lane import UserLane, run_chosen
from app.stream.fastparse import FastLineParser
from app.stream.lines import read_lines
from app.stream.ordering import TimeOrderer
from app.stream.sources import DemoOrPhoneSource, Source

WATCH_INTERVAL_S = 0.3
RERUN_PIECE = 4096             # samples per piece of a re-run (cancel and progress checks)
MAX_CATCH_UP_ROWS = 200_000    # a buffer larger than this is skipped: the filter is too slow
# the changes of the configuration that reach your filter (not OWN's estimator, alignment or
# comparisons)
USER_CHANGES = ("sensor", "settings", "reset")
SLOW_BELOW = 0.99              # used_fraction under this: "slow"


def _stat(path: Path) -> tuple[int, int] | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size


def ordered_log(path: Path, piece_bytes: int = 1 << 20) -> tuple[np.ndarray, ...]:
    """A log's filter-tag samples (t_ms, tag, values) in the order the live engine feeds them
    to the runner: the same compiled parser and time orderer, fed as a replay feeds them."""
    data = b"".join(read_lines(path))
    parser, orderer = FastLineParser(), TimeOrderer()
    pieces = []
    for start in range(0, len(data), piece_bytes):
        parsed = parser.feed_arrays(data[start:start + piece_bytes])
        if len(parsed.t_ms):
            pieces.append(orderer.push_arrays(parsed.t_ms, parsed.tag, parsed.values))
    parsed = parser.finish_arrays()
    if len(parsed.t_ms):
        pieces.append(orderer.push_arrays(parsed.t_ms, parsed.tag, parsed.values))
    pieces.append(orderer.flush_arrays())
    return (np.concatenate([p.t_ms for p in pieces]), np.concatenate([p.tag for p in pieces]),
            np.concatenate([p.values for p in pieces]))


def replay_path(source: Source) -> Path | None:
    """The log a replay source plays (None: a live phone or a source without a file)."""
    if isinstance(source, DemoOrPhoneSource):
        source = None if source.phone_active else source.demo
    if source is None or source.kind != "replay":
        return None
    path = getattr(source, "path", None)
    return Path(path) if path is not None else None


class CatchUp:
    """A background run of a new filter object: the log's first `samples` samples (if any) with
    the pass's `setup` (its configuration over time), then the rows the lane buffered
    meanwhile, then the hand-over."""

    def __init__(self, lane: UserLane, estimator: UserFilterEstimator, log: Path | None,
                 samples: int, setup: Setup, arrays: Callable[[Path], tuple]) -> None:
        self.lane, self.estimator, self.log, self.samples = lane, estimator, log, samples
        self.setup = setup
        self._arrays = arrays
        self.cancel = threading.Event()
        self.done = threading.Event()
        self.progress = 0.0
        self.history: UserHistory | None = None
        self.errors = ErrorSums()
        self.skipped_rows = 0
        self.error = ""
        self.started = time.perf_counter()
        self.seconds = math.nan
        self.token = lane.begin_catch_up()
        self.thread = threading.Thread(target=self._run, name="user-filter-catch-up", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def _run(self) -> None:
        try:
            if self.samples and self.log is not None:
                self._rerun_log()
            if not self.cancel.is_set():
                self._drain()
        except Exception as error:   # noqa: BLE001 (the user's errors are caught deeper; ours)
            self.error = f"catch-up failed: {type(error).__name__}: {error}"
            self.lane.replace(self.estimator)
        finally:
            self.seconds = time.perf_counter() - self.started
            self.done.set()

    def _rerun_log(self) -> None:
        t_ms, tag, values = self._arrays(self.log)
        n = min(self.samples, len(t_ms))
        runner = EstimatorRunner(self.estimator, self.setup.settings, self.setup.sensors)
        start_config = self.setup.start
        if self.estimator.settings != start_config.settings:
            self.estimator.set_settings(start_config.settings)
        for sensor in ekf.SENSORS:
            runner.set_sensor_enabled(sensor, sensor in start_config.sensors)
        pipeline = Pipeline(runner)
        pipeline.continue_with(tuple(c for c in self.setup.until(n).timeline
                                     if c.kind in USER_CHANGES))
        for start in range(0, n, RERUN_PIECE):
            if self.cancel.is_set() or self.estimator.paused:
                break
            end = min(n, start + RERUN_PIECE)
            pipeline.feed_samples(t_ms[start:end], tag[start:end], values[start:end])
            self.progress = end / max(n, 1)
        runner.finish()
        rows = runner.take_rows()
        rows = rows.select(rows.has_sample)
        errors = runner.take_errors()          # against PHONE at PHONE's times
        self.errors.add(errors)
        if len(rows):
            euler = np.degrees(ekf.quaternion.to_euler(rows.quat))
            self.history = UserHistory(rows.t_ms, euler, errors.t_ms, errors.error_deg)

    def _drain(self) -> None:
        if not self.samples:
            # after a seek: the re-sync lines are about to arrive; do not hand over before
            deadline = time.perf_counter() + 0.5
            while (not self.lane.buffered_rows and time.perf_counter() < deadline
                   and not self.cancel.is_set()):
                time.sleep(0.01)
        while not self.cancel.is_set():
            pieces = self.lane.take_buffered(self.estimator, self.token)
            if pieces is None:
                return
            if sum(len(p[0]) for p in pieces) > MAX_CATCH_UP_ROWS:
                self.skipped_rows += sum(len(p[0]) for p in pieces)
                continue
            for t_s, gyr, acc, mag in pieces:
                if self.cancel.is_set():
                    return
                run_chosen(self.estimator, np.arange(len(t_s)), t_s, gyr, acc, mag)


class UserFilterHost:
    """Owns the user's filter for one engine (all methods are called from the engine thread).

    record(kind, **data) writes a session timeline entry (the recorder's, through the engine);
    realtime: the lane decimates a filter slower than the stream; position(): the samples fed
    to the estimators in the current pass (a replay's position; default: counted here from the
    last restart); setup(): the pass's configuration over time (default: the runner's now).
    """

    def __init__(self, runner: EstimatorRunner, source: Source,
                 record: Callable[..., None] | None = None, realtime: bool = True,
                 clock: Callable[[], float] = time.monotonic,
                 position: Callable[[], int] | None = None,
                 setup: Callable[[], Setup] | None = None) -> None:
        self.runner = runner
        self._position = position
        self._setup = setup or (lambda: Setup.of(Config.of(self.runner)))
        self.source = source
        self._record = record or (lambda kind, **data: None)
        self.realtime = realtime
        self._clock = clock
        self.lane: UserLane | None = None
        self.path: Path | None = None
        self.code: FilterCode | None = None
        self.load_problem: UserProblem | None = None
        self.generation = 0
        self.message = ""
        self._done = "loaded"
        self.history: UserHistory | None = None
        self.job: CatchUp | None = None
        self._stat: tuple[int, int] | None = None
        self._checked = -math.inf
        self._base = 0
        self._log_cache: dict[Path, tuple[tuple[int, int] | None, tuple]] = {}

    # -- commands -------------------------------------------------------------------------------

    def load(self, path: str | Path, action: str = "load") -> None:
        """Load (or reload) the file; problems end up in the status, never raised."""
        path = Path(path).expanduser().resolve()
        self._cancel_job()
        self.path, self._stat = path, _stat(path)
        self.generation += 1
        self.history = None
        if self.lane is None:
            self.lane = UserLane(realtime=self.realtime)
            self.runner.set_user_lane(self.lane)
        if self.code is not None:
            unload_code(self.code)
        try:
            self.code = load_code(path)
            estimator = UserFilterEstimator(self.code, self.runner.settings)
        except UserFilterError as error:
            self.code, self.load_problem = None, error.problem
            self.lane.replace(None)
            self.message = f"{path.name} does not load: fix it and save it again"
            self._record("user_filter", action=action, name=path.name, path=str(path),
                         sha256=None, problem=error.problem.message)
            return
        self.load_problem = None
        estimator.collect_innovations = True
        self._record("user_filter", action=action, name=path.name, path=str(path),
                     sha256=self.code.sha256)
        self._start(estimator, action)

    def _start(self, estimator: UserFilterEstimator, action: str) -> None:
        done = self._done = "reloaded" if action == "reload" else "loaded"
        log = replay_path(self.source)
        samples = self._samples()
        if log is not None and samples > 0:
            self.job = CatchUp(self.lane, estimator, log, samples, self._setup(),
                               self._log_arrays)
            self.job.start()
            self.message = f"{done}: re-running the replay up to now with the new code"
        else:
            self.lane.replace(estimator)
            self.lane.reset_errors()
            self.message = (f"{done}: live stream, your filter continues from now with the new "
                            "code (the session so far is not re-run)"
                            if action == "reload" and samples > 0 else f"{done}")

    def unload(self) -> None:
        self._cancel_job()
        if self.lane is not None:
            self.lane.replace(None)
        self.runner.set_user_lane(None)
        if self.code is not None:
            unload_code(self.code)
            self._record("user_filter", action="unload", name=self.code.name,
                         path=str(self.code.path), sha256=self.code.sha256)
        self.lane = self.code = self.path = self.load_problem = self.history = None
        self.message = ""

    def stop(self) -> None:
        self._cancel_job()

    def _cancel_job(self) -> None:
        if self.job is not None:
            self.job.cancel.set()
            self.job = None

    # -- the engine's events ---------------------------------------------------------------------

    def _samples(self) -> int:
        """Samples fed to the estimators in this pass so far."""
        if self._position is not None:
            return int(self._position())
        return self.runner.samples_fed - self._base

    def on_restart(self, kind: str) -> None:
        """After the engine restarted the stream ("connected", "loop", "seek"): samples are
        counted from here; a new pass of a replay starts your filter afresh; after a seek the
        re-sync lines are run in the background."""
        self._base = self.runner.samples_fed
        lane = self.lane
        if kind in ("loop", "seek") and lane is not None and self.job is None:
            lane.reset()
            estimator = lane.estimator
            if estimator is not None and estimator.settings != self.runner.settings:
                estimator.set_settings(self.runner.settings)    # the pass's, from its start
        if kind != "seek" or lane is None or self.job is not None:
            return
        estimator = lane.estimator
        if estimator is not None and not estimator.paused:
            self.job = CatchUp(lane, estimator, None, 0, self._setup(), self._log_arrays)
            self.job.start()

    def on_seek(self) -> None:
        """A replay jumped: the engine restored a checkpoint before the target and is about to
        replay the lines from there. Your filter re-runs the log from the pass's start up to
        the checkpoint in the background with a fresh object, then the lines after it (buffered
        meanwhile), as after a reload."""
        if self.lane is None or self.code is None:
            return
        self._cancel_job()
        estimator = UserFilterEstimator(self.code, self.runner.settings)
        estimator.collect_innovations = True
        log = replay_path(self.source)
        samples = self._samples()
        if log is None or samples <= 0:
            self.lane.replace(estimator)
            self.lane.reset_errors()
            return
        self.job = CatchUp(self.lane, estimator, log, samples, self._setup(),
                           self._log_arrays)
        self.job.start()
        self._done = "after the seek"
        self.message = "after the seek: re-running the replay up to there with your filter"

    def tick(self) -> None:
        """Between two passes: reload a saved file, finish a catch-up."""
        now = self._clock()
        if self.path is not None and now - self._checked >= WATCH_INTERVAL_S:
            self._checked = now
            stat = _stat(self.path)
            if stat is not None and stat != self._stat:
                self.load(self.path, "reload")
        job = self.job
        if job is not None and job.done.is_set():
            self.job = None
            if self.lane is not None and job.errors.count:
                self.lane.errors.squared = self.lane.errors.squared + job.errors.squared
                self.lane.errors.count += job.errors.count
                self.lane.errors.latest = job.errors.latest
            if job.history is not None:
                self.history = job.history
                self.message = (f"{self._done}: re-ran {len(job.history.t_ms)} rows of the "
                                f"replay in {job.seconds:.1f} s")
            if job.skipped_rows:
                self.message += f"; too slow to catch up: {job.skipped_rows} rows skipped"
            if job.error:
                self.message = job.error

    def _log_arrays(self, path: Path) -> tuple:
        """The log's filter-tag samples in release order, as the live engine got them (parsed
        once per file version)."""
        stat = _stat(path)
        cached = self._log_cache.get(path)
        if cached is not None and cached[0] == stat:
            return cached[1]
        result = ordered_log(path)
        self._log_cache = {path: (stat, result)}
        return result

    # -- what the snapshot shows -----------------------------------------------------------------

    def status(self) -> UserFilterStatus | None:
        if self.path is None:
            return None
        lane = self.lane
        job = self.job
        estimator = job.estimator if job is not None else (lane.estimator if lane else None)
        status = UserFilterStatus(name=self.path.name, path=str(self.path),
                                  sha256=self.code.sha256 if self.code else "",
                                  generation=self.generation, message=self.message,
                                  history=self.history)
        if estimator is None:
            status.problem = self.load_problem
            status.state = "failed to load" if self.load_problem else "running"
            return status
        status.problem = estimator.problem
        status.state = ("catching up" if job is not None else
                        "paused" if estimator.problem is not None else "running")
        status.progress = None if job is None else job.progress
        _fill_outputs(status, estimator)
        if lane is not None:
            status.used_fraction = lane.used_fraction()
            status.slow = status.used_fraction < SLOW_BELOW
            status.angle_to_phone_deg = lane.angle_to_phone_deg
            status.rmse_deg = lane.rmse_deg
        return status

    def comparison_row(self) -> Comparison | None:
        """YOURS' row of the comparison table: its total, heading and inclination errors
        against PHONE at PHONE's times."""
        status = self.status()
        if status is None:
            return None
        errors = self.lane.errors if self.lane is not None else None
        if errors is None:
            return Comparison(f"YOURS ({status.name})", status.quat)
        return Comparison(f"YOURS ({status.name})", status.quat, tuple(errors.rmse().tolist()),
                          tuple(errors.latest.tolist()), errors.count)


def _fill_outputs(status: UserFilterStatus, estimator: UserFilterEstimator) -> None:
    out = estimator.output
    if out is not None:
        status.quat = estimator.quat
        status.cov = estimator.cov
        status.acc_disturbed, status.mag_disturbed = out.acc_disturbed, out.mag_disturbed
        status.standstill = out.standstill
    status.missing_steps = estimator.missing_steps()
    status.notes = list(estimator.notes)
    status.time_per_sample_s = estimator.time_per_call_s
    status.steps = estimator.calls
