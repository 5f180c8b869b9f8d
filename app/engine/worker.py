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
where; the estimators start afresh, nothing of an earlier connection carries over).

:class:`Engine` coordinates parts that live in modules of their own: the processing
(:mod:`~app.engine.pipeline`), the output and the snapshots (:mod:`~app.engine.publisher`),
failures (:mod:`~app.engine.failures`), replays and seeks (:mod:`~app.engine.replay_lane`),
recordings (:mod:`~app.engine.recording_lane`), your filter (:mod:`~app.engine.userfilter.host`),
markers, the stream's health; the commands' handlers are in :mod:`~app.engine.command_table`.

The engine thread works chunk by chunk: everything the source has is parsed in one compiled call
(:class:`~app.stream.fastparse.FastLineParser`), ordered in one (:class:`~app.stream.ordering.TimeOrderer`)
and run through each estimator in one (:meth:`~app.engine.runner.EstimatorRunner.feed_arrays`); the
kernels release the GIL, so the GUI thread keeps running while the engine computes.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import ekf
from app.engine.command_table import Mark, handler_of
from app.engine.configuration import Change, Config, Configuration
from app.engine.estimates import EstimatesWriter
from app.engine.failures import FailureLog
from app.engine.forwarding import Forward
from app.engine.health import HealthTracker
from app.engine.markers import Markers
from app.engine.parts import Connection, EngineParts, engine_snapshot
from app.engine.pipeline import Pipeline
from app.engine.publisher import Output, Publisher
from app.engine.recording import SessionRecording
from app.engine.recording_lane import RecordingLane
from app.engine.replay import session_for_source
from app.engine.replay_lane import ReplayLane
from app.engine.runner import SENSORS, EstimatorRunner, Rows
from app.engine.session import SessionInfo
from app.engine.snapshot import EngineFailure, Snapshot
from app.engine.userfilter.code import is_filter_file
from app.engine.userfilter.host import UserFilterHost
from app.engine.warmup import warm_up
from app.stream.events import Chunk, SourceEvent
from app.stream.fastparse import ParsedArrays
from app.stream.forwarder import LineForwarder
from app.stream.protocol import DEFAULT_LIMITS, Limits
from app.stream.recorder import Recorder
from app.stream.sources import Source

log = logging.getLogger("orientation_lab.engine")

MAX_BYTES_PER_PASS = 1 << 20    # received bytes processed between two publishes (~25k lines)
PUBLISH_IDLE_S = 0.25          # publish health at least this often without data


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

    The estimator, sensors, settings and comparisons given here are the engine's own set-up:
    where a replayed recording has its own, the recording's applies
    (:mod:`app.engine.configuration`).
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
        if recorder is None and estimates is not None:
            raise ValueError("estimates.csv belongs to a recording: give its recorder too")
        self.source = source
        self.limits = limits
        runner = EstimatorRunner(estimator, settings, sensors, comparisons, collect_plot=True)
        self.pipeline = Pipeline(runner, limits, dict(orderer_options or {}),
                                 on_cut=self._on_cut, on_event=self._on_session_event,
                                 on_parsed=self._on_parsed, on_applied=self._on_applied)
        session = session if session is not None else session_for_source(source)
        replayed = source.played()
        path = getattr(replayed, "path", None)
        self.configuration = Configuration(Config.of(runner), session,
                                           replaying=replayed is not None,
                                           path=None if path is None else str(path))
        self._health = HealthTracker()
        self.publisher = Publisher(max_plot_rows)
        self._failures = FailureLog()
        self.failures: deque[EngineFailure] = self._failures.items   # the latest, oldest first
        self.stopped_by_failure = False
        self.markers = Markers()
        self.recording_lane = RecordingLane(self.pipeline, self._health)
        self.output = Output(self.pipeline, self.publisher, self.recording_lane, record_rows)
        self.rows_log: list[Rows] = self.output.rows_log      # record_rows: every row
        self._user = UserFilterHost(runner, source, record=self.recording_lane.event,
                                    position=lambda: self.pipeline.fed,
                                    setup=self.configuration.setup)
        self.replay_lane = ReplayLane(source, self.pipeline, self.configuration, session,
                                      self.markers, self.recording_lane, _ReplayEvents(self),
                                      index)
        self.seeks = self.replay_lane.seeks
        self.latencies_s = self.publisher.latencies_s
        self.latency_arrivals_s = self.publisher.latency_arrivals_s
        self.preparing = False           # compiling or loading the kernels (start)
        self._commands: queue.SimpleQueue = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._connection = Connection()
        self._forward = Forward(forwarder)
        self._parts = EngineParts(source, self.pipeline, self.configuration, self.replay_lane,
                                  self.recording_lane, self.markers, self._user, self._health,
                                  self.publisher, self.output, self._connection,
                                  self._forward, self._failures)
        self._backlog: list[Chunk | SourceEvent] = []   # read but not yet processed
        # monotonic time since which the source has had nothing for the engine (None: busy)
        self.waiting_since: float | None = None
        self._other_samples = 0
        self._applied = 0                    # commands applied so far
        if recorder is not None:
            self.recording_lane.attach(SessionRecording(
                recorder.directory, runner, recorder=recorder, estimates=estimates,
                source=source.kind))
        if user_filter is not None:
            self._user.load(user_filter)

    # -- the parts' state, as attributes of the engine -------------------------------------------

    @property
    def runner(self) -> EstimatorRunner:
        """The estimators (the pipeline's runner)."""
        return self.pipeline.runner

    @property
    def forwarder(self) -> LineForwarder | None:
        """The forward of the phone's lines running now (None: none)."""
        return self._forward.current

    @property
    def recording(self) -> SessionRecording | None:
        """The recording in progress (None: not recording)."""
        return self.recording_lane.current

    @property
    def last_recording(self) -> Path | None:
        """The folder of the latest recording (in progress or done)."""
        return self.recording_lane.last_folder

    @property
    def failure_count(self) -> int:
        return self._failures.count

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
        self.replay_lane.stop()
        if self.recording is not None:
            try:
                self.pipeline.end_of_stream(partial_line_damaged=False)
                self.output.take()
            except Exception as error:   # the thread is gone: nothing else would report it
                self._on_failure(error)
            self.recording_lane.close(self.publisher.latest.health)

    def __enter__(self) -> Engine:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # -- GUI side --------------------------------------------------------------------------------

    def send(self, command: Any) -> None:
        """Queue a command (app.engine.commands); applied between two batches, in order."""
        self._commands.put(command)

    def poll(self) -> Snapshot | None:
        """The latest state and the plot samples since the previous poll, or None when nothing
        changed. Non-blocking (a short lock), thread-safe."""
        return self.publisher.poll()

    def snapshot_now(self) -> Snapshot:
        """The latest state, always (for tests): unlike poll() it leaves the plot samples and
        the "changed" mark for the next poll (its plot is empty)."""
        return self.publisher.snapshot_now()

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
        if self._applied != applied:
            self.waiting_since = None        # idle counts from after the latest command
        self._user.tick()
        self.replay_lane.tick()
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
        if changed or now - self.publisher.last_publish >= PUBLISH_IDLE_S:
            self._publish(now)
        self.recording_lane.tick()

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

    def _on_failure(self, error: BaseException) -> bool:
        """Log and publish a failure; True when there were too many to go on."""
        failure = self._failures.record(error)
        self._health.warn("failure", f"engine error: {failure.message}", force=True)
        try:
            self._publish(time.perf_counter())
        except Exception:   # the failure may be in publishing itself: it is logged
            self.publisher.amend(list(self.failures))
        return failure.fatal

    def _stop_after_failures(self) -> None:
        self.stopped_by_failure = True
        self._connection.state = "stopped"
        try:
            self.source.stop()
        except Exception as error:   # noqa: BLE001 (reported, then nothing more to do)
            log.error("stopping the source after failures: %r", error)
        self.publisher.amend(list(self.failures), stopped=True)

    def _on_parsed(self, parsed: ParsedArrays) -> None:
        self._health.track(parsed)
        self._other_samples += len(parsed.other)   # other tags pass the orderer untouched

    def _on_chunks(self, chunks: list[Chunk]) -> None:
        """Consecutive chunks of one stream, parsed and filtered as one."""
        pipeline = self.pipeline
        parser = pipeline.parser
        damaged_before = parser.stats.damaged + parser.stats.too_long
        data = chunks[0].data if len(chunks) == 1 else b"".join(c.data for c in chunks)
        forwarder = self.forwarder
        if forwarder is not None and self.source.capabilities.forward:
            for chunk in chunks:
                forwarder.feed(chunk.data, chunk.connection)
        pipeline.feed_bytes(data)
        if not self._backlog:
            self.replay_lane.fed()
        self.publisher.arrived((chunk.t_host for chunk in chunks), pipeline.orderer.sequence)
        if parser.stats.damaged + parser.stats.too_long > damaged_before:
            message = parser.stats.bad_examples[-1][2] if parser.stats.bad_examples else ""
            self._health.warn("damaged", f"damaged line skipped ({message})")

    def _on_event(self, event: SourceEvent) -> None:
        kind = event.kind
        pipeline = self.pipeline
        if kind in ("connected", "loop", "seek"):
            pipeline.end_of_stream(partial_line_damaged=kind == "connected")
            pipeline.cut()
        if kind == "connected":
            self.replay_lane.connected()
            live = self.source.capabilities.reconnect
            self._connection.state = "connected" if live else "replaying"
            self._connection.peer = event.peer
            self.recording_lane.event("connected", peer=event.peer)
            self._user.on_restart(kind)
            if live:
                self.recording_lane.set_peer(event.peer)
        elif kind == "disconnected":
            pipeline.end_of_stream(partial_line_damaged=True)
            self._connection.state = "disconnected"
            self._health.warn("disconnected", f"phone disconnected ({event.detail})")
            self.recording_lane.event("disconnected", peer=event.peer, reason=event.detail)
        elif kind in ("loop", "seek"):
            self.replay_lane.restarted(kind)
            self._user.on_restart(kind)
        elif kind == "finished":
            pipeline.end_of_stream(partial_line_damaged=False)
            self._connection.state = "finished"
        elif kind == "error":
            self._health.warn("error", event.detail, force=True)
        elif kind == "closed":
            self._health.warn("closed", event.detail)

    # -- the pipeline's callbacks ------------------------------------------------------------------

    def _on_cut(self, rows: Rows, piece: Any) -> None:
        self.output.cut(rows, piece)

    def _on_session_event(self, kind: str, **data: Any) -> None:
        self.recording_lane.event(kind, **data)

    def _on_applied(self, change: Change, data: dict[str, Any]) -> None:
        """A change of the configuration applied: the recording keeps it; an alignment says
        what it did."""
        self.recording_lane.applied(change, data)
        if change.kind == "align_heading":
            turned = data.get("turned_deg")
            self._health.warn("align", "align heading: no PHONE orientation (ORI) yet"
                              if turned is None else
                              f"heading aligned with PHONE: OWN turned by {turned:+.1f}° "
                              "about up", force=True)

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
            handler = handler_of(command)
            if handler is None:
                self._health.warn("command", f"unknown command {command!r}", force=True)
            elif handler(self._parts, command):
                moved = True

    # -- snapshots ------------------------------------------------------------------------------

    def _publish(self, now: float) -> None:
        """Hand the rows and plot samples since the last publish to their consumers and make a
        new snapshot the latest."""
        piece = self.output.take()
        snapshot = engine_snapshot(self._parts, now, self.preparing)
        self.publisher.publish(snapshot, piece, self.pipeline.orderer, now, time.perf_counter())
        self.recording_lane.set_stats(snapshot.health)


class _ReplayEvents:
    """The engine's side of its replay lane (app.engine.replay_lane.ReplayEvents)."""

    def __init__(self, engine: Engine) -> None:
        self._engine = engine

    def jumped(self) -> None:
        engine = self._engine
        engine._backlog = []
        engine._connection.state = "replaying"
        engine._user.on_seek()

    def new_pass(self) -> None:
        self._engine.publisher.forget_arrivals()

    def say(self, topic: str, text: str) -> None:
        self._engine._health.warn(topic, text, force=True)
