"""Put the filter tags' samples back in time order, on one clock, before a filter sees them.

Real phones write each sensor when its batch arrives, so lines are not in global time order
(each tag's own times increase); some tags sit on another clock (one phone's ACC runs exactly
131,072,000 ms ahead of its GYR and MAG). See ../shared/PROTOCOL.md, "Time".

:class:`TimeOrderer` handles only the filter tags (GYR, ACC, MAG, ORI); other tags pass
through untouched (RSSWIFI/GPS may carry epoch ms and never reach a filter's dt).

- Clock alignment, per segment: the first filter tag seen is the reference clock. A tag whose
  first sample is more than ``align_threshold_ms`` away from the reference's latest time gets
  a constant offset that aligns it (snapped to whole seconds when within window_ms / 2 of
  them), reported in ``stats.clock_quirks``. At the start of a segment releases wait at least
  ``startup_hold_ms``, until two tags are there and no new tag has shown up for ``window_ms``
  (at most 4 x startup_hold_ms), so a sensor starting a little late keeps its first samples;
  the hold ends at once when all four filter tags are there (none can start late any more).
- Reordering: a k-way merge with a watermark. A sample at aligned time t is released once
  every *active* tag has reached t (a tag lagging the newest time by more than ``window_ms``
  is inactive: it stopped or is late), or when more than ``max_pending`` samples wait.
  Released samples are sorted by (t, GYR < ACC < MAG < ORI).
- A sample older than the last released time, or a tag going back in its own time (by at
  most ``gap_ms``), is dropped and counted in ``stats.out_of_order``.
- A jump of a tag's own clock by more than ``gap_ms`` (forward: a pause; backward: a reboot or
  another phone) or a :meth:`restart` call (reconnect) starts a new segment: pending samples
  are released, alignment is learned again. Output times never go backwards: a segment that
  would start before the last released time is shifted to start ``restart_gap_ms`` after it,
  so a filter sees dt > 1 s, restarts its time base and keeps its orientation.

The output depends only on the sequence of samples pushed, never on wall time or chunking.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from app.stream.protocol import FILTER_TAGS, TAG_PRIORITY, Sample

_MAX_QUIRKS = 20


@dataclass
class OrderStats:
    """Counters of a :class:`TimeOrderer`."""

    pushed: int = 0                 # filter-tag samples pushed
    released: int = 0
    out_of_order: int = 0           # dropped: older than released, or a tag going back in time
    forced: int = 0                 # released early because the buffer bound was reached
    restarts: int = 0               # segments started after the first
    restart_times_ms: list[int] = field(default_factory=list)   # aligned start of the last 100
    clock_quirks: list[str] = field(default_factory=list)
    offsets_ms: dict[str, int] = field(default_factory=dict)    # current tag -> aligned offset

    def copy(self) -> OrderStats:
        return OrderStats(self.pushed, self.released, self.out_of_order, self.forced,
                          self.restarts, list(self.restart_times_ms), list(self.clock_quirks),
                          dict(self.offsets_ms))


class ReferenceTimeOrderer:
    """Streaming reorder + clock alignment of filter-tag samples (see the module docstring),
    in plain Python: the executable specification of :class:`TimeOrderer` (tests compare them).

    push(sample) -> the samples released by it (aligned t_ms), flush() at end of stream.
    """

    def __init__(self, window_ms: int = 100, gap_ms: int = 2000,
                 align_threshold_ms: int = 10_000, max_pending: int = 20_000,
                 restart_gap_ms: int = 1500, startup_hold_ms: int = 250) -> None:
        self.window_ms = int(window_ms)
        self.gap_ms = int(gap_ms)
        self.align_threshold_ms = int(align_threshold_ms)
        self.max_pending = int(max_pending)
        self.restart_gap_ms = int(restart_gap_ms)
        self.startup_hold_ms = int(startup_hold_ms)
        self.stats = OrderStats()
        self._heap: list[tuple[int, int, int, Sample]] = []
        self._sequence = 0
        self.last_released_ms: int | None = None
        self._new_segment(first=True)

    # -- public ------------------------------------------------------------------------------

    def push(self, sample: Sample) -> list[Sample]:
        """Take one sample (any tag); return what it releases, in release order."""
        if sample.tag not in TAG_PRIORITY:
            return [sample]
        out: list[Sample] = []
        self._push(sample, out)
        return out

    def push_many(self, samples: Iterable[Sample]) -> list[Sample]:
        out: list[Sample] = []
        for sample in samples:
            if sample.tag in TAG_PRIORITY:
                self._push(sample, out)
            else:
                out.append(sample)
        return out

    def flush(self) -> list[Sample]:
        """Release everything pending (end of stream). The segment stays open."""
        out: list[Sample] = []
        self._release_all(out)
        return out

    def restart(self) -> list[Sample]:
        """Reconnect: release what is pending and learn the clocks again for what follows."""
        out = self.flush()
        self._new_segment(first=False)
        return out

    @property
    def pending(self) -> int:
        return len(self._heap)

    # -- internals -----------------------------------------------------------------------------

    def _new_segment(self, first: bool) -> None:
        self._offsets: dict[str, int] = {}
        self._last: dict[str, int] = {}          # tag -> latest aligned time in this segment
        self._reference: str | None = None
        self._segment_start: int | None = None
        self._warm = False           # hold releases for startup_hold_ms: lets every tag show up
        self._newest: int | None = None
        self._last_new_tag_ms = 0
        self.stats.offsets_ms = self._offsets
        if not first:
            self.stats.restarts += 1

    def _quirk(self, text: str) -> None:
        quirks = self.stats.clock_quirks
        if text not in quirks:
            quirks.append(text)
            del quirks[:-_MAX_QUIRKS]

    def _learn_offset(self, sample: Sample) -> int:
        raw = sample.t_ms
        if self._reference is None:
            self._reference = sample.tag
            shift = 0
            if self.last_released_ms is not None and raw <= self.last_released_ms:
                shift = self.last_released_ms + self.restart_gap_ms - raw
            if self.stats.restarts or self.last_released_ms is not None:
                times = self.stats.restart_times_ms
                times.append(raw + shift)
                del times[:-100]
            self._segment_start = raw + shift
            return shift
        reference_latest = self._last[self._reference]
        reference_offset = self._offsets[self._reference]
        if abs(raw + reference_offset - reference_latest) > self.align_threshold_ms:
            offset = reference_latest - raw
            # The estimate is off by the batching delay (~10 ms); the known quirk is a whole
            # number of seconds (131,072 s), so snap to one when this close to it.
            whole_seconds = round((offset - reference_offset) / 1000) * 1000 + reference_offset
            if abs(offset - whole_seconds) <= self.window_ms // 2:
                offset = whole_seconds
            difference = -(offset - reference_offset)
            self._quirk(f"{sample.tag} clock {difference:+d} ms vs {self._reference} (aligned)")
            return offset
        return reference_offset

    def _push(self, sample: Sample, out: list[Sample]) -> None:
        stats = self.stats
        stats.pushed += 1
        tag = sample.tag
        offset = self._offsets.get(tag)
        if offset is not None:
            t = sample.t_ms + offset
            last = self._last[tag]
            if t > last + self.gap_ms or t < last - self.gap_ms:
                # A pause, a reboot or another phone: a new time base, same orientation.
                self._release_all(out)
                self._new_segment(first=False)
                offset = None
            elif t < last:
                stats.out_of_order += 1
                return
        if offset is None:
            offset = self._learn_offset(sample)
            self._offsets[tag] = offset
            t = sample.t_ms + offset
            self._last_new_tag_ms = t
        if self.last_released_ms is not None and t < self.last_released_ms:
            stats.out_of_order += 1
            # The tag still moves on: later samples are compared with this one.
            self._last[tag] = t
            return
        self._last[tag] = t
        if self._newest is None or t > self._newest:
            self._newest = t
        if offset:
            sample = sample._replace(t_ms=t)
        self._sequence += 1
        heapq.heappush(self._heap, (t, TAG_PRIORITY[tag], self._sequence, sample))
        if not self._warm:
            # Hold until two tags are there and no new tag has shown up for window_ms (a sensor
            # starting late keeps its first samples): at least startup_hold_ms, at most
            # 4 x startup_hold_ms.
            since_start = self._newest - self._segment_start
            # All four filter tags there: none can start late any more, stop holding.
            if len(self._last) < len(FILTER_TAGS) and len(self._heap) <= self.max_pending \
                    and since_start < 4 * self.startup_hold_ms \
                    and (since_start < self.startup_hold_ms or len(self._last) < 2
                         or self._newest - self._last_new_tag_ms < self.window_ms):
                return
            self._warm = True
        self._release(out)

    def _release(self, out: list[Sample]) -> None:
        heap = self._heap
        threshold = self._newest - self.window_ms
        watermark = None
        for last in self._last.values():
            if last >= threshold and (watermark is None or last < watermark):
                watermark = last
        released = 0
        while heap and heap[0][0] <= watermark:
            out.append(heapq.heappop(heap)[3])
            released += 1
        while len(heap) > self.max_pending:
            out.append(heapq.heappop(heap)[3])
            released += 1
            self.stats.forced += 1
        if released:
            self.last_released_ms = out[-1].t_ms
            self.stats.released += released

    def _release_all(self, out: list[Sample]) -> None:
        heap = self._heap
        if not heap:
            return
        self.stats.released += len(heap)
        while heap:
            out.append(heapq.heappop(heap)[3])
        self.last_released_ms = out[-1].t_ms




# =============================================================================================
# The compiled orderer: the same algorithm on arrays, in one nogil numba call per chunk.

# int64 state layout
_NEWEST = 0
_HAS_NEWEST = 1
_LAST_RELEASED = 2
_HAS_LAST_RELEASED = 3
_REFERENCE = 4              # tag code of the reference clock, -1 = none yet
_SEGMENT_START = 5
_WARM = 6
_LAST_NEW_TAG = 7
_SEQUENCE = 8
_PUSHED = 9
_RELEASED = 10
_OUT_OF_ORDER = 11
_FORCED = 12
_RESTARTS = 13
_HEAP_N = 14
_SEGMENT_ID = 15            # +1 per new segment (the Python side rebuilds its offsets dict)
_RESUME = 16                # 1: the next sample was counted and its offset just learned
_OFFSET = 17                # (4) per tag code
_HAS_OFFSET = 21
_LAST = 25
_HAS_LAST = 29
_STATE_SIZE = 33
# heap key columns (lexicographic order; seq is unique, so the order is total)
_K_T, _K_PRIORITY, _K_SEQ, _K_PAYLOAD = 0, 1, 2, 3

_jit = njit(cache=True, nogil=True)


@_jit
def _less(keys, i, j):
    for c in range(3):
        if keys[i, c] != keys[j, c]:
            return keys[i, c] < keys[j, c]
    return False


@_jit
def _swap(keys, values, i, j):
    for c in range(4):
        keys[i, c], keys[j, c] = keys[j, c], keys[i, c]
        values[i, c], values[j, c] = values[j, c], values[i, c]


@_jit
def _heap_push(st, keys, values, t, priority, seq, payload, v):
    i = st[_HEAP_N]
    st[_HEAP_N] = i + 1
    keys[i, 0] = t
    keys[i, 1] = priority
    keys[i, 2] = seq
    keys[i, 3] = payload
    for c in range(4):
        values[i, c] = v[c]
    while i > 0:
        parent = (i - 1) // 2
        if not _less(keys, i, parent):
            break
        _swap(keys, values, i, parent)
        i = parent


@_jit
def _heap_pop(st, keys, values, out_keys, out_values, k):
    """Move the smallest entry to out[k]."""
    n = st[_HEAP_N] - 1
    for c in range(4):
        out_keys[k, c] = keys[0, c]
        out_values[k, c] = values[0, c]
    st[_HEAP_N] = n
    if n == 0:
        return
    for c in range(4):
        keys[0, c] = keys[n, c]
        values[0, c] = values[n, c]
    i = 0
    while True:
        left = 2 * i + 1
        if left >= n:
            break
        child = left
        if left + 1 < n and _less(keys, left + 1, left):
            child = left + 1
        if not _less(keys, child, i):
            break
        _swap(keys, values, i, child)
        i = child


@_jit
def _release_all(st, keys, values, out_keys, out_values, n_out):
    count = st[_HEAP_N]
    if count == 0:
        return n_out
    st[_RELEASED] += count
    while st[_HEAP_N] > 0:
        _heap_pop(st, keys, values, out_keys, out_values, n_out)
        n_out += 1
    st[_LAST_RELEASED] = out_keys[n_out - 1, _K_T]
    st[_HAS_LAST_RELEASED] = 1
    return n_out


@_jit
def _new_segment(st):
    for tag in range(4):
        st[_OFFSET + tag] = 0
        st[_HAS_OFFSET + tag] = 0
        st[_LAST + tag] = 0
        st[_HAS_LAST + tag] = 0
    st[_REFERENCE] = -1
    st[_SEGMENT_START] = 0
    st[_WARM] = 0
    st[_HAS_NEWEST] = 0
    st[_NEWEST] = 0
    st[_LAST_NEW_TAG] = 0
    st[_SEGMENT_ID] += 1
    st[_RESTARTS] += 1


@_jit
def _release(st, keys, values, window_ms, max_pending, out_keys, out_values, n_out):
    threshold = st[_NEWEST] - window_ms
    watermark = 0
    found = False
    for tag in range(4):
        if st[_HAS_LAST + tag]:
            last = st[_LAST + tag]
            if last >= threshold and (not found or last < watermark):
                watermark = last
                found = True
    first = n_out
    while st[_HEAP_N] > 0 and keys[0, _K_T] <= watermark:
        _heap_pop(st, keys, values, out_keys, out_values, n_out)
        n_out += 1
    while st[_HEAP_N] > max_pending:
        _heap_pop(st, keys, values, out_keys, out_values, n_out)
        n_out += 1
        st[_FORCED] += 1
    if n_out > first:
        st[_LAST_RELEASED] = out_keys[n_out - 1, _K_T]
        st[_HAS_LAST_RELEASED] = 1
        st[_RELEASED] += n_out - first
    return n_out


@_jit
def _push_run(st, keys, values, t_in, tag_in, v_in, payload_in, start, window_ms, gap_ms,
              max_pending, startup_hold_ms, out_keys, out_values, n_out):
    """ReferenceTimeOrderer._push for samples start.. until one needs its clock offset learned
    (done in Python). Returns (entries in out, index of that sample or len(t_in))."""
    n = t_in.shape[0]
    i = start
    while i < n:
        tag = tag_in[i]
        raw = t_in[i]
        if st[_RESUME] == 1:
            st[_RESUME] = 0
            t = raw + st[_OFFSET + tag]
            st[_LAST_NEW_TAG] = t
        else:
            st[_PUSHED] += 1
            if st[_HAS_OFFSET + tag] == 0:
                return n_out, i
            t = raw + st[_OFFSET + tag]
            last = st[_LAST + tag]
            if t > last + gap_ms or t < last - gap_ms:
                # A pause, a reboot or another phone: a new time base, same orientation.
                n_out = _release_all(st, keys, values, out_keys, out_values, n_out)
                _new_segment(st)
                return n_out, i
            if t < last:
                st[_OUT_OF_ORDER] += 1
                i += 1
                continue
        if st[_HAS_LAST_RELEASED] and t < st[_LAST_RELEASED]:
            st[_OUT_OF_ORDER] += 1
            st[_LAST + tag] = t           # the tag still moves on
            st[_HAS_LAST + tag] = 1
            i += 1
            continue
        st[_LAST + tag] = t
        st[_HAS_LAST + tag] = 1
        if st[_HAS_NEWEST] == 0 or t > st[_NEWEST]:
            st[_NEWEST] = t
            st[_HAS_NEWEST] = 1
        st[_SEQUENCE] += 1
        _heap_push(st, keys, values, t, tag, st[_SEQUENCE], payload_in[i], v_in[i])
        i += 1
        if st[_WARM] == 0:
            since_start = st[_NEWEST] - st[_SEGMENT_START]
            tags = 0
            for other in range(4):
                tags += st[_HAS_LAST + other]
            # all four filter tags there: none can start late any more, stop holding
            if tags < 4 and st[_HEAP_N] <= max_pending and since_start < 4 * startup_hold_ms and (
                    since_start < startup_hold_ms or tags < 2
                    or st[_NEWEST] - st[_LAST_NEW_TAG] < window_ms):
                continue
            st[_WARM] = 1
        n_out = _release(st, keys, values, window_ms, max_pending, out_keys, out_values, n_out)
    return n_out, n


@_jit
def _flush(st, keys, values, out_keys, out_values):
    return _release_all(st, keys, values, out_keys, out_values, 0)


@_jit
def _oldest_pending_sequence(st, keys):
    oldest = st[_SEQUENCE] + 1
    for i in range(st[_HEAP_N]):
        if keys[i, _K_SEQ] < oldest:
            oldest = keys[i, _K_SEQ]
    return oldest


@dataclass
class OrderedArrays:
    """Released samples in release order: t_ms (n,) aligned phone ms; tag (n,) codes (GYR 0,
    ACC 1, MAG 2, ORI 3); values (n, 4); seq (n,) push sequence; payload (n,) the caller's id."""

    t_ms: np.ndarray
    tag: np.ndarray
    values: np.ndarray
    seq: np.ndarray
    payload: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ms)

    @staticmethod
    def from_keys(keys: np.ndarray, values: np.ndarray, n: int) -> OrderedArrays:
        return OrderedArrays(keys[:n, _K_T].copy(), keys[:n, _K_PRIORITY].copy(), values[:n].copy(),
                             keys[:n, _K_SEQ].copy(), keys[:n, _K_PAYLOAD].copy())


class TimeOrderer:
    """Streaming reorder + clock alignment of filter-tag samples (see the module docstring).

    The algorithm of :class:`ReferenceTimeOrderer` (same releases, counters and quirk texts)
    run by a nogil numba kernel; only learning a tag's clock offset (a few times per segment)
    runs in Python. Two faces: Samples (:meth:`push`, :meth:`push_many`, :meth:`flush`,
    :meth:`restart`) and arrays (:meth:`push_arrays`, :meth:`flush_arrays`,
    :meth:`restart_arrays`) for the live engine.
    """

    def __init__(self, window_ms: int = 100, gap_ms: int = 2000,
                 align_threshold_ms: int = 10_000, max_pending: int = 20_000,
                 restart_gap_ms: int = 1500, startup_hold_ms: int = 250) -> None:
        self.window_ms = int(window_ms)
        self.gap_ms = int(gap_ms)
        self.align_threshold_ms = int(align_threshold_ms)
        self.max_pending = int(max_pending)
        self.restart_gap_ms = int(restart_gap_ms)
        self.startup_hold_ms = int(startup_hold_ms)
        self.stats = OrderStats()
        self._state = np.zeros(_STATE_SIZE, np.int64)
        self._state[_REFERENCE] = -1
        self._segment_id = 0
        self._offsets: dict[str, int] = {}
        self.stats.offsets_ms = self._offsets
        capacity = self.max_pending + 2
        self._keys = np.zeros((capacity, 4), np.int64)
        self._values = np.zeros((capacity, 4))
        self._payloads: dict[int, Sample] = {}     # Sample face: payload id -> Sample
        self._next_payload = 0

    # -- arrays face -------------------------------------------------------------------------

    def push_arrays(self, t_ms: np.ndarray, tag: np.ndarray, values: np.ndarray,
                    payload: np.ndarray | None = None) -> OrderedArrays:
        """Filter-tag samples (tag codes GYR 0, ACC 1, MAG 2, ORI 3; values (n, 4)) in
        arrival order; returns what they release, in release order."""
        t_ms = np.ascontiguousarray(t_ms, dtype=np.int64)
        tag = np.ascontiguousarray(tag, dtype=np.int64)
        values = np.ascontiguousarray(values, dtype=np.float64).reshape(-1, 4)
        n = len(t_ms)
        if payload is None:
            payload = np.full(n, -1, np.int64)
        state = self._state
        out_keys = np.empty((n + int(state[_HEAP_N]), 4), np.int64)
        out_values = np.empty((len(out_keys), 4))
        n_out, index = 0, 0
        while True:
            n_out, index = _push_run(state, self._keys, self._values, t_ms, tag, values,
                                     payload, index, self.window_ms, self.gap_ms,
                                     self.max_pending, self.startup_hold_ms, out_keys,
                                     out_values, n_out)
            if index >= n:
                break
            self._sync_segment()
            self._learn_offset(int(tag[index]), int(t_ms[index]))
            state[_RESUME] = 1
        self._sync()
        return OrderedArrays.from_keys(out_keys, out_values, n_out)

    def flush_arrays(self) -> OrderedArrays:
        """Release everything pending (end of stream). The segment stays open."""
        count = int(self._state[_HEAP_N])
        out_keys = np.empty((count, 4), np.int64)
        out_values = np.empty((count, 4))
        n_out = _flush(self._state, self._keys, self._values, out_keys, out_values) \
            if count else 0
        self._sync()
        return OrderedArrays.from_keys(out_keys, out_values, n_out)

    def restart_arrays(self) -> OrderedArrays:
        """Reconnect: release what is pending and learn the clocks again for what follows."""
        out = self.flush_arrays()
        _new_segment(self._state)
        self._sync()
        return out

    @property
    def oldest_pending_sequence(self) -> int:
        """The push sequence number of the oldest sample still held (next one when none):
        every sample pushed before it has been released or dropped."""
        return int(_oldest_pending_sequence(self._state, self._keys))

    @property
    def sequence(self) -> int:
        """Sequence number of the latest sample that entered the buffer."""
        return int(self._state[_SEQUENCE])

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

    def restart(self) -> list[Sample]:
        """Reconnect: release what is pending and learn the clocks again for what follows."""
        return self._to_samples(self.restart_arrays())

    @property
    def pending(self) -> int:
        return int(self._state[_HEAP_N])

    @property
    def last_released_ms(self) -> int | None:
        state = self._state
        return int(state[_LAST_RELEASED]) if state[_HAS_LAST_RELEASED] else None

    # -- internals -----------------------------------------------------------------------------

    def _push_samples(self, samples: list[Sample]) -> list[Sample]:
        n = len(samples)
        first = self._next_payload
        self._next_payload += n
        values = np.zeros((n, 4))
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
            held = set(self._keys[:self.pending, _K_PAYLOAD].tolist())
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
        segment = int(self._state[_SEGMENT_ID])
        if segment != self._segment_id:
            self._segment_id = segment
            self._offsets = {}
            self.stats.offsets_ms = self._offsets

    def _sync(self) -> None:
        self._sync_segment()
        state = self._state
        stats = self.stats
        stats.pushed = int(state[_PUSHED])
        stats.released = int(state[_RELEASED])
        stats.out_of_order = int(state[_OUT_OF_ORDER])
        stats.forced = int(state[_FORCED])
        stats.restarts = int(state[_RESTARTS])

    def _quirk(self, text: str) -> None:
        quirks = self.stats.clock_quirks
        if text not in quirks:
            quirks.append(text)
            del quirks[:-_MAX_QUIRKS]

    def _learn_offset(self, tag: int, raw: int) -> None:
        """ReferenceTimeOrderer._learn_offset on the packed state."""
        state = self._state
        name = FILTER_TAGS[tag]
        if state[_REFERENCE] < 0:
            state[_REFERENCE] = tag
            shift = 0
            last_released = self.last_released_ms
            if last_released is not None and raw <= last_released:
                shift = last_released + self.restart_gap_ms - raw
            if state[_RESTARTS] or last_released is not None:
                times = self.stats.restart_times_ms
                times.append(raw + shift)
                del times[:-100]
            state[_SEGMENT_START] = raw + shift
            offset = shift
        else:
            reference = int(state[_REFERENCE])
            reference_latest = int(state[_LAST + reference])
            reference_offset = int(state[_OFFSET + reference])
            offset = reference_offset
            if abs(raw + reference_offset - reference_latest) > self.align_threshold_ms:
                offset = reference_latest - raw
                whole_seconds = round((offset - reference_offset) / 1000) * 1000 \
                    + reference_offset
                if abs(offset - whole_seconds) <= self.window_ms // 2:
                    offset = whole_seconds
                difference = -(offset - reference_offset)
                self._quirk(f"{name} clock {difference:+d} ms vs "
                            f"{FILTER_TAGS[reference]} (aligned)")
        state[_OFFSET + tag] = offset
        state[_HAS_OFFSET + tag] = 1
        self._offsets[name] = offset


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernels before the first chunk arrives."""
    orderer = TimeOrderer()
    orderer.push_arrays(np.array([1000, 1000, 5000]), np.array([0, 1, 0]), np.zeros((3, 4)))
    orderer.restart_arrays()
    _ = orderer.oldest_pending_sequence


__all__ = ["TimeOrderer", "ReferenceTimeOrderer", "OrderStats", "OrderedArrays", "FILTER_TAGS"]
