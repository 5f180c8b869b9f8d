"""The background engine: source -> parser -> time ordering -> estimators -> snapshots, and the
commands it applies.

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
(:mod:`~app.engine.processing.pipeline`), the output and the snapshots
(:mod:`~app.engine.live.publisher`), failures (:mod:`~app.engine.errors`), replays and seeks
(:mod:`~app.engine.sessions.replay`), recordings (:mod:`~app.engine.sessions.recording`), your
filter (:mod:`~app.engine.userfilter.host`), markers, the stream's health.

The engine thread works chunk by chunk: everything the source has is parsed in one compiled call
(:class:`~app.stream.fastparse.FastLineParser`), ordered in one
(:class:`~app.stream.ordering.TimeOrderer`) and run through each estimator in one
(:meth:`~app.engine.processing.runner.EstimatorRunner.feed_arrays`); the kernels release the GIL,
so the GUI thread keeps running while the engine computes.

The command table (:func:`handler_of`): each command type and its handler(parts, command), which
returns True when the command moved a replay (a seek: what was read before is dropped). A
command is looked up along its class's bases, so a subclass is handled as its base. A handler
works on the engine's parts (:class:`~app.engine.live.parts.EngineParts`) and hands its command
to the part it is for: the configuration (set-up changes, through the replay lane, which makes
them overrides or changes at the current sample), the replay lane (seeks, back to the
recording), the recording lane, the markers, your filter's host, the source (connection
commands) or the forward. The set-up commands (a sensor switch, the estimator, the settings, the
comparisons, a reset, a heading alignment) become changes of the configuration
(:class:`~app.engine.processing.configuration.Change`): one maker per command type in
`SETUP_CHANGES`; a maker returns None when it refuses (saying why through `refuse`).

Ending the process on SIGTERM and SIGHUP as on Ctrl-C (:func:`on_finishing_signals`): by
default these signals (`kill`, a service manager; the terminal that started the program was
closed) end a process at once: raw.txt keeps what was flushed, session.json is never finalised.
`serve` and the window ask them to stop instead; they then stop the engine, which closes the
recording (raw.txt flushed, session.json with its stop time and counts, estimates.csv to the
last row).
"""
from __future__ import annotations

import dataclasses
import logging
import queue
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import ekf
from app.engine.commands import (AddMarker, AlignHeading, LoadUserFilter, ReplayControl,
                                 ResetFilter, SetComparisonsEnabled, SetConsistencyEnabled,
                                 SetEstimator, SetFollowTimeline, SetForward, SetMarkerLabel,
                                 SetSensorEnabled, SetSettings, StartRecording, StopRecording,
                                 UnloadUserFilter)
from app.engine.errors import EngineFailure, FailureLog
from app.engine.live.parts import Connection, EngineParts, Forward, engine_snapshot
from app.engine.live.publisher import EngineOutput, Publisher
from app.engine.offline.filtering import EstimatesWriter
from app.engine.processing.configuration import Change, Config, Configuration
from app.engine.processing.health import HealthTracker
from app.engine.processing.pipeline import Pipeline
from app.engine.processing.runner import SENSORS, EstimatorRunner, Rows
from app.engine.sessions.recording import RecordingLane, SessionRecording
from app.engine.sessions.replay import ReplayLane, session_for_source
from app.engine.sessions.session import Markers, SessionInfo
from app.engine.snapshot import Snapshot
from app.engine.userfilter.code import is_filter_file
from app.engine.userfilter.host import UserFilterHost
from app.engine.warmup import warm_up
from app.stream.events import CONNECTION_COMMANDS, Chunk, SourceEvent
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
    known-tag line from the start; estimates: an
    :class:`~app.engine.offline.filtering.EstimatesWriter` that gets every estimate row (the
    recording's estimates.csv); record_rows: keep every estimate row in :attr:`rows_log`
    (tests/benchmarks: unbounded memory); limits: the physical bounds a sample must respect (others
    are damaged lines); session: the session.json of a replayed recording (default: found beside the
    replayed raw.txt); index: build a replay's index (checkpoints, whole-session plots) in the
    background; user_filter: a user's filter file run beside the main estimator (YOURS,
    :mod:`app.engine.userfilter.host`); forwarder: a
    :class:`~app.stream.forwarder.LineForwarder` that gets a copy of every line from the phone.

    The estimator, sensors, settings and comparisons given here are the engine's own set-up:
    where a replayed recording has its own, the recording's applies
    (:mod:`app.engine.processing.configuration`).
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
        self.output = EngineOutput(self.pipeline, self.publisher, self.recording_lane, record_rows)
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
    """The engine's side of its replay lane (app.engine.sessions.replay.ReplayEvents)."""

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


# ---- the commands: set-up changes and the command table -----------------------------------

Refuse = Callable[[str], None]


def _sensor(command: SetSensorEnabled, refuse: Refuse) -> Change | None:
    if command.sensor not in ekf.SENSORS:
        refuse(f"unknown sensor {command.sensor!r}")
        return None
    return Change.of(command.sensor, bool(command.enabled))


def _estimator(command: SetEstimator, refuse: Refuse) -> Change | None:
    if command.name not in ekf.ESTIMATORS:
        refuse(f"unknown estimator {command.name!r}")
        return None
    return Change.of("estimator", command.name)


def _settings(command: SetSettings, refuse: Refuse) -> Change | None:
    if not isinstance(command.settings, ekf.EKFSettings):
        refuse(f"settings: expected filter settings, got {type(command.settings).__name__}")
        return None
    note: list[tuple[str, Any]] = [("source", command.source)] if command.source else []
    if command.calibration is not None:
        note.append(("profile", command.calibration.get("name")))
    return Change(0, "settings", settings=command.settings, note=tuple(note),
                  calibration=command.calibration)


def _comparisons(command: SetComparisonsEnabled, refuse: Refuse) -> Change | None:
    if command.estimator is not None and command.estimator not in ekf.ESTIMATORS:
        refuse(f"unknown estimator {command.estimator!r}")
        return None
    return Change(0, "comparisons", enabled=bool(command.enabled), name=command.estimator)


SETUP_CHANGES: dict[type, Callable[[Any, Refuse], Change | None]] = {
    SetSensorEnabled: _sensor,
    SetEstimator: _estimator,
    SetSettings: _settings,
    SetComparisonsEnabled: _comparisons,
    ResetFilter: lambda command, refuse: Change(0, "reset"),
    AlignHeading: lambda command, refuse: Change(0, "align_heading"),
}
"""Each set-up command type and the change it makes (None: refused)."""


Handler = Callable[[EngineParts, Any], bool]


@dataclasses.dataclass(frozen=True)
class Mark:
    """wait_idle's command: set when the engine reaches it."""

    event: threading.Event


def _setup(parts: EngineParts, command: Any) -> bool:
    """A set-up command: a change of the configuration (refused: nothing changes)."""
    change = SETUP_CHANGES[type(command)](command, lambda text: parts.say("command", text))
    if change is not None:
        parts.replay.change(change)
    return False


def _start_recording(parts: EngineParts, command: StartRecording) -> None:
    live = parts.source.capabilities.reconnect
    parts.recordings.start(command, parts.source.kind, parts.connection.peer if live else None,
                           parts.output.flush)


def _stop_recording(parts: EngineParts, command: StopRecording) -> None:
    parts.recordings.stop(parts.output.flush, parts.publisher.latest.health)


def _add_marker(parts: EngineParts, command: AddMarker) -> None:
    pipeline = parts.pipeline
    note = parts.markers.add(command.label, pipeline.runner.latest_t_ms, pipeline.t0_ms,
                             parts.recordings.current, parts.replay.shown, pipeline.fed_total)
    parts.say("marker", note)


def _set_marker_label(parts: EngineParts, command: SetMarkerLabel) -> None:
    note = parts.markers.set_label(command.id, command.label, parts.recordings.current,
                                   parts.replay.shown)
    if note and "(" in note:
        parts.say("markers", note.strip(" ()"))


def _set_forward(parts: EngineParts, command: SetForward) -> None:
    """Stop the running forward (if any), start one to the command's target (if given)."""
    line, changed = parts.forward.switch(command.target, parts.source.capabilities.forward)
    parts.say("forward", line)
    if changed:
        parts.recordings.event("forward", target=parts.forward.target())


def _never_moves(action: Callable[[EngineParts, Any], None]) -> Handler:
    """The handler of a command that never moves a replay."""
    def handler(parts: EngineParts, command: Any) -> bool:
        action(parts, command)
        return False
    return handler


TABLE: dict[type, Handler] = {
    ReplayControl: lambda parts, command: parts.replay.control(command),
    **{kind: _setup for kind in SETUP_CHANGES},
    StartRecording: _never_moves(_start_recording),
    StopRecording: _never_moves(_stop_recording),
    AddMarker: _never_moves(_add_marker),
    SetMarkerLabel: _never_moves(_set_marker_label),
    SetFollowTimeline: _never_moves(
        lambda parts, command: parts.replay.set_follow(command.enabled)),
    **{kind: _never_moves(lambda parts, command: parts.source.control(command))
       for kind in CONNECTION_COMMANDS},
    LoadUserFilter: _never_moves(lambda parts, command: parts.user.load(command.path)),
    UnloadUserFilter: _never_moves(lambda parts, _: parts.user.unload()),
    SetConsistencyEnabled: _never_moves(
        lambda parts, command: parts.pipeline.runner.set_consistency_enabled(command.enabled)),
    SetForward: _never_moves(_set_forward),
    Mark: _never_moves(lambda parts, command: parts.publisher.add_mark(command.event)),
}


def handler_of(command: Any) -> Handler | None:
    """The handler of `command`'s type or of its nearest base in the table; None if none."""
    for kind in type(command).__mro__:
        handler = TABLE.get(kind)
        if handler is not None:
            return handler
    return None




# ---- ending the process on SIGTERM and SIGHUP as on Ctrl-C -----------------------------------

FINISHING_SIGNALS = ("SIGTERM", "SIGHUP")


def on_finishing_signals(handler: Callable[[], None]) -> Callable[[], None]:
    """From now on SIGTERM and SIGHUP call handler() (in the main thread, between two Python
    steps) instead of ending the process. A signal the process ignores stays ignored (SIGHUP
    under `nohup`); a platform without it (SIGHUP on Windows) is skipped; outside the main
    thread nothing changes. Returns the function that puts the previous handlers back."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = {}
    for name in FINISHING_SIGNALS:
        number = getattr(signal, name, None)
        if number is None or signal.getsignal(number) == signal.SIG_IGN:
            continue
        previous[number] = signal.signal(number, lambda *_: handler())

    def restore() -> None:
        for number, old in previous.items():
            signal.signal(number, old)
    return restore
