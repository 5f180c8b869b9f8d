"""The background engine: source -> parser -> time ordering -> estimators -> snapshots.

One plain ``threading`` thread (no Qt) runs the filter at the sample rate; the GUI (or the
``serve`` command) calls :meth:`Engine.poll` at its own frame rate and gets the latest
estimates, status and stream health plus every plot sample since its previous poll, merged into
one :class:`~app.engine.snapshot.PlotChunk`. Neither side waits for the other; buffers are
bounded. Commands (:mod:`app.engine.commands`) go in with :meth:`Engine.send` and are applied
between two batches of samples, in the order they were sent.

Nothing a client sends reaches a filter unchecked: the parser rejects values outside the
physical bounds (:class:`~app.stream.protocol.Limits`; counted as damaged by reason), and a
stream whose clock does not continue the previous one's starts a new session (the orderer says
where; the estimators start afresh, nothing of an earlier connection carries over). A recording
that fails (disk full, folder removed, size or free-space limit) stops with a one-line warning
while the stream and the estimates go on.

A failure while processing a batch never ends the engine silently: it is logged with its
traceback, published in the snapshots (:class:`~app.engine.snapshot.EngineFailure`, which the
window shows with a "copy details" button and `serve` prints) and the engine goes on with the
next batch; after MAX_FAILURES failures within FAILURE_WINDOW_S it stops cleanly instead
(source closed, state "stopped", the reason published).

Replays (:mod:`app.engine.replay`): every pass starts from the same state; a background index
keeps a checkpoint every second of data, so a seek restores the nearest one before its target
and replays at most one second; a recorded session's timeline is applied at its sample
positions. Recording (:mod:`app.engine.recording`) starts and stops with commands at any time.

The engine thread works chunk by chunk: everything the source has is parsed in one compiled call
(:class:`~app.stream.fastparse.FastLineParser`), ordered in one (:class:`~app.stream.ordering.TimeOrderer`)
and run through each estimator in one (:meth:`~app.engine.runner.EstimatorRunner.feed_arrays`); the
kernels release the GIL, so the GUI thread keeps running while the engine computes.
"""

from __future__ import annotations

import dataclasses
import logging
import queue
import threading
import time
import traceback
from collections import deque
from collections.abc import Iterable
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

import ekf
from app.engine.commands import ReplayControl, StartRecording
from app.engine.config import ConfigError, megabytes
from app.engine.command_table import Mark, handler_of
from app.engine.forwarding import switch_forward
from app.engine.estimates import EstimatesWriter
from app.engine.health import HealthTracker, stats_dict
from app.engine.markers import Markers
from app.engine.pipeline import Pipeline
from app.engine.recording import SessionRecording
from app.engine.replay import ReplayManager, session_for_source
from app.engine.runner import SENSORS, EstimatorRunner, Rows
from app.engine.session import SessionInfo, default_session_folder
from app.engine.warmup import warm_up
from app.engine.snapshot import (Comparison, EngineFailure, FilterStatus, PlotBuffer, PlotChunk,
                                 Snapshot, StreamHealth)
from app.engine.userfilter.code import is_filter_file
from app.engine.userfilter.host import UserFilterHost
from app.stream import fastparse
from app.stream.events import Chunk, SourceEvent
from app.stream.fastparse import ParsedArrays
from app.stream.forwarder import LineForwarder
from app.stream.protocol import DEFAULT_LIMITS, Limits
from app.stream.recorder import DEFAULT_MAX_BYTES, DEFAULT_MIN_FREE_BYTES, Recorder, \
    new_session_folder
from app.stream.sources import DemoOrPhoneSource, LineReplaySource, Source

log = logging.getLogger("orientation_lab.engine")

MAX_BYTES_PER_PASS = 1 << 20    # received bytes processed between two publishes (~25k lines)
PUBLISH_IDLE_S = 0.25          # publish health at least this often without data
MAX_FAILURES = 5               # this many failures within FAILURE_WINDOW_S stop the engine
FAILURE_WINDOW_S = 10.0
# commands that change a replay's set-up (the index is built again for it)


class Engine:
    """Run a source through the estimators in a background thread.

    source: any :class:`app.stream.sources.Source`; settings: ekf.EKFSettings (None: default
    preset); estimator: name from ekf.ESTIMATORS; comparisons: run the 7 EKF sensor
    combinations too; recorder: an :class:`app.stream.recorder.Recorder` that gets every received
    known-tag line from the start; estimates: an :class:`~app.engine.estimates.EstimatesWriter`
    that gets every estimate row (the recording's estimates.csv); record_rows: keep every
    estimate row in :attr:`rows_log` (tests/benchmarks: unbounded memory); limits: the physical
    bounds a sample must respect (others are damaged lines); session: the session.json of a
    replayed recording (default: found beside the replayed raw.txt); index: build a replay's
    index (checkpoints, whole-session plots) in the background; user_filter: a user's filter
    file run beside the main estimator (YOURS, :mod:`app.engine.userfilter.host`); forwarder: a
    :class:`~app.stream.forwarder.LineForwarder` that gets a copy of every line from the phone.
    """

    def __init__(self, source: Source, settings: ekf.EKFSettings | None = None,
                 estimator: str = "ekf", comparisons: bool = True,
                 sensors: Iterable[str] = SENSORS, recorder: Recorder | None = None,
                 estimates: EstimatesWriter | None = None, record_rows: bool = False,
                 max_plot_rows: int = 60_000,
                 orderer_options: dict[str, Any] | None = None,
                 limits: Limits = DEFAULT_LIMITS, session: SessionInfo | None = None,
                 index: bool = True, user_filter: str | Path | None = None,
                 forwarder: LineForwarder | None = None) -> None:
        if estimator not in ekf.ESTIMATORS and not is_filter_file(estimator):
            raise ValueError(f"unknown estimator {estimator!r}; choose from "
                             f"{', '.join(ekf.ESTIMATORS)}")
        self.source = source
        self.record_rows = record_rows
        self.limits = limits
        self.rows_log: list[Rows] = []
        self._recording_reported = False
        self._orderer_options = dict(orderer_options or {})
        self._runner = EstimatorRunner(estimator, settings, sensors, comparisons,
                                       collect_plot=True)
        self.pipeline = Pipeline(self._runner, limits, self._orderer_options,
                                 on_cut=self._on_cut, on_event=self._record_event)
        self.pipeline.on_parsed = self._on_parsed
        self.recording: SessionRecording | None = None
        self.last_recording: Path | None = None
        self._initial_recording = (recorder, estimates)
        self._markers = Markers()
        self.preparing = False           # compiling or loading the kernels (start)
        self._replay: ReplayManager | None = None
        self._session = session if session is not None else session_for_source(source)
        self._index = bool(index)
        self._commands: queue.SimpleQueue = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._plot = PlotBuffer(max_plot_rows)
        self._seq = 0
        self._polled_seq = -1
        self._latest = Snapshot()
        self._connection_state = "waiting"
        self._peer: str | None = None
        self._health = HealthTracker()
        self._last_publish = 0.0
        self._backlog: list[Chunk | SourceEvent] = []   # read but not yet processed
        # (chunk arrival time, orderer sequence after it): a chunk's estimates are out once
        # the orderer holds nothing pushed up to that sequence
        self._pending_host_times: deque[tuple[float, int]] = deque(maxlen=100_000)
        # chunk arrival -> the estimates of all its samples published (time held for reordering
        # included)
        self.latencies_s: deque[float] = deque(maxlen=200_000)
        self.latency_arrivals_s: deque[float] = deque(maxlen=200_000)   # their chunks' t_host
        self.failures: deque[EngineFailure] = deque(maxlen=20)   # the latest, oldest first
        self.failure_count = 0
        self.stopped_by_failure = False
        self._failure_times: deque[float] = deque(maxlen=MAX_FAILURES)
        # monotonic time since which the source has had nothing for the engine (None: busy)
        self.waiting_since: float | None = None
        self._other_samples = 0
        self._applied = 0                    # commands applied so far
        self._marks: list[threading.Event] = []   # wait_idle's, set at the next publish
        self._seek: tuple[int, int] | None = None   # a seek's target and start line
        # seeks done: (perf_counter when the state reached the target, lines replayed)
        self.seeks: deque[tuple[float, int]] = deque(maxlen=1000)
        if recorder is not None:
            self._attach_recording(SessionRecording(recorder.directory, self._runner,
                                                    recorder=recorder, estimates=estimates,
                                                    source=source.kind))
        elif estimates is not None:
            raise ValueError("estimates.csv belongs to a recording: give its recorder too")
        self.forwarder = forwarder
        self._user = UserFilterHost(self._runner, source, record=self._record_event,
                                    position=lambda: self.pipeline.fed)
        if user_filter is not None:
            self._user.load(user_filter)

    # -- compatibility ---------------------------------------------------------------------------

    @property
    def _parser(self) -> fastparse.FastLineParser:
        return self.pipeline.parser

    @property
    def recorder(self) -> Recorder | None:
        return self.recording.recorder if self.recording is not None else None

    @property
    def estimates(self) -> EstimatesWriter | None:
        return self.recording.estimates if self.recording is not None else None

    @property
    def samples_processed(self) -> int:
        """Samples through the estimators (and other tags' samples) so far."""
        return self.pipeline.fed_total + self._other_samples

    # -- lifecycle --------------------------------------------------------------------------------

    def start(self) -> None:
        """Start the source (may raise OSError/LogError, e.g. port taken) and the thread."""
        if self._thread is not None:
            return
        self.preparing = True       # the thread compiles (or loads) the kernels first
        self.source.start()
        if self.forwarder is not None:
            self.forwarder.start()
        self._thread = threading.Thread(target=self._run, name="engine", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread, the source, the index, the recording. Idempotent.

        The row of the latest time is committed first, so a recording's estimates.csv ends
        where `orientation-lab filter` on its raw.txt ends."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
            self._thread = None
        self.source.stop()
        self._user.stop()
        if self.forwarder is not None:
            self.forwarder.stop()
        if self._replay is not None:
            self._replay.stop()
        if self.recording is not None:
            try:
                self.pipeline.end_of_stream(partial_line_damaged=False)
                self._take_output()
            except Exception as error:   # the thread is gone: nothing else would report it
                self._on_failure(error)
            self._close_recording()

    def __enter__(self) -> Engine:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # -- GUI side -----------------------------------------------------------------------------------

    def send(self, command: Any) -> None:
        """Queue a command (app.engine.commands); applied between two batches, in order."""
        self._commands.put(command)

    def poll(self) -> Snapshot | None:
        """The latest state and the plot samples since the previous poll, or None when nothing
        changed. Non-blocking (a short lock), thread-safe."""
        with self._lock:
            if self._seq == self._polled_seq:
                return None
            self._polled_seq = self._seq
            return self._copy_latest(self._plot.take())

    def snapshot_now(self) -> Snapshot:
        """The latest state, always (for tests): unlike poll() it leaves the plot samples and
        the "changed" mark for the next poll (its plot is empty)."""
        with self._lock:
            return self._copy_latest(PlotChunk())

    def _copy_latest(self, plot: PlotChunk) -> Snapshot:
        return dataclasses.replace(self._latest, seq=self._seq, plot=plot)

    def wait_idle(self, timeout: float = 30.0) -> bool:
        """Tests: wait until every command sent has been applied and the source has had
        nothing more for a moment."""
        deadline = time.monotonic() + timeout
        marker = threading.Event()
        self.send(Mark(marker))
        if not marker.wait(timeout):
            return False
        while time.monotonic() < deadline:
            since = self.waiting_since
            if since is not None and time.monotonic() - since > 0.1 and not self._backlog:
                return True
            time.sleep(0.01)
        return False

    # -- engine thread ----------------------------------------------------------------------------

    def _prepare(self) -> None:
        """Before the first sample: compile the kernels (the first start) or load them from
        numba's cache, saying so in the snapshots, then start a paced replay's clock, so the
        demo or a log begins at its start instead of where its clock ran to meanwhile."""
        self._publish(time.perf_counter())
        try:
            warm_up()
        finally:
            self.preparing = False
        ready = getattr(self.source, "ready", None)     # (a source of a test may lack it)
        if ready is not None:
            ready()

    def _run(self) -> None:
        try:
            self._prepare()
        except Exception as error:
            self._on_failure(error)
        while not self._stop.is_set():
            try:
                self._pass()
            except Exception as error:
                if self._on_failure(error):
                    self._stop_after_failures()
                    return

    def _pass(self) -> None:
        """Read what the source has, process it (at most MAX_BYTES_PER_PASS of chunks, the rest
        waits in the backlog) and publish (at once after a command)."""
        applied = self._applied
        self._apply_commands()
        self._user.tick()
        if self._replay is not None and self._replay.poll():
            self._resync()
        if self._backlog:
            items, self._backlog = self._backlog, []
        else:
            items = self.source.read(0.02)
        if items:
            self.waiting_since = None
        elif self.waiting_since is None:
            self.waiting_since = time.monotonic()
        changed = self._process(items) or self._applied != applied
        now = time.perf_counter()
        if changed or now - self._last_publish >= PUBLISH_IDLE_S:
            self._publish(now)
        if self.recording is not None:
            self.recording.tick()
            self._check_recording()

    def _process(self, items: list[Chunk | SourceEvent]) -> bool:
        changed = False
        chunks: list[Chunk] = []
        size = 0
        for index, item in enumerate(items):
            if isinstance(item, Chunk):
                chunks.append(item)
                size += len(item.data)
                if size < MAX_BYTES_PER_PASS:
                    continue
                # Enough for one pass: publish, then go on with the rest (bounded work and
                # rows between publishes, commands between passes).
                self._backlog = items[index + 1:]
                break
            if chunks:
                if self._apply_commands():
                    return True            # a seek dropped what was read
                self._on_chunks(chunks)
                chunks = []
            if self._apply_commands():
                return True
            self._on_event(item)
            changed = True
        if chunks:
            if self._apply_commands():
                return True
            self._on_chunks(chunks)
            changed = True
        return changed

    def _check_recording(self) -> None:
        """A recording that stopped (write error, size or free-space limit) is reported once;
        its estimates.csv stops with it (the session ends there)."""
        recording = self.recording
        if recording is None or recording.error is None or self._recording_reported:
            return
        self._recording_reported = True
        log.error("recording stopped: %s", recording.error)
        self._health.warn("recording", f"recording stopped: {recording.error} (the stream and "
                                       "the estimates go on)", force=True)
        if recording.estimates is not None:
            recording.estimates.close()
            recording.estimates = None

    def _on_failure(self, error: BaseException) -> bool:
        """Log and publish a failure; True when there were too many to go on."""
        frames = traceback.extract_tb(error.__traceback__)
        where = ""
        if frames:
            last = frames[-1]
            where = f" ({Path(last.filename).name}, line {last.lineno}, in {last.name})"
        message = f"{type(error).__name__}: {error}{where}"
        details = "".join(traceback.format_exception(type(error), error, error.__traceback__))
        now = time.monotonic()
        self._failure_times.append(now)
        fatal = (len(self._failure_times) == MAX_FAILURES
                 and now - self._failure_times[0] <= FAILURE_WINDOW_S)
        self.failure_count += 1
        failure = EngineFailure(self.failure_count, message, details,
                                datetime.now(timezone.utc).isoformat(timespec="seconds"), fatal)
        self.failures.append(failure)
        log.error("engine failure %d%s: %s\n%s", failure.number,
                  " (engine stopped)" if fatal else " (going on with the next batch)",
                  message, details)
        self._health.warn("failure", f"engine error: {message}", force=True)
        try:
            self._publish(time.perf_counter())
        except Exception:   # the failure may be in publishing itself: it is logged above
            with self._lock:
                self._latest.failures = list(self.failures)
                self._seq += 1
        return fatal

    def _stop_after_failures(self) -> None:
        self.stopped_by_failure = True
        self._connection_state = "stopped"
        try:
            self.source.stop()
        except Exception as error:   # noqa: BLE001 (reported, then nothing more to do)
            log.error("stopping the source after failures: %r", error)
        with self._lock:
            health = self._latest.health
            health.connection_state = "stopped"
            self._latest.failures = list(self.failures)
            self._seq += 1

    def _on_parsed(self, parsed: ParsedArrays) -> None:
        self._health.track(parsed)
        self._other_samples += len(parsed.other)   # other tags pass the orderer untouched

    def _on_chunks(self, chunks: list[Chunk]) -> None:
        """Consecutive chunks of one stream, parsed and filtered as one."""
        pipeline = self.pipeline
        parser = pipeline.parser
        damaged_before = parser.stats.damaged + parser.stats.too_long
        data = chunks[0].data if len(chunks) == 1 else b"".join(c.data for c in chunks)
        if self.forwarder is not None and self.source.kind == "tcp":
            for chunk in chunks:
                self.forwarder.feed(chunk.data, chunk.connection)
        pipeline.feed_bytes(data)
        if self._seek is not None and getattr(self._replay_source(), "_index", -1) \
                >= self._seek[0] and not self._backlog:
            self._seek_done()
        sequence = pipeline.orderer.sequence
        for chunk in chunks:
            self._pending_host_times.append((chunk.t_host, sequence))
        if parser.stats.damaged + parser.stats.too_long > damaged_before:
            message = parser.stats.bad_examples[-1][2] if parser.stats.bad_examples else ""
            self._health.warn("damaged", f"damaged line skipped ({message})")

    # -- events ------------------------------------------------------------------------------------

    def _replay_source(self) -> LineReplaySource | None:
        """The replay being played (the demo until a phone takes over), else None."""
        source = self.source
        if isinstance(source, DemoOrPhoneSource):
            source = None if source.phone_active else source.demo
        return source if isinstance(source, LineReplaySource) else None

    def _on_event(self, event: SourceEvent) -> None:
        kind = event.kind
        pipeline = self.pipeline
        replay = self._replay_source()
        if kind in ("connected", "loop", "seek"):
            pipeline.end_of_stream(partial_line_damaged=kind == "connected")
            pipeline.cut()
        if kind == "connected":
            if replay is not None:
                self._begin_pass(replay)
                if getattr(replay, "torn_lines", 0):
                    pipeline.parser._count_bad("damaged", "torn last line (the recording was "
                                               "cut off)", "torn last line")
            else:
                self._replay_off()
                pipeline.restart()
            self._connection_state = "replaying" if self.source.kind != "tcp" else "connected"
            self._peer = event.peer
            self._record_event("connected", peer=event.peer)
            self._user.on_restart(kind)
            if self.recording is not None and self.source.kind == "tcp":
                self.recording.set_peer(event.peer)
        elif kind == "disconnected":
            pipeline.end_of_stream(partial_line_damaged=True)
            self._connection_state = "disconnected"
            self._health.warn("disconnected", f"phone disconnected ({event.detail})")
            self._record_event("disconnected", peer=event.peer, reason=event.detail)
        elif kind in ("loop", "seek"):
            # Every pass of a replay starts from the same state: each loop shows the same
            # estimates, and a source's own seek re-runs its lines from the start.
            if replay is not None:
                self._begin_pass(replay)
            else:
                pipeline.restart(continue_time=kind == "loop")
            self._user.on_restart(kind)
        elif kind == "finished":
            pipeline.end_of_stream(partial_line_damaged=False)
            self._connection_state = "finished"
        elif kind == "error":
            self._health.warn("error", event.detail, force=True)
        elif kind == "closed":
            self._health.warn("closed", event.detail)

    def _begin_pass(self, source: LineReplaySource) -> None:
        manager = self._replay
        if manager is None or manager.source is not source:
            if manager is not None:
                manager.stop()
            session = self._session if self._session_matches(source) else None
            manager = self._replay = ReplayManager(
                source, session, {"limits": self.limits, "orderer_options": self._orderer_options},
                index=self._index)
            self._markers.replace(manager.markers)
        manager.apply(self.pipeline, manager.begin(self.pipeline))
        self._pending_host_times.clear()

    def _session_matches(self, source: LineReplaySource) -> bool:
        session = self._session
        path = getattr(source, "path", None)
        return session is not None and path is not None and \
            Path(session.path).parent == Path(path).parent

    def _replay_off(self) -> None:
        """A phone took over from the demo: no replay any more."""
        if self._replay is not None:
            self._replay.stop()
            self._replay = None
            self._markers.replace([])

    def _seek_line(self, target: int) -> bool:
        """Go to line `target` of the replay: restore the latest checkpoint before it, replay
        the lines from there (at most a second of them once indexed). False: not a replay."""
        source, manager = self._replay_source(), self._replay
        if source is None or manager is None:
            return False
        target = max(0, min(int(target), source.line_count))
        checkpoint = manager.checkpoint_before(target)
        self._backlog = []                       # read at the old position: not wanted
        self._pending_host_times.clear()
        self.pipeline.cut()
        manager.apply(self.pipeline, checkpoint)
        source.jump(checkpoint.line, target)
        self._user.on_seek()              # YOURS re-runs the log up to here in the background
        self._connection_state = "replaying"
        self._seek = (target, checkpoint.line)
        # the lines replayed up to the target were not watched: a recording skips them
        self.pipeline.set_raw_sinks(None, None)
        if checkpoint.line >= target:
            self._seek_done()
        return True

    def _seek_done(self) -> None:
        """A seek reached its target: (when, lines replayed) for the benchmarks."""
        target, start = self._seek
        self.seeks.append((time.perf_counter(), target - start))
        rows, piece = self.pipeline.take_output()   # the re-sync: plotted, not recorded
        self._distribute(rows)
        self._seek = None
        with self._lock:
            self._plot.add(piece)
        if self.recording is not None and self.recording.active:
            recorder = self.recording.recorder
            self.pipeline.set_raw_sinks(recorder.write_line, recorder.write_block)

    def _resync(self) -> None:
        """The index of a changed set-up is ready: be where it says at the current line."""
        source = self._replay_source()
        if source is not None:
            self._seek_line(source.line_index)

    # -- commands ------------------------------------------------------------------------------

    def _apply_commands(self) -> bool:
        """Apply the queued commands; True when one of them moved a replay (a seek: what was
        read before is dropped)."""
        moved = False
        while True:
            try:
                command = self._commands.get_nowait()
            except queue.Empty:
                return moved
            self._applied += 1
            moved = self._apply(command) or moved

    def _apply(self, command: Any) -> bool:
        """One command through the command table; True when it moved a replay."""
        handler = handler_of(command)
        if handler is None:
            self._health.warn("command", f"unknown command {command!r}", force=True)
            return False
        return bool(handler(self, command))

    def _setup_changed(self) -> bool:
        """Replaying: the user chose another set-up (index again, re-sync once indexed). While
        a recording runs it applies from now on, as on a live stream, so the recording replays
        exactly what was shown; the whole replay follows once the recording stops."""
        manager = self._replay
        if manager is None or self._replay_source() is None:
            return False
        if self.recording is not None and self.recording.active:
            self._setup_deferred = True
            return False
        if manager.changed(self.pipeline):
            self._health.warn("timeline", "recorded timeline off: your choices apply to the "
                                          "whole replay (re-computing it)", force=True)
        return False

    def _set_follow(self, enabled: bool) -> bool:
        manager = self._replay
        if manager is None or manager.session is None:
            self._health.warn("timeline", "only a recorded session has a timeline to follow",
                              force=True)
            return False
        manager.set_follow(self.pipeline, enabled)
        self._health.warn("timeline", "following the recorded timeline" if manager.follow
                          else "recorded timeline off: your choices apply to the whole replay",
                          force=True)
        return False

    def _replay_control(self, command: ReplayControl) -> bool:
        source = self._replay_source()
        if source is None or self._replay is None:
            self.source.control(command)
            return False
        target = command.seek_line
        if command.seek_s is not None:
            target = source.line_at(command.seek_s)
        step = command.step or 0
        if step < 0:
            target = max(0, source.line_index + step)
        rest = dataclasses.replace(command, seek_s=None, seek_line=None,
                                   step=step if step > 0 else None)
        moved = target is not None and self._seek_line(target)
        source.control(rest)
        return moved

    # -- recording -------------------------------------------------------------------------------

    def _attach_recording(self, recording: SessionRecording) -> None:
        self.recording = recording
        self._recording_reported = False
        recorder = recording.recorder
        self.pipeline.set_raw_sinks(recorder.write_line, recorder.write_block)
        self.last_recording = recording.folder

    def _start_recording(self, command: StartRecording) -> None:
        if self.recording is not None and self.recording.active:
            self._health.warn("recording", f"already recording into {self.recording.folder}",
                              force=True)
            return
        folder = Path(command.folder) if command.folder else None
        try:
            folder = new_session_folder(folder or default_session_folder())
            max_bytes = DEFAULT_MAX_BYTES if command.max_mb is None else megabytes(command.max_mb)
            min_free = DEFAULT_MIN_FREE_BYTES if command.min_free_mb is None \
                else megabytes(command.min_free_mb)
            pipeline = self.pipeline
            running = pipeline.fed_total > 0 or pipeline.orderer.pending > 0
            # the rows so far belong to before the recording
            self._flush_output()
            recording = SessionRecording(
                folder, self._runner, fed_at_start=pipeline.fed_total,
                start_state=pipeline.start_state() if running else None,
                source=self.source.kind, peer=self._peer if self.source.kind == "tcp" else None,
                max_bytes=max_bytes, min_free_bytes=min_free)
        except (ConfigError, OSError) as error:
            self._health.warn("recording", f"cannot record: {error}", force=True)
            self._last_recording_status = {"folder": str(folder or ""), "elapsed_s": 0.0,
                                           "bytes": 0, "lines": 0, "error": f"cannot record: "
                                           f"{error}", "active": False, "at": time.time()}
            return
        self._attach_recording(recording)
        self._record_event("recording", folder=str(folder))
        self._health.warn("recording", f"recording into {folder}", force=True)

    def _stop_recording(self) -> None:
        if self.recording is None or not self.recording.active:
            self._health.warn("recording", "not recording", force=True)
            return
        folder = self.recording.folder
        self._flush_output()         # the rows up to now go into estimates.csv
        self._close_recording()
        self._health.warn("recording", f"recording saved in {folder}", force=True)
        if self._setup_deferred:
            self._setup_deferred = False
            self._setup_changed()

    def _close_recording(self) -> None:
        recording, self.recording = self.recording, None
        self.pipeline.set_raw_sinks(None, None)
        if recording is not None:
            self._last_recording_status = {**recording.status(), "active": False}
            recording.close(stats_dict(self._latest.health))

    _last_recording_status: dict[str, Any] | None = None
    _setup_deferred = False      # a set-up change during a recording of a replay

    def _set_forward(self, target: str | None) -> None:
        """SetForward: stop the running forward (if any), start one to target (if given)."""
        self.forwarder, line, changed = switch_forward(self.forwarder, target,
                                                       self.source.kind == "tcp")
        self._health.warn("forward", line, force=True)
        if changed:
            self._record_event("forward", target=None if self.forwarder is None else
                               f"{self.forwarder.host}:{self.forwarder.port}")

    def _record_event(self, kind: str, **data: Any) -> None:
        if self.recording is not None and self.recording.active:
            self.recording.add_event(kind, self._runner.latest_t_ms, self.pipeline.fed_total,
                                     **data)

    # -- markers ---------------------------------------------------------------------------------

    def _add_marker(self, label: str) -> None:
        replay = self._replay if self._replay_source() is not None else None
        note = self._markers.add(label, self._runner.latest_t_ms, self.pipeline.t0_ms,
                                 self.recording, replay, self.pipeline.fed_total)
        self._health.warn("marker", note, force=True)

    def _set_marker_label(self, number: int, label: str) -> None:
        replay = self._replay if self._replay_source() is not None else None
        note = self._markers.set_label(number, label, self.recording, replay)
        if note and "(" in note:
            self._health.warn("markers", note.strip(" ()"), force=True)

    # -- output ----------------------------------------------------------------------------------

    def _on_cut(self, rows: Rows, piece: PlotChunk) -> None:
        """A session's output with its own time origin (pipeline.cut)."""
        self._distribute(rows)
        with self._lock:
            self._plot.add(piece)

    def _distribute(self, rows: Rows) -> None:
        if self.record_rows and len(rows):
            self.rows_log.append(rows)
        warning = None
        if self._seek is not None:
            pass            # a seek's re-sync: the rows up to its target were not shown
        elif self.recording is not None:
            warning = self.recording.write_rows(rows)
        if warning:
            self._health.warn("estimates", warning, force=True)

    def _flush_output(self) -> None:
        """The output so far to its consumers now (rows, and the plots at the next poll)."""
        piece = self._take_output()
        with self._lock:
            self._plot.add(piece)

    def _take_output(self) -> PlotChunk:
        """The rows since the last call to their consumers (rows_log, estimates.csv); the plot
        samples as a PlotChunk in the current session's time."""
        rows, piece = self.pipeline.take_output()
        recording = self.recording
        if recording is not None and recording.active and recording.t0_ms is None:
            recording.t0_ms = self.pipeline.piece_first_ms   # as a replay of it will count
        self._distribute(rows)
        return piece

    def _publish(self, now: float) -> None:
        """Hand the rows and plot samples since the last publish to their consumers and make a
        new snapshot the latest."""
        runner = self._runner
        piece = self._take_output()
        main = runner.main
        cov = main.cov
        info = self.source.info()
        phone = runner.phone_quat
        replay = info.get("replay")
        manager = self._replay if self._replay_source() is not None else None
        if replay is not None and manager is not None:
            replay = {**replay, **manager.info()}
        comparisons = [Comparison(c.name, c.estimator.quat, tuple(c.errors.rmse().tolist()),
                                  tuple(c.errors.latest.tolist()), c.errors.count)
                       for c in runner.comparisons]
        yours = self._user.comparison_row()
        if yours is not None:
            comparisons.append(yours)
        snapshot = Snapshot(
            t_ms=runner.latest_t_ms, own_quat=main.quat,
            own_cov=None if cov is None else np.array(cov)[:4, :4],
            phone_quat=None if phone is None else np.array(phone),
            status=self._filter_status(), comparisons=comparisons,
            comparison_estimator=runner.comparison_estimator, t0_ms=self.pipeline.t0_ms,
            health=self._stream_health(now, info), replay=replay,
            failures=list(self.failures), markers=tuple(self._markers.items),
            preparing=self.preparing,
            user=self._user.status(),
            recording=self.recording.status() if self.recording is not None
            else self._last_recording_status,
            session_plot=manager.plot if manager is not None else None,
            session_samples=runner.session_samples)
        published = time.perf_counter()
        with self._lock:
            self._plot.add(piece)
            self._latest = snapshot
            self._seq += 1
            snapshot.seq = self._seq
        pending = self._pending_host_times
        if pending:
            oldest = self.pipeline.orderer.oldest_pending_sequence
            while pending and pending[0][1] < oldest:
                t_host = pending.popleft()[0]
                self.latencies_s.append(published - t_host)
                self.latency_arrivals_s.append(t_host)
        self._last_publish = now
        for mark in self._marks:
            mark.set()
        self._marks = []
        if self.recording is not None and self.recording.active:
            self.recording.recorder.set_stats(stats_dict(snapshot.health))

    def _filter_status(self) -> FilterStatus:
        main = self._runner.main
        return FilterStatus(sensors_enabled=main.enabled, flags=main.flags,
                            diagnostics=main.diagnostics, estimator=self._runner.estimator_name,
                            initialised=main.initialised, settings=self._runner.settings)

    def _stream_health(self, now: float, info: dict[str, Any]) -> StreamHealth:
        state = info.get("connection_state", "waiting")
        if self.source.kind == "tcp":
            state = self._connection_state if state != "waiting" else "waiting"
        health = self._health.health(now, info, self.pipeline.parser, self.pipeline.orderer,
                                     self.pipeline.order_retired, state, self._peer,
                                     self._recording_text())
        if self.forwarder is not None:
            health.forward = self.forwarder.status()
        return health

    def _recording_text(self) -> str | None:
        recording = self.recording
        if recording is None:
            if self._last_recording_status and self._last_recording_status.get("error"):
                return f"recording stopped: {self._last_recording_status['error']}"
            return None
        if recording.error is not None:
            return f"recording stopped: {recording.error}"
        return (f"recording into {recording.folder} "
                f"({recording.recorder.bytes_written / 2**20:.1f} MB)")
