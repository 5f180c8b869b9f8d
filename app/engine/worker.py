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

The engine thread works chunk by chunk: everything the source has is parsed in one compiled call
(:class:`~app.stream.fastparse.FastLineParser`), ordered in one (:class:`~app.stream.ordering.TimeOrderer`)
and run through each estimator in one (:meth:`~app.engine.runner.EstimatorRunner.feed_arrays`); the
kernels release the GIL, so the GUI thread keeps running while the engine computes.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import queue
import threading
import time
import traceback
from collections import deque
from datetime import datetime, timezone
from pathlib import Path
from collections.abc import Iterable
from typing import Any

import numpy as np

import ekf
from app.engine.commands import (AlignHeading, LoadUserFilter, ReplayControl, ResetFilter,
                                 SetComparisonsEnabled, SetConsistencyEnabled, SetEstimator,
                                 SetSensorEnabled, SetSettings, UnloadUserFilter)
from app.stream.events import CONNECTION_COMMANDS
from app.engine.estimates import EstimatesWriter
from app.engine.runner import SENSORS, EstimatorRunner, Rows
from app.engine.snapshot import (Comparison, EngineFailure, FilterStatus, PlotChunk, Snapshot,
                                 StreamHealth)
from app.engine.user_code import is_filter_file
from app.engine.user_host import UserFilterHost
from app.stream import fastparse, ordering
from app.stream.events import Chunk, SourceEvent
from app.stream.fastparse import ParsedArrays
from app.stream.forwarder import LineForwarder
from app.stream.ordering import OrderedArrays, TimeOrderer
from app.stream.protocol import DEFAULT_LIMITS, FILTER_TAGS, Limits
from app.stream.recorder import Recorder
from app.stream.sources import Source

log = logging.getLogger("orientation_lab.engine")

RATE_WINDOW_MS = 2000          # per-tag rates are measured over this much phone time
MAX_BYTES_PER_PASS = 1 << 20    # received bytes processed between two publishes (~25k lines)
PUBLISH_IDLE_S = 0.25          # publish health at least this often without data
WARNING_INTERVAL_S = 5.0       # one warning of a kind per this many seconds
MAX_FAILURES = 5               # this many failures within FAILURE_WINDOW_S stop the engine
FAILURE_WINDOW_S = 10.0


class _PlotBuffer:
    """PlotChunk pieces waiting for the next poll, bounded by a number of estimate rows."""

    def __init__(self, max_rows: int) -> None:
        self.max_rows = max_rows
        self.pieces: deque[PlotChunk] = deque()
        self.rows = 0

    def add(self, piece: PlotChunk) -> None:
        self.pieces.append(piece)
        self.rows += max(len(piece.t_est), len(piece.t_acc), len(piece.t_gyr))
        while self.rows > self.max_rows and len(self.pieces) > 1:
            old = self.pieces.popleft()
            self.rows -= max(len(old.t_est), len(old.t_acc), len(old.t_gyr))

    def take(self) -> PlotChunk:
        pieces = list(self.pieces)
        self.pieces.clear()
        self.rows = 0
        if not pieces:
            return PlotChunk()
        if len(pieces) == 1:
            return pieces[0]
        return PlotChunk(**{name: np.concatenate([getattr(p, name) for p in pieces])
                            for name in PlotChunk.__dataclass_fields__})


class Engine:
    """Run a source through the estimators in a background thread.

    source: any :class:`app.stream.sources.Source`; settings: ekf.EKFSettings (None: default
    preset); estimator: name from ekf.ESTIMATORS; comparisons: run the 7 EKF sensor
    combinations too; recorder: an :class:`app.stream.recorder.Recorder` that gets every received
    known-tag line; estimates: an :class:`~app.engine.estimates.EstimatesWriter` that gets every
    estimate row (a recording's estimates.csv); record_rows: keep every estimate row in
    :attr:`rows_log` (tests/benchmarks: unbounded memory); limits: the physical bounds a sample
    must respect (others are damaged lines); user_filter: a user's filter file run beside the
    main estimator (YOURS, :mod:`app.engine.user_host`); forwarder: a
    :class:`~app.stream.forwarder.LineForwarder` that gets a copy of every line from the phone.
    """

    def __init__(self, source: Source, settings: ekf.EKFSettings | None = None,
                 estimator: str = "ekf", comparisons: bool = True,
                 sensors: Iterable[str] = SENSORS, recorder: Recorder | None = None,
                 estimates: EstimatesWriter | None = None, record_rows: bool = False,
                 max_plot_rows: int = 60_000,
                 orderer_options: dict[str, Any] | None = None,
                 limits: Limits = DEFAULT_LIMITS, user_filter: str | Path | None = None,
                 forwarder: LineForwarder | None = None) -> None:
        if estimator not in ekf.ESTIMATORS and not is_filter_file(estimator):
            raise ValueError(f"unknown estimator {estimator!r}; choose from "
                             f"{', '.join(ekf.ESTIMATORS)}")
        self.source = source
        self.recorder = recorder
        self.estimates = estimates
        self.record_rows = record_rows
        self.limits = limits
        self.rows_log: list[Rows] = []
        self._recording_reported = False
        self._orderer_options = dict(orderer_options or {})
        self._runner = EstimatorRunner(estimator, settings, sensors, comparisons,
                                       collect_plot=True)
        self._parser = self._new_parser()
        self._orderer = TimeOrderer(**self._orderer_options)
        self._commands: queue.SimpleQueue = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._plot = _PlotBuffer(max_plot_rows)
        self._seq = 0
        self._polled_seq = -1
        self._latest = Snapshot()
        self._connection_state = "waiting"
        self._peer: str | None = None
        self._warnings: deque[str] = deque(maxlen=5)
        self._warned_at: dict[str, float] = {}
        self._tag_times: dict[str, deque[int]] = {}
        self._line_rate_marks: deque[tuple[float, int]] = deque()
        self._t0_ms: int | None = None     # the session's start: plots count time from it
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
        self.samples_processed = 0
        self._parser_retired = [0, 0, 0, 0, 0]   # counts of parsers replaced by a seek
        self._reasons_retired: dict[str, int] = {}
        self._order_retired = 0
        self.forwarder = forwarder
        self._user = UserFilterHost(self._runner, source, record=self._record_event)
        if user_filter is not None:
            self._user.load(user_filter)

    # -- lifecycle --------------------------------------------------------------------------------

    def start(self) -> None:
        """Start the source (may raise OSError/LogError, e.g. port taken) and the thread."""
        if self._thread is not None:
            return
        # Load the compiled kernels now (numba's on-disk cache), not at the first chunk.
        fastparse.warm_up()
        ordering.warm_up()
        self.source.start()
        if self.forwarder is not None:
            self.forwarder.start()
        self._thread = threading.Thread(target=self._run, name="engine", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread, the source, the recorder and the estimates file. Idempotent.

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
        if self.estimates is not None:
            try:
                self._end_of_stream(partial_line_damaged=False)
                self.estimates.write(self._runner.take_rows())
            except Exception as error:   # the thread is gone: nothing else would report it
                self._on_failure(error)
            self.estimates.close()
            self.estimates = None
        if self.recorder is not None and not self.recorder.closed:
            self.recorder.set_stats(self._stats_dict())
            self.recorder.close()

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

    # -- engine thread ----------------------------------------------------------------------------

    def _new_parser(self) -> fastparse.FastLineParser:
        if self.recorder is None:
            return fastparse.FastLineParser(limits=self.limits)
        return fastparse.FastLineParser(raw_sink=self.recorder.write_line,
                                        raw_block_sink=self.recorder.write_block,
                                        limits=self.limits)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._pass()
            except Exception as error:
                if self._on_failure(error):
                    self._stop_after_failures()
                    return

    def _pass(self) -> None:
        """Read what the source has, process it (at most MAX_BYTES_PER_PASS of chunks, the rest
        waits in the backlog) and publish."""
        self._apply_commands()
        self._user.tick()
        if self._backlog:
            items, self._backlog = self._backlog, []
        else:
            items = self.source.read(0.02)
        if items:
            self.waiting_since = None
        elif self.waiting_since is None:
            self.waiting_since = time.monotonic()
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
                self._apply_commands()
                self._on_chunks(chunks)
                chunks = []
            self._apply_commands()
            self._on_event(item)
            changed = True
        if chunks:
            self._apply_commands()
            self._on_chunks(chunks)
            changed = True
        now = time.perf_counter()
        if changed or now - self._last_publish >= PUBLISH_IDLE_S:
            self._publish(now)
        if self.recorder is not None:
            self.recorder.tick()
            self._check_recording()
        if self.estimates is not None:
            self.estimates.flush()

    def _check_recording(self) -> None:
        """A recording that stopped (write error, size or free-space limit) is reported once;
        its estimates.csv stops with it (the session ends there)."""
        recorder = self.recorder
        if recorder is None or recorder.error is None or self._recording_reported:
            return
        self._recording_reported = True
        log.error("recording stopped: %s", recorder.error)
        self._warn("recording", f"recording stopped: {recorder.error}", force=True)
        if self.estimates is not None:
            self.estimates.close()
            self.estimates = None

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
        self._warn("failure", f"engine error: {message}", force=True)
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

    def _feed(self, ordered: OrderedArrays) -> None:
        if not len(ordered.session_starts):
            if len(ordered):
                self._runner.feed_arrays(ordered.t_ms, ordered.tag, ordered.values)
                self.samples_processed += len(ordered)
            return
        # A clock that does not continue the previous stream's: nothing carries over (the
        # session may start while its first samples are still held: nothing released yet), and
        # the plots count time from the new session's start.
        for new, piece in ordered.pieces():
            if new:
                self._record_event("session", reason="the clock does not continue")
                self._runner.finish()
                self._start_session()
                self._runner.new_session()
            self._runner.feed_arrays(ordered.t_ms[piece], ordered.tag[piece],
                                     ordered.values[piece])
        self.samples_processed += len(ordered)

    def _parsed(self, parsed: ParsedArrays) -> None:
        """Parsed samples (in line order) -> rates, orderer, estimators."""
        self._track_rates(parsed)
        self.samples_processed += len(parsed.other)   # other tags pass the orderer untouched
        if len(parsed.t_ms):
            self._feed(self._orderer.push_arrays(parsed.t_ms, parsed.tag, parsed.values))

    def _on_chunks(self, chunks: list[Chunk]) -> None:
        """Consecutive chunks of one stream, parsed and filtered as one."""
        parser = self._parser
        damaged_before = parser.stats.damaged + parser.stats.too_long
        data = chunks[0].data if len(chunks) == 1 else b"".join(c.data for c in chunks)
        if self.forwarder is not None and self.source.kind == "tcp":
            for chunk in chunks:
                self.forwarder.feed(chunk.data, chunk.connection)
        self._parsed(parser.feed_arrays(data))
        sequence = self._orderer.sequence
        for chunk in chunks:
            self._pending_host_times.append((chunk.t_host, sequence))
        if parser.stats.damaged + parser.stats.too_long > damaged_before:
            message = parser.stats.bad_examples[-1][2] if parser.stats.bad_examples else ""
            self._warn("damaged", f"damaged line skipped ({message})")

    def _on_event(self, event: SourceEvent) -> None:
        kind = event.kind
        if kind in ("connected", "loop", "seek"):
            self._end_of_stream(partial_line_damaged=kind == "connected")
            self._start_session()
        if kind == "connected":
            self._feed(self._orderer.restart_arrays())
            self._connection_state = "replaying" if self.source.kind != "tcp" else "connected"
            self._peer = event.peer
            self._record_event("connected", peer=event.peer)
            self._user.on_restart(kind)
        elif kind == "disconnected":
            self._end_of_stream(partial_line_damaged=True)
            self._connection_state = "disconnected"
            self._warn("disconnected", f"phone disconnected ({event.detail})")
            self._record_event("disconnected", peer=event.peer, reason=event.detail)
        elif kind == "loop":
            self._feed(self._orderer.restart_arrays(continue_time=True))
            self._user.on_restart(kind)
        elif kind == "seek":
            # Re-run the filter from the start of the log up to the target (the source sends
            # those lines unpaced): the estimate there is exactly what playing would give.
            self._runner.take_rows()
            self._runner.take_plot_samples()
            self._runner.reset()
            self._runner.phone_quat = None
            self._retire_parser()
            self._order_retired += self._orderer.stats.out_of_order
            self._orderer = TimeOrderer(**self._orderer_options)
            # everything the old orderer held was released by _end_of_stream
            self._pending_host_times = deque(((t_host, -1) for t_host, _ in
                                              self._pending_host_times), maxlen=100_000)
            self._user.on_restart(kind)
        elif kind == "finished":
            self._end_of_stream(partial_line_damaged=False)
            self._connection_state = "finished"
        elif kind == "error":
            self._warn("error", event.detail, force=True)
        elif kind == "closed":
            self._warn("closed", event.detail)

    def _start_session(self) -> None:
        """A new connection, a replay's loop or seek: what the old session produced goes out
        (to the next poll) with its own time origin, and the next samples set a new one."""
        piece = self._take_output()
        with self._lock:
            self._plot.add(piece)
        self._t0_ms = None

    def _retire_parser(self) -> None:
        stats = self._parser.stats
        for index, value in enumerate((stats.lines, stats.damaged, stats.unknown,
                                       stats.too_long, stats.good)):
            self._parser_retired[index] += value
        for reason, count in stats.damaged_reasons.items():
            self._reasons_retired[reason] = self._reasons_retired.get(reason, 0) + count
        self._parser = self._new_parser()

    def _end_of_stream(self, partial_line_damaged: bool) -> None:
        """The current stream ended: a partial line is dropped (a line cut by a disconnect is
        damaged), pending samples are released, the last row is committed."""
        parser = self._parser
        if partial_line_damaged:
            if parser._pending or parser._discarding:
                kind = "too_long" if parser._discarding else "damaged"
                parser._count_bad(kind, "line cut off by the end of the connection", "cut off")
            parser.reset_line()
        else:
            self._parsed(parser.finish_arrays())
        self._feed(self._orderer.flush_arrays())
        self._runner.finish()

    def _apply_commands(self) -> None:
        while True:
            try:
                command = self._commands.get_nowait()
            except queue.Empty:
                return
            self._apply(command)

    def _apply(self, command: Any) -> None:
        runner = self._runner
        if isinstance(command, SetSensorEnabled):
            runner.set_sensor_enabled(command.sensor, command.enabled)
            self._record_event("sensor", sensor=command.sensor, enabled=command.enabled)
        elif isinstance(command, SetEstimator):
            if command.name not in ekf.ESTIMATORS:
                self._warn("command", f"unknown estimator {command.name!r}", force=True)
                return
            runner.set_estimator(command.name)
            self._record_event("estimator", name=command.name)
        elif isinstance(command, SetSettings):
            runner.set_settings(command.settings)
            if self.recorder is not None:
                self.recorder.set_settings(command.settings)
                if command.calibration is not None:
                    self.recorder.set_calibration(command.calibration)
            details = {"source": command.source} if command.source else {}
            if command.calibration is not None:
                details["profile"] = command.calibration.get("name")
            self._record_event("settings", **details)
        elif isinstance(command, ResetFilter):
            runner.reset()
            self._record_event("reset")
        elif isinstance(command, AlignHeading):
            turned = runner.align_heading()
            if turned is None:
                self._warn("align", "align heading: no PHONE orientation (ORI) yet", force=True)
            else:
                self._record_event("align_heading", turned_deg=round(turned, 2))
                self._warn("align", f"heading aligned with PHONE: OWN turned by {turned:+.1f}° "
                                    "about up", force=True)
        elif isinstance(command, SetComparisonsEnabled):
            if command.estimator is not None and command.estimator not in ekf.ESTIMATORS:
                self._warn("command", f"unknown estimator {command.estimator!r}", force=True)
                return
            runner.set_comparisons_enabled(command.enabled, command.estimator)
        elif isinstance(command, (ReplayControl, *CONNECTION_COMMANDS)):
            self.source.control(command)
        elif isinstance(command, LoadUserFilter):
            self._user.load(command.path)
        elif isinstance(command, UnloadUserFilter):
            self._user.unload()
        elif isinstance(command, SetConsistencyEnabled):
            runner.set_consistency_enabled(command.enabled)
        else:
            self._warn("command", f"unknown command {command!r}", force=True)

    def _record_event(self, kind: str, **data: Any) -> None:
        if self.recorder is not None:
            self.recorder.add_event(kind, self._runner.latest_t_ms, **data)

    def _warn(self, kind: str, message: str, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._warned_at.get(kind, -math.inf) < WARNING_INTERVAL_S:
            return
        self._warned_at[kind] = now
        self._warnings.append(message)

    def _track_rates(self, parsed: ParsedArrays) -> None:
        """Remember each tag's own (unaligned) times, in line order, for :meth:`_rates`."""
        times = self._tag_times
        if parsed.other:
            # Rare tags: keep the line order among all tags (deque creation order = first seen).
            samples = parsed.to_samples()
        elif len(parsed.t_ms):
            codes = parsed.tag
            present = sorted(set(codes.tolist()), key=lambda c: int(np.argmax(codes == c)))
            for code in present:
                tag = FILTER_TAGS[code]
                queue_ = times.get(tag)
                if queue_ is None:
                    queue_ = times[tag] = deque()
                queue_.extend(parsed.t_ms[codes == code].tolist())
            return
        else:
            return
        for sample in samples:
            queue_ = times.get(sample.tag)
            if queue_ is None:
                queue_ = times[sample.tag] = deque()
            queue_.append(sample.t_ms)

    def _rates(self) -> dict[str, float]:
        rates = {}
        for tag, times in self._tag_times.items():
            if not times:
                continue
            newest = times[-1]
            while times and (times[0] < newest - RATE_WINDOW_MS or times[0] > newest):
                times.popleft()
            if len(times) >= 2 and times[-1] > times[0]:
                rates[tag] = round((len(times) - 1) * 1000.0 / (times[-1] - times[0]), 1)
        return rates

    def _lines_per_s(self, now: float, lines: int) -> float:
        marks = self._line_rate_marks
        marks.append((now, lines))
        while len(marks) > 2 and now - marks[1][0] >= 1.0:
            marks.popleft()
        first_time, first_lines = marks[0]
        if now - first_time <= 0:
            return 0.0
        return (lines - first_lines) / (now - first_time)

    def _stats_dict(self) -> dict[str, Any]:
        health = self._latest.health
        return {"lines": health.lines_total, "damaged": health.damaged,
                "damaged_reasons": dict(health.damaged_reasons),
                "unknown": health.unknown, "too_long": health.too_long,
                "out_of_order": health.out_of_order, "clock_quirks": list(health.clock_quirks),
                "sessions": health.sessions, "rates_hz": dict(health.rates_hz),
                "connections_closed": dict(health.connections_closed)}

    def _take_output(self) -> PlotChunk:
        """The rows since the last call to their consumers (rows_log, estimates.csv); the plot
        samples as a PlotChunk in the current session's time."""
        runner = self._runner
        rows = runner.take_rows()
        if self.record_rows and len(rows):
            self.rows_log.append(rows)
        if self.estimates is not None:
            self.estimates.write(rows)
            if self.estimates.error is not None:
                self._warn("estimates", f"estimates.csv stopped: {self.estimates.error}",
                           force=True)
                self.estimates = None
        return self._plot_piece(rows, runner.take_plot_samples())

    def _publish(self, now: float) -> None:
        """Hand the rows and plot samples since the last publish to their consumers and make a
        new snapshot the latest."""
        runner = self._runner
        piece = self._take_output()
        main = runner.main
        cov = main.cov
        info = self.source.info()
        phone = runner.phone_quat
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
            comparison_estimator=runner.comparison_estimator, t0_ms=self._t0_ms,
            health=self._health(now, info), replay=info.get("replay"),
            failures=list(self.failures), user=self._user.status())
        published = time.perf_counter()
        with self._lock:
            self._plot.add(piece)
            self._latest = snapshot
            self._seq += 1
            snapshot.seq = self._seq
        pending = self._pending_host_times
        if pending:
            oldest = self._orderer.oldest_pending_sequence
            while pending and pending[0][1] < oldest:
                t_host = pending.popleft()[0]
                self.latencies_s.append(published - t_host)
                self.latency_arrivals_s.append(t_host)
        self._last_publish = now
        if self.recorder is not None:
            self.recorder.set_stats(self._stats_dict())

    def _plot_piece(self, rows: Rows, plot: dict[str, np.ndarray]) -> PlotChunk:
        """The plot samples since the last publish, in seconds since the session's start."""
        runner = self._runner
        ori_t, ori_q = runner.take_phone_samples()
        errors = runner.take_errors()
        rows = rows.select(rows.has_sample)         # OWN at our own estimate times
        if self._t0_ms is None:
            firsts = [int(t[0]) for t in (rows.t_ms, plot["t_acc"], plot["t_gyr"],
                                          plot["t_mag"], ori_t) if len(t)]
            self._t0_ms = min(firsts) if firsts else None
        t0 = self._t0_ms or 0
        count = len(rows)
        if count or len(ori_q):
            # one call for both series (the per-call overhead dominates at live chunk sizes)
            euler = np.degrees(ekf.quaternion.to_euler(np.concatenate([rows.quat, ori_q])))
        else:
            euler = np.empty((0, 3))

        def seconds(t_ms: np.ndarray) -> np.ndarray:
            return (np.asarray(t_ms, np.float64) - t0) / 1000.0

        innovations = runner.take_innovations()
        if "t_innovation" in innovations:
            innovations["t_innovation"] = seconds(np.asarray(innovations["t_innovation"]) * 1000.0)
        return PlotChunk(
            **self._user_plot(rows, seconds), **innovations,
            t_acc=seconds(plot["t_acc"]), acc=plot["acc"], acc_rejected=plot["acc_rejected"],
            t_gyr=seconds(plot["t_gyr"]), gyr=plot["gyr"],
            t_mag=seconds(plot["t_mag"]), mag=plot["mag"], mag_rejected=plot["mag_rejected"],
            t_est=seconds(rows.t_ms), own_euler_deg=euler[:count],
            t_ori=seconds(ori_t), phone_euler_deg=euler[count:],
            t_err=seconds(errors.t_ms), error_deg=errors.error_deg)

    def _user_plot(self, rows: Rows, seconds) -> dict[str, np.ndarray]:
        """YOURS for the plots: its Euler angles (wrapped, at our estimate times, NaN where it
        has none) and its errors against PHONE at PHONE's times."""
        errors = self._runner.take_user_errors()
        out = {"t_user_err": seconds(errors.t_ms), "user_error_deg": errors.error_deg}
        if rows.user_quat is None or not len(rows):
            return out
        euler = np.full((len(rows), 3), np.nan)
        finite = np.isfinite(rows.user_quat).all(axis=1)
        if finite.any():
            euler[finite] = np.degrees(ekf.quaternion.to_euler(rows.user_quat[finite]))
        return {**out, "t_user": seconds(rows.t_ms), "user_euler_deg": euler}

    def _filter_status(self) -> FilterStatus:
        main = self._runner.main
        return FilterStatus(sensors_enabled=main.enabled, flags=main.flags,
                            diagnostics=main.diagnostics, estimator=self._runner.estimator_name,
                            initialised=main.initialised, settings=self._runner.settings)

    def _health(self, now: float, info: dict[str, Any]) -> StreamHealth:
        parse = self._parser.stats
        retired = self._parser_retired
        lines_total = parse.lines + retired[0]
        state = info.get("connection_state", "waiting")
        if self.source.kind == "tcp":
            state = self._connection_state if state != "waiting" else "waiting"
        reasons = dict(self._reasons_retired)
        for reason, count in parse.damaged_reasons.items():
            reasons[reason] = reasons.get(reason, 0) + count
        order = self._orderer.stats
        return StreamHealth(
            connection_state=state, peer=info.get("peer") or self._peer,
            listen_addresses=list(info.get("listen_addresses") or []), port=info.get("port"),
            rates_hz=self._rates(), lines_per_s=round(self._lines_per_s(now, lines_total), 1),
            lines_total=lines_total, damaged=parse.damaged + retired[1],
            unknown=parse.unknown + retired[2], too_long=parse.too_long + retired[3],
            out_of_order=order.out_of_order + self._order_retired,
            clock_quirks=list(order.clock_quirks), warnings=list(self._warnings),
            damaged_reasons=reasons, sessions=order.sessions,
            reorder_window_ms=order.window_ms, lags_ms=dict(order.lags_ms),
            waiting_peers=list(info.get("waiting_peers") or []),
            connections_closed=dict(info.get("connections_closed") or {}),
            allowed=list(info.get("allowed") or []), recording=self._recording_text(),
            forward=None if self.forwarder is None else self.forwarder.status())

    def _recording_text(self) -> str | None:
        recorder = self.recorder
        if recorder is None:
            return None
        if recorder.error is not None:
            return f"recording stopped: {recorder.error}"
        return (f"recording into {recorder.directory} "
                f"({recorder.bytes_written / 2**20:.1f} MB)")
