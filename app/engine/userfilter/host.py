"""The engine's side of your filter (YOURS): load and unload it, watch its file, reload it when
it is saved, catch up after a reload, and say what it is doing in every snapshot.

Your filter runs in a process of its own (app.engine.userfilter.remote), one per load: loading,
reloading and unloading end the previous process and whatever it started. Nothing here waits
for it: the file loads in that process while the engine goes on ("loading"), its results come
back to the lane (app.engine.userfilter.lane), and a filter that is stuck or whose process
ended is paused with the reason.

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
target (app.engine.sessions.replay), and your filter, which is not part of a checkpoint (it is your
object), re-runs the log from the pass's start up to that checkpoint in the background, then the
re-sync lines, so it is exactly where playing would have brought it and is never decimated by a
seek. A new pass of a replay (a loop) starts your filter afresh, as it starts ours, with the
pass's settings. A re-run applies the configuration over time as the engine does
(:mod:`app.engine.processing.configuration`): the sensors switched off at a sample reach your filter
as None there, new settings restart it, resets reset it.

What your filter prints is kept (the last PRINTED_SHOWN lines are in the status, for the dock)
and logged to the ``orientation_lab.your_filter`` logger, at most LOG_LINES_PER_S lines a second.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from pathlib import Path
from typing import Callable

import numpy as np

import ekf
from app.engine.processing.compare import ErrorSums
from app.engine.processing.configuration import Config, Setup
from app.engine.processing.pipeline import Pipeline
from app.engine.processing.runner import EstimatorRunner
from app.engine.snapshot import Comparison, UserFilterStatus, UserHistory, UserProblem
from app.engine.userfilter.code import UserFilterError
from app.engine.userfilter.filter import UserFilterEstimator
from app.engine.userfilter.lane import UserLane
from app.engine.userfilter.octave import MatlabFolder, filter_folder, is_matlab_filter
from app.engine.userfilter.octave_remote import load_filter_process
from app.engine.userfilter.remote import RemoteFilter
from app.stream.fastparse import FastLineParser
from app.stream.lines import read_lines
from app.stream.ordering import TimeOrderer
from app.stream.sources import Source

WATCH_INTERVAL_S = 0.3
RERUN_PIECE = 4096             # samples per piece of a re-run (cancel and progress checks)
MAX_CATCH_UP_ROWS = 200_000    # a buffer larger than this is skipped: the filter is too slow
# the changes of the configuration that reach your filter (not OWN's estimator, alignment or
# comparisons)
USER_CHANGES = ("sensor", "settings", "reset")
SLOW_BELOW = 0.99              # used_fraction under this: "slow"
PRINTED_SHOWN = 20             # lines your filter printed, in the status
LOG_LINES_PER_S = 20

log = logging.getLogger("orientation_lab.your_filter")


def _stat(path: Path) -> tuple | None:
    """What changes when the filter is saved: the file's modification time and size (a MATLAB
    filter: those of each .m file in its folder, and their names)."""
    if is_matlab_filter(path):
        return MatlabFolder.stat(path)
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
    path = getattr(source.played(), "path", None)
    return Path(path) if path is not None else None


class PrintedLog:
    """What a filter prints, to the log: at most LOG_LINES_PER_S lines a second (the rest are
    counted and said once the next line is logged). Called from the process's output thread."""

    def __init__(self, name: str, clock: Callable[[], float] = time.monotonic) -> None:
        self.name = name
        self._clock = clock
        self._second = -math.inf
        self._lines = 0
        self.dropped = 0

    def __call__(self, line: str) -> None:
        now = self._clock()
        if now - self._second >= 1.0:
            self._second, self._lines = now, 0
        if self._lines >= LOG_LINES_PER_S:
            self.dropped += 1
            return
        self._lines += 1
        if self.dropped:
            log.info("%s printed %d lines more than the log keeps", self.name, self.dropped)
            self.dropped = 0
        log.info("%s: %s", self.name, line)


class CatchUp:
    """A background run of the filter's process: the log's first `samples` samples (if any)
    with the pass's `setup` (its configuration over time), then the rows the lane buffered
    meanwhile, then the hand-over."""

    def __init__(self, lane: UserLane, remote: RemoteFilter, log: Path | None,
                 samples: int, setup: Setup, arrays: Callable[[Path], tuple]) -> None:
        self.lane, self.remote, self.log, self.samples = lane, remote, log, samples
        self.setup = setup
        self.settings = setup.start.settings
        self._arrays = arrays
        self.cancel = threading.Event()
        self.estimator = UserFilterEstimator(remote, self.settings)
        self.estimator.cancel = self.cancel
        self.estimator.collect_innovations = False
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

    def stop(self, timeout: float = 5.0) -> None:
        """Cancel it and wait for its thread."""
        self.cancel.set()
        if self.thread.is_alive() and self.thread is not threading.current_thread():
            self.thread.join(timeout)

    def _hand_over(self) -> None:
        """The process takes over as it is (it does not load, it is stuck or gone, or the
        catch-up failed): the rows buffered meanwhile are dropped. Nothing when superseded."""
        while self.lane.take_buffered(self.remote, self.token) is not None:
            pass

    def _run(self) -> None:
        try:
            self.estimator.wait_started()
            if self.remote.load_problem is not None or not self.remote.usable:
                self._hand_over()
                return
            if self.samples and self.log is not None:
                self._rerun_log()
            if not self.cancel.is_set():
                self._drain()
        except Exception as error:   # noqa: BLE001 (the user's errors are caught deeper; ours)
            self.error = f"catch-up failed: {type(error).__name__}: {error}"
            self._hand_over()
        finally:
            self.seconds = time.perf_counter() - self.started
            self.done.set()

    def _rerun_log(self) -> None:
        t_ms, tag, values = self._arrays(self.log)
        n = min(self.samples, len(t_ms))
        runner = EstimatorRunner(self.estimator, self.settings)
        for sensor in ekf.SENSORS:
            runner.set_sensor_enabled(sensor, sensor in self.setup.sensors)
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
        # the buffered rows are the runner's: a switched-off sensor is left out of them already
        self.estimator.set_enabled(**{sensor: True for sensor in ekf.SENSORS})
        while not self.cancel.is_set():
            estimator = self.estimator
            pieces = self.lane.take_buffered(self.remote, self.token, (
                estimator.quat if estimator.initialised else None, estimator.lights,
                estimator.cov))
            if pieces is None:
                return
            if sum(len(p[0]) for p in pieces) > MAX_CATCH_UP_ROWS:
                self.skipped_rows += sum(len(p[0]) for p in pieces)
                continue
            for t_s, gyr, acc, mag in pieces:
                if self.cancel.is_set():
                    return
                self.estimator.run_batch(t_s, gyr, acc, mag)


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
        self.remote: RemoteFilter | None = None
        self.load_problem: UserProblem | None = None
        self.generation = 0
        self.message = ""
        self._done = "loaded"
        self._action = "load"
        self._load_said = True
        self.history: UserHistory | None = None
        self.job: CatchUp | None = None
        self._stat: tuple[int, int] | None = None
        self._checked = -math.inf
        self._base = 0
        self._log_cache: dict[Path, tuple[tuple[int, int] | None, tuple]] = {}

    # -- commands -------------------------------------------------------------------------------

    def load(self, path: str | Path, action: str = "load") -> None:
        """Load (or reload) the file in a new process (the previous one ends); problems end up
        in the status, never raised."""
        path = Path(path).expanduser().resolve()
        if is_matlab_filter(path):
            path = filter_folder(path)            # a .m file names its folder
        self._cancel_job()
        self.path, self._stat = path, _stat(path)
        self.generation += 1
        self.history = None
        if self.lane is None:
            self.lane = UserLane(realtime=self.realtime)
            self.runner.set_user_lane(self.lane)
        self._close_remote()
        try:
            remote = load_filter_process(path, self.runner.settings,
                                         on_output=PrintedLog(path.name))
        except UserFilterError as error:
            self.load_problem = error.problem
            self.lane.replace(None)
            self.message = f"{path.name} does not load: fix it and save it again"
            self._record("user_filter", action=action, name=path.name, path=str(path),
                         sha256=None, problem=error.problem.message)
            return
        self.remote, self.load_problem = remote, None
        self._action, self._load_said = action, False
        self._record("user_filter", action=action, name=path.name, path=str(path),
                     sha256=remote.sha256)
        self._start(remote, action)

    def _start(self, remote: RemoteFilter, action: str) -> None:
        done = self._done = "reloaded" if action == "reload" else "loaded"
        log = replay_path(self.source)
        samples = self._samples()
        if log is not None and samples > 0:
            self.job = CatchUp(self.lane, remote, log, samples, self._setup(),
                               self._log_arrays)
            self.job.start()
            self.message = f"{done}: re-running the replay up to now with the new code"
        else:
            self.lane.replace(remote)
            self.lane.reset_errors()
            self.message = (f"{done}: live stream, your filter continues from now with the new "
                            "code (the session so far is not re-run)"
                            if action == "reload" and samples > 0 else f"{done}")

    def _close_remote(self) -> None:
        if self.remote is not None:
            self.remote.close()
            self.remote = None

    def unload(self) -> None:
        self._cancel_job()
        if self.lane is not None:
            self.lane.replace(None)
        self.runner.set_user_lane(None)
        if self.remote is not None:
            self._record("user_filter", action="unload", name=self.remote.name,
                         path=str(self.remote.path), sha256=self.remote.sha256)
        self._close_remote()
        self.lane = self.path = self.load_problem = self.history = None
        self.message = ""

    def stop(self) -> None:
        """The engine ends: the catch-up stops and the filter's process ends."""
        job = self.job
        self._cancel_job()
        self._close_remote()
        if job is not None:
            job.stop()

    def _cancel_job(self) -> None:
        """Cancel the catch-up (never waits: its thread ends by itself once its process is
        closed or it sees the cancel)."""
        if self.job is not None:
            job, self.job = self.job, None
            job.cancel.set()

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
            lane.set_settings(self.runner.settings)     # afresh, with the pass's settings
        if kind != "seek" or lane is None or self.job is not None:
            return
        remote = lane.remote
        if remote is not None and not remote.paused:
            self.job = CatchUp(lane, remote, None, 0, self._setup(), self._log_arrays)
            self.job.start()

    def on_seek(self) -> None:
        """A replay jumped: the engine restored a checkpoint before the target and is about to
        replay the lines from there. Your filter re-runs the log from the pass's start up to
        the checkpoint in the background with a fresh Filter object, then the lines after it
        (buffered meanwhile), as after a reload."""
        if self.lane is None or self.remote is None:
            return
        running = self.job is not None and not self.job.done.is_set()
        self._cancel_job()
        setup = self._setup()
        log = replay_path(self.source)
        samples = self._samples()
        # a re-run starts with the pass's settings; without one, the runner's now
        settings = setup.start.settings if log is not None and samples > 0 \
            else self.runner.settings
        if self.remote.usable and not running:
            self.remote.reset(settings, fresh=True, new_epoch=True)
        else:       # stuck, ended, or a catch-up still using it: a new process for the same code
            remote = self.remote.again(settings)
            self._close_remote()
            self.remote = remote
        if log is None or samples <= 0:
            self.lane.replace(self.remote)
            self.lane.reset_errors()
            return
        self.job = CatchUp(self.lane, self.remote, log, samples, setup, self._log_arrays)
        self.job.start()
        self._done = "after the seek"
        self.message = "after the seek: re-running the replay up to there with your filter"

    def tick(self) -> None:
        """Between two passes: take your filter's results, reload a saved file, finish a
        catch-up."""
        if self.lane is not None and self.job is None:
            self.lane.collect()
        self._say_load()
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

    def _say_load(self) -> None:
        """Once the process says the file does not load: the message and the session's
        timeline say so."""
        remote = self.remote
        if self._load_said or remote is None or not (remote.started or remote.paused):
            return
        self._load_said = True
        problem = remote.load_problem
        if problem is None and not remote.started:
            problem = remote.problem              # stuck while loading, or the process ended
        if problem is not None:
            self.message = f"{remote.name} does not load: fix it and save it again"
            self._record("user_filter", action="load failed", name=remote.name,
                         path=str(remote.path), sha256=remote.sha256, problem=problem.message)

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
        remote = self.remote
        status = UserFilterStatus(name=self.path.name, path=str(self.path),
                                  sha256=remote.sha256 if remote is not None else "",
                                  generation=self.generation, message=self.message,
                                  history=self.history)
        if remote is None:
            status.problem = self.load_problem
            status.state = "failed to load" if self.load_problem else "running"
            return status
        status.problem = remote.problem
        status.state = ("failed to load" if remote.load_problem is not None
                        or (remote.problem is not None and not remote.started) else
                        "paused" if remote.problem is not None else
                        "loading" if not remote.started else
                        "catching up" if job is not None else "running")
        status.progress = None if job is None else job.progress
        status.missing_steps = list(remote.missing)
        status.notes = list(remote.notes)
        status.time_per_sample_s = remote.time_per_call_s
        status.steps = remote.calls
        printed = remote.output
        status.printed = printed[-PRINTED_SHOWN:]
        status.printed_total = remote.process.lines_total
        if job is not None:
            estimator = job.estimator
            if estimator.initialised:
                status.quat = estimator.quat
                status.cov = estimator.cov
                status.acc_disturbed, status.mag_disturbed, status.standstill = estimator.lights
        elif lane is not None and lane.output_q is not None:
            status.quat = lane.output_q.copy()
            status.cov = None if lane.cov is None else lane.cov.copy()
            status.acc_disturbed, status.mag_disturbed, status.standstill = lane.lights
        if lane is not None:
            status.used_fraction = lane.used_fraction()
            status.slow = remote.started and status.used_fraction < SLOW_BELOW
            status.lag_s = lane.lag_s
            status.backlog_rows = lane.backlog_rows
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
