"""Put the filter tags' samples back in time order, on one clock, before a filter sees them.

Real phones write each sensor when its batch arrives, so lines are not in global time order
(each tag's own times increase); some tags sit on another clock (one phone's ACC runs exactly
131,072,000 ms ahead of its GYR and MAG). See ../shared/PROTOCOL.md, "Time".

:class:`TimeOrderer` handles only the filter tags (GYR, ACC, MAG, ORI); other tags pass
through untouched (RSSWIFI/GPS may carry epoch ms and never reach a filter's dt).

- Clock alignment, per segment: the first filter tag seen is the reference clock. A tag whose
  first sample is more than ``align_threshold_ms`` (250 ms) away from the reference's latest
  time sits on another clock, whatever the size of the offset: it gets a constant offset that
  aligns it (snapped to whole seconds when within window_ms / 2 of them), reported in
  ``stats.clock_quirks`` (a tag that fits the clock of a tag already aligned takes that
  offset: tags sharing a clock share it exactly). Closer than that it is a tag arriving late,
  which the adaptive window below absorbs. At the start of a segment releases wait at least ``startup_hold_ms``,
  until two tags are there and no new tag has shown up for ``window_ms`` (at most 4 x
  startup_hold_ms), so a sensor starting a little late keeps its first samples; the hold ends
  at once when all four filter tags are there (none can start late any more).
- Reordering: a k-way merge with a watermark. A sample at aligned time t is released once
  every *active* tag has reached t (a tag lagging the newest time by more than the window is
  inactive: it stopped or is late), or when more than ``max_pending`` samples wait. Released
  samples are sorted by (t, GYR < ACC < MAG < ORI).
- The window adapts: each tag's lag (how far behind the newest time its samples arrive, the
  largest seen over the last 5-10 s of phone time, lags over ``max_window_ms`` ignored) is
  learned, and the window is ``lag + lag/4 + 10 ms``, at least ``window_ms`` (100 ms) and at
  most ``max_window_ms`` (500 ms). A tag that arrives 95 or 300 ms behind the others is waited
  for, not dropped. ``stats.window_ms`` and ``stats.lags_ms`` show them.
- A sample older than the last released time, or a tag going back in its own time, is dropped
  and counted in ``stats.out_of_order``; so is a block written late (its tag going back by
  more than ``gap_ms`` but at most ``late_horizon_ms``): it is never played as a new segment.
  Only when such late samples go on for more than ``gap_ms`` of their own time has the clock
  really gone back (a reboot), and a new segment starts.
- A jump of a tag's own clock by more than ``gap_ms`` (forward: a pause; backward beyond the
  horizon: a reboot or another phone) or a :meth:`restart` call (reconnect) starts a new
  segment: pending samples are released, alignment is learned again (within one stream the
  reference tag keeps its offset). A jump is held (the samples wait beside the buffer) until
  it is confirmed: another tag jumps to within ``gap_ms`` of it, the tag's own samples stay on
  the new clock for more than ``gap_ms``, no other tag is seen in the segment, or the hold is
  full. When the tag's next sample continues its old clock instead, the held samples were bad
  time stamps (a sample at t = 0, a burst a year ahead): they are dropped and counted in
  ``stats.out_of_order``, and nothing else changes (no new segment, no clock quirk). Held
  samples still unconfirmed at the end of a stream are dropped too. A segment whose clock continues the previous one's (later
  than the last released time, by at most ``session_gap_ms``) continues its time axis: the
  filters keep their orientation. One that starts before the last released time (another
  phone, a reboot, an earlier connection's fake clock) or much later starts a new *session*:
  its times are its own, never shifted by an earlier stream's, and the consumer re-initialises
  its filters there (``stats.sessions``; ``session_starts`` of :class:`OrderedArrays`).
  ``restart(continue_time=True)`` (a replay that loops) instead shifts the new segment to
  start ``restart_gap_ms`` after the last released time, so a filter sees dt > 1 s, restarts
  its time base and keeps its orientation.

The output depends only on the sequence of samples pushed, never on wall time or chunking.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, fields

import numpy as np

from app.stream.ordering_kernels import (K, K_COLUMNS, PARAMETERS, S, SUSPECT_COLUMNS, U,
                                         clear_suspects, flush_all, new_segment,
                                         oldest_pending_sequence, push_run)
from app.stream.ordering_reference import (_MAX_QUIRKS, OrderOptions, OrderStats,
                                           ReferenceTimeOrderer, _append_bounded,
                                           effective_window)
from app.stream.protocol import FILTER_TAGS, TAG_PRIORITY, Sample
from app.stream.tags import MAX_WIDTH, N_FILTER_TAGS


@dataclass
class OrderedArrays:
    """Released samples in release order: t_ms (n,) aligned phone ms; tag (n,) codes (GYR 0,
    ACC 1, MAG 2, ORI 3); values (n, 4); seq (n,) push sequence; payload (n,) the caller's id;
    session_starts: indices where a new session begins (the consumer re-initialises there)."""

    t_ms: np.ndarray
    tag: np.ndarray
    values: np.ndarray
    seq: np.ndarray
    payload: np.ndarray
    session_starts: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))

    def __len__(self) -> int:
        return len(self.t_ms)

    @staticmethod
    def from_keys(keys: np.ndarray, values: np.ndarray, n: int,
                  session_starts: list[int] | None = None) -> OrderedArrays:
        return OrderedArrays(keys[:n, K.t].copy(), keys[:n, K.priority].copy(), values[:n].copy(),
                             keys[:n, K.seq].copy(), keys[:n, K.payload].copy(),
                             np.asarray(session_starts or [], np.int64))

    def pieces(self) -> list[tuple[bool, slice]]:
        """(a new session starts here, the slice of its samples), in order."""
        cuts = [int(c) for c in self.session_starts]
        bounds = [0] + cuts + [len(self)]
        return [(k > 0, slice(bounds[k], bounds[k + 1])) for k in range(len(bounds) - 1)
                if k > 0 or bounds[1] > 0]


class TimeOrderer:
    """Streaming reorder + clock alignment of filter-tag samples (see the module docstring).

    The algorithm of :class:`ReferenceTimeOrderer` (same releases, counters and quirk texts)
    run by a nogil numba kernel; only learning a tag's clock offset (a few times per segment)
    runs in Python. Two faces: Samples (:meth:`push`, :meth:`push_many`, :meth:`flush`,
    :meth:`restart`) and arrays (:meth:`push_arrays`, :meth:`flush_arrays`,
    :meth:`restart_arrays`) for the live engine.
    """

    def __init__(self, options: OrderOptions | None = None, **overrides: int) -> None:
        self.options = OrderOptions.of(options, **overrides)
        for item in fields(self.options):
            setattr(self, item.name, getattr(self.options, item.name))
        self._params = np.array([getattr(self.options, name) for name in PARAMETERS], np.int64)
        self.stats = OrderStats(window_ms=self.window_ms)
        self._state = np.zeros(S.size, np.int64)
        self._state[S.reference] = -1
        self._segment_id = 0
        self._offsets: dict[str, int] = {}
        self._continue_time = False
        self.stats.offsets_ms = self._offsets
        capacity = self.max_pending + 2
        self._keys = np.zeros((capacity, K_COLUMNS), np.int64)
        self._values = np.zeros((capacity, MAX_WIDTH))
        self._suspects = np.zeros((capacity, len(SUSPECT_COLUMNS)), np.int64)
        self._suspect_values = np.zeros((capacity, MAX_WIDTH))
        self._payloads: dict[int, Sample] = {}     # Sample face: payload id -> Sample
        self._next_payload = 0

    # -- arrays face -------------------------------------------------------------------------

    def push_arrays(self, t_ms: np.ndarray, tag: np.ndarray, values: np.ndarray,
                    payload: np.ndarray | None = None) -> OrderedArrays:
        """Filter-tag samples (tag codes GYR 0, ACC 1, MAG 2, ORI 3; values (n, 4)) in
        arrival order; returns what they release, in release order."""
        t_ms = np.ascontiguousarray(t_ms, dtype=np.int64)
        tag = np.ascontiguousarray(tag, dtype=np.int64)
        values = np.ascontiguousarray(values, dtype=np.float64).reshape(-1, MAX_WIDTH)
        n = len(t_ms)
        if payload is None:
            payload = np.full(n, -1, np.int64)
        state = self._state
        capacity = n + int(state[S.heap_n]) + int(state[S.suspects])
        out_keys = np.empty((capacity, K_COLUMNS), np.int64)
        out_values = np.empty((capacity, MAX_WIDTH))
        n_out, index, counted = 0, 0, 0
        session_starts: list[int] = []
        while True:
            n_out, index, held = push_run(state, self._keys, self._values, self._suspects,
                                          self._suspect_values, t_ms, tag, values, payload,
                                          index, counted, self._params, out_keys, out_values,
                                          n_out)
            if held:
                # a confirmed jump: the held samples start the new segment, then the rest
                suspects = self._suspects[:held]
                t_ms = np.concatenate([suspects[:, U.raw], t_ms[index:]])
                tag = np.concatenate([suspects[:, U.tag], tag[index:]])
                payload = np.concatenate([suspects[:, U.payload], payload[index:]])
                values = np.concatenate([self._suspect_values[:held], values[index:]])
                n, index, counted = len(t_ms), 0, held
                continue
            if index >= n:
                break
            self._sync_segment()
            if self._learn_offset(int(tag[index]), int(t_ms[index])):
                session_starts.append(n_out)
            state[S.resume] = 1
        self._sync()
        return OrderedArrays.from_keys(out_keys, out_values, n_out, session_starts)

    def flush_arrays(self) -> OrderedArrays:
        """Release everything pending (end of stream). The segment stays open; samples whose
        jump no other sample confirmed are dropped (counted)."""
        self._state[S.out_of_order] += self._state[S.suspects]
        clear_suspects(self._state)
        count = int(self._state[S.heap_n])
        out_keys = np.empty((count, K_COLUMNS), np.int64)
        out_values = np.empty((count, MAX_WIDTH))
        n_out = flush_all(self._state, self._keys, self._values, out_keys, out_values) \
            if count else 0
        self._sync()
        return OrderedArrays.from_keys(out_keys, out_values, n_out)

    def restart_arrays(self, continue_time: bool = False) -> OrderedArrays:
        """Reconnect: release what is pending and learn the clocks again for what follows
        (continue_time: see :meth:`ReferenceTimeOrderer.restart`)."""
        out = self.flush_arrays()
        new_segment(self._state, 0)
        self._continue_time = bool(continue_time)
        self._sync()
        return out

    @property
    def oldest_pending_sequence(self) -> int:
        """The push sequence number of the oldest sample still in the reorder buffer (the
        next one when none): every sample that entered the buffer before it has been released.
        (A sample held because its own clock jumped enters the buffer once the jump is
        confirmed.)"""
        return int(oldest_pending_sequence(self._state, self._keys))

    @property
    def sequence(self) -> int:
        """Sequence number of the latest sample that entered the buffer."""
        return int(self._state[S.sequence])

    def snapshot(self) -> dict:
        """The arrays face's whole state (copies: the packed state, the samples held, the learned
        clock offsets), to continue later from exactly here with :meth:`restore` (a replay's
        checkpoints). Statistics are not part of it."""
        held = int(self._state[S.heap_n])
        suspects = int(self._state[S.suspects])
        return {"state": self._state.copy(), "keys": self._keys[:held].copy(),
                "values": self._values[:held].copy(),
                "suspects": self._suspects[:suspects].copy(),
                "suspect_values": self._suspect_values[:suspects].copy(),
                "segment_id": self._segment_id, "offsets": dict(self._offsets),
                "continue_time": self._continue_time}

    def restore(self, snapshot: dict) -> None:
        """Continue from a :meth:`snapshot` of an orderer with the same parameters (the counters
        in :attr:`stats` follow the restored state)."""
        state = np.asarray(snapshot["state"], np.int64)
        held = len(snapshot["keys"])
        suspects = len(snapshot.get("suspects", ()))
        if state.shape != (S.size,) or held > len(self._keys) or held != state[S.heap_n] \
                or suspects > len(self._suspects) or suspects != state[S.suspects]:
            raise ValueError("not a snapshot of this orderer")
        self._state[:] = state
        self._keys[:held] = snapshot["keys"]
        self._values[:held] = snapshot["values"]
        if suspects:
            self._suspects[:suspects] = snapshot["suspects"]
            self._suspect_values[:suspects] = snapshot["suspect_values"]
        self._segment_id = int(snapshot["segment_id"])
        self._offsets = dict(snapshot["offsets"])
        self.stats.offsets_ms = self._offsets
        self._continue_time = bool(snapshot["continue_time"])
        self._payloads.clear()
        self._sync()

    # -- Sample face ---------------------------------------------------------------------------

    def push(self, sample: Sample) -> list[Sample]:
        """Take one sample (any tag); return what it releases, in release order."""
        if sample.tag not in TAG_PRIORITY:
            return [sample]
        return self._push_samples([sample])

    def push_many(self, samples: Iterable[Sample]) -> list[Sample]:
        out: list[Sample] = []
        run: list[Sample] = []
        for sample in samples:
            if sample.tag in TAG_PRIORITY:
                run.append(sample)
            else:
                if run:
                    out += self._push_samples(run)
                    run = []
                out.append(sample)
        if run:
            out += self._push_samples(run)
        return out

    def flush(self) -> list[Sample]:
        """Release everything pending (end of stream). The segment stays open."""
        return self._to_samples(self.flush_arrays())

    def restart(self, continue_time: bool = False) -> list[Sample]:
        """Reconnect: release what is pending and learn the clocks again for what follows."""
        return self._to_samples(self.restart_arrays(continue_time))

    @property
    def pending(self) -> int:
        return int(self._state[S.heap_n]) + int(self._state[S.suspects])

    @property
    def last_released_ms(self) -> int | None:
        state = self._state
        return int(state[S.last_released]) if state[S.has_last_released] else None

    # -- internals -----------------------------------------------------------------------------

    def _push_samples(self, samples: list[Sample]) -> list[Sample]:
        n = len(samples)
        first = self._next_payload
        self._next_payload += n
        values = np.zeros((n, MAX_WIDTH))
        for k, sample in enumerate(samples):
            self._payloads[first + k] = sample
        out = self.push_arrays(np.fromiter((s.t_ms for s in samples), np.int64, n),
                               np.fromiter((TAG_PRIORITY[s.tag] for s in samples), np.int64, n),
                               values, np.arange(first, first + n, dtype=np.int64))
        # Samples dropped on the way never come back: forget them once they are older than
        # anything still held.
        released = self._to_samples(out)
        if not self.pending:
            self._payloads.clear()
        elif len(self._payloads) > 2 * self.pending + 1024:
            held = set(self._keys[:int(self._state[S.heap_n]), K.payload].tolist()) | set(
                self._suspects[:int(self._state[S.suspects]), U.payload].tolist())
            self._payloads = {key: s for key, s in self._payloads.items() if key in held}
        return released

    def _to_samples(self, out: OrderedArrays) -> list[Sample]:
        payloads = self._payloads
        result = []
        for t, key in zip(out.t_ms.tolist(), out.payload.tolist()):
            sample = payloads.pop(key)
            result.append(sample if sample.t_ms == t else sample._replace(t_ms=t))
        return result

    def _sync_segment(self) -> None:
        segment = int(self._state[S.segment_id])
        if segment != self._segment_id:
            self._segment_id = segment
            self._offsets = {}
            self.stats.offsets_ms = self._offsets

    def _sync(self) -> None:
        self._sync_segment()
        state = self._state
        stats = self.stats
        stats.pushed = int(state[S.pushed])
        stats.released = int(state[S.released])
        stats.out_of_order = int(state[S.out_of_order])
        stats.forced = int(state[S.forced])
        stats.restarts = int(state[S.restarts])
        lags = [max(int(state[S.lag_current + c]), int(state[S.lag_previous + c]))
                for c in range(N_FILTER_TAGS)]
        stats.lags_ms = {FILTER_TAGS[c]: lag for c, lag in enumerate(lags) if lag > 0}
        stats.window_ms = effective_window(max(lags), self.window_ms, self.max_window_ms)

    def _quirk(self, text: str) -> None:
        quirks = self.stats.clock_quirks
        if text not in quirks:
            quirks.append(text)
            del quirks[:-_MAX_QUIRKS]

    def _start_segment_clock(self, tag: int, raw: int) -> tuple[int, bool]:
        """ReferenceTimeOrderer._start_segment_clock on the packed state: (offset, whether a
        new session starts)."""
        state = self._state
        state[S.reference] = tag
        base = int(state[S.previous_offset + tag]) if state[S.has_previous_offset + tag] else 0
        t = raw + base
        shift = 0
        new_session = False
        last = self.last_released_ms
        if last is not None:
            if self._continue_time:
                if t <= last:
                    shift = last + self.restart_gap_ms - t
            elif t <= last or t - last > self.session_gap_ms:
                state[S.has_last_released] = 0
                self.stats.sessions += 1
                _append_bounded(self.stats.session_starts, int(state[S.released]))
                new_session = True
        self._continue_time = False
        if state[S.restarts] or last is not None:
            _append_bounded(self.stats.restart_times_ms, t + shift)
        state[S.segment_start] = t + shift
        return base + shift, new_session

    def _learn_offset(self, tag: int, raw: int) -> bool:
        """ReferenceTimeOrderer._learn_offset on the packed state; True when a new session
        starts with this sample."""
        state = self._state
        name = FILTER_TAGS[tag]
        new_session = False
        if state[S.reference] < 0:
            offset, new_session = self._start_segment_clock(tag, raw)
        else:
            reference = int(state[S.reference])
            reference_latest = int(state[S.last + reference])
            reference_offset = int(state[S.offset + reference])
            offset = reference_offset
            if abs(raw + reference_offset - reference_latest) > self.align_threshold_ms:
                offset = next((int(state[S.offset + other]) for other in range(N_FILTER_TAGS)
                               if state[S.has_offset + other] and abs(
                                   raw + int(state[S.offset + other]) - reference_latest)
                               <= self.align_threshold_ms), None)
                if offset is None:
                    offset = reference_latest - raw
                    whole_seconds = round((offset - reference_offset) / 1000) * 1000 \
                        + reference_offset
                    if abs(offset - whole_seconds) <= self.window_ms // 2:
                        offset = whole_seconds
                difference = -(offset - reference_offset)
                self._quirk(f"{name} clock {difference:+d} ms vs "
                            f"{FILTER_TAGS[reference]} (aligned)")
        state[S.offset + tag] = offset
        state[S.has_offset + tag] = 1
        self._offsets[name] = offset
        return new_session


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernels before the first chunk arrives."""
    orderer = TimeOrderer()
    orderer.push_arrays(np.array([1000, 1000, 5000]), np.array([0, 1, 0]), np.zeros((3, MAX_WIDTH)))
    orderer.restart_arrays()
    _ = orderer.oldest_pending_sequence


__all__ = ["TimeOrderer", "ReferenceTimeOrderer", "OrderOptions", "OrderStats", "OrderedArrays",
           "FILTER_TAGS", "effective_window"]
