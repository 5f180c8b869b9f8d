"""Where the engine's output goes: its rows to their consumers, its snapshots to the GUI.

:class:`EngineOutput` hands each estimate row to the engine's rows_log (when kept) and to a
recording's estimates.csv, and the plot samples to the next poll. :class:`Publisher` holds the
latest :class:`~app.engine.snapshot.Snapshot`, the plot samples since the previous poll
(bounded, :class:`~app.engine.snapshot.PlotBuffer`) and a sequence number that says whether
anything changed; the engine's thread publishes, any thread polls, a short lock between them.
It also measures the latency of the estimates: from a chunk's arrival to the publish after
which the time orderer holds none of its samples any more. (The snapshot itself is composed
from the engine's parts by :func:`app.engine.live.parts.engine_snapshot`.)
"""

from __future__ import annotations

import dataclasses
import threading
from collections import deque
from collections.abc import Iterable
from typing import Any

from app.engine.processing.pipeline import Pipeline
from app.engine.sessions.recording import RecordingLane
from app.engine.errors import EngineFailure
from app.engine.snapshot import PlotBuffer, PlotChunk, Snapshot


class Publisher:
    """The latest snapshot and the plot samples waiting for the next poll (thread-safe)."""

    def __init__(self, max_plot_rows: int) -> None:
        self._lock = threading.Lock()
        self._plot = PlotBuffer(max_plot_rows)
        self._seq = 0
        self._polled_seq = -1
        self._latest = Snapshot()
        self.last_publish = 0.0            # perf_counter of the latest publish
        self._marks: list[threading.Event] = []   # wait_idle's, set at the next publish
        # (chunk arrival time, orderer sequence after it): a chunk's estimates are out once
        # the orderer holds nothing pushed up to that sequence
        self._arrivals: deque[tuple[float, int]] = deque(maxlen=100_000)
        # chunk arrival -> the estimates of all its samples published (time held for reordering
        # included), and those chunks' arrival times
        self.latencies_s: deque[float] = deque(maxlen=200_000)
        self.latency_arrivals_s: deque[float] = deque(maxlen=200_000)

    # -- any thread ------------------------------------------------------------------------------

    def poll(self) -> Snapshot | None:
        """The latest state and the plot samples since the previous poll, or None when nothing
        changed."""
        with self._lock:
            if self._seq == self._polled_seq:
                return None
            self._polled_seq = self._seq
            return self._copy_latest(self._plot.take())

    def snapshot_now(self) -> Snapshot:
        """The latest state, leaving the plot samples and the "changed" mark for the next poll
        (its plot is empty)."""
        with self._lock:
            return self._copy_latest(PlotChunk())

    def _copy_latest(self, plot: PlotChunk) -> Snapshot:
        return dataclasses.replace(self._latest, seq=self._seq, plot=plot)

    # -- the engine's thread ---------------------------------------------------------------------

    @property
    def latest(self) -> Snapshot:
        """The snapshot published last (the engine's thread reads it, e.g. its health)."""
        return self._latest

    def add_plot(self, piece: PlotChunk) -> None:
        """Plot samples for the next poll."""
        with self._lock:
            self._plot.add(piece)

    def add_mark(self, event: threading.Event) -> None:
        """Set `event` at the next publish."""
        self._marks.append(event)

    def arrived(self, t_hosts: Iterable[float], sequence: int) -> None:
        """Chunks that arrived at `t_hosts` were pushed into the orderer up to `sequence`."""
        self._arrivals.extend((t_host, sequence) for t_host in t_hosts)

    def forget_arrivals(self) -> None:
        """What was pushed before is not going to be published (a new pass, a seek)."""
        self._arrivals.clear()

    def publish(self, snapshot: Snapshot, piece: PlotChunk, orderer: Any, now: float,
                published: float) -> None:
        """Make `snapshot` the latest with `piece` for the next poll; the chunks whose samples
        the time orderer no longer holds count as published at `published`; `now` is the
        pass's time (for the idle publishes)."""
        with self._lock:
            self._plot.add(piece)
            self._latest = snapshot
            self._seq += 1
            snapshot.seq = self._seq
        arrivals = self._arrivals
        oldest = orderer.oldest_pending_sequence if arrivals else 0
        while arrivals and arrivals[0][1] < oldest:
            t_host = arrivals.popleft()[0]
            self.latencies_s.append(published - t_host)
            self.latency_arrivals_s.append(t_host)
        self.last_publish = now
        for mark in self._marks:
            mark.set()
        self._marks = []

    def amend(self, failures: list[EngineFailure], stopped: bool = False) -> None:
        """The latest snapshot with these failures (and, when `stopped`, the engine stopped),
        published again: for when a full publish is not possible."""
        with self._lock:
            self._latest.failures = list(failures)
            if stopped:
                self._latest.health.connection_state = "stopped"
            self._seq += 1


class EngineOutput:
    """The pipeline's output to its consumers: rows to rows_log (record_rows: keep them all,
    unbounded) and the recording lane (which leaves out the rows a seek re-runs up to its
    target: they were not shown); plot samples to the publisher."""

    def __init__(self, pipeline: Pipeline, publisher: Publisher, recordings: RecordingLane,
                 record_rows: bool) -> None:
        self.pipeline = pipeline
        self.publisher = publisher
        self.recordings = recordings
        self.record_rows = record_rows
        self.rows_log: list[Any] = []

    def cut(self, rows: Any, piece: PlotChunk) -> None:
        """Output ready as it is (a session's end with its own time origin, a seek's re-sync)."""
        self.rows(rows)
        self.publisher.add_plot(piece)

    def rows(self, rows: Any) -> None:
        if self.record_rows and len(rows):
            self.rows_log.append(rows)
        self.recordings.write_rows(rows)

    def flush(self) -> None:
        """The output so far to its consumers now (rows, and the plots at the next poll)."""
        self.publisher.add_plot(self.take())

    def take(self) -> PlotChunk:
        """The rows since the last call to their consumers; the plot samples as a PlotChunk in
        the current session's time."""
        rows, piece = self.pipeline.take_output()
        self.recordings.output_starts(self.pipeline.piece_first_ms)
        self.rows(rows)
        return piece
