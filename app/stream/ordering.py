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
  reference tag keeps its offset). A segment whose clock continues the previous one's (later
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
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from app.stream.ordering_reference import (_MAX_QUIRKS, LAG_BUCKET_MS, OrderStats,
                                           ReferenceTimeOrderer, _append_bounded,
                                           effective_window)
from app.stream.protocol import FILTER_TAGS, TAG_PRIORITY, Sample


# =============================================================================================
# The compiled orderer: the same algorithm on arrays, in one nogil numba call per chunk.

# int64 state layout: scalars, then blocks of 4 (one per tag code)
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
_LAG_BUCKET = 17
_HAS_LAG_BUCKET = 18
_OFFSET = 19                # (4) per tag code
_HAS_OFFSET = 23
_LAST = 27
_HAS_LAST = 31
_LATE = 35                  # first sample of the tag's late block
_HAS_LATE = 39
_LAG_CURRENT = 43
_LAG_PREVIOUS = 47
_PREVIOUS_OFFSET = 51       # the offset of the previous segment of this stream
_HAS_PREVIOUS_OFFSET = 55
_STATE_SIZE = 59
# parameters (int64 array)
_P_WINDOW, _P_GAP, _P_MAX_PENDING, _P_HOLD, _P_MAX_WINDOW, _P_HORIZON = range(6)
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
def _new_segment(st, keep_offsets):
    for tag in range(4):
        st[_PREVIOUS_OFFSET + tag] = st[_OFFSET + tag]
        st[_HAS_PREVIOUS_OFFSET + tag] = st[_HAS_OFFSET + tag] if keep_offsets else 0
        for block in (_OFFSET, _HAS_OFFSET, _LAST, _HAS_LAST, _LATE, _HAS_LATE, _LAG_CURRENT,
                      _LAG_PREVIOUS):
            st[block + tag] = 0
    st[_REFERENCE] = -1
    st[_SEGMENT_START] = 0
    st[_WARM] = 0
    st[_HAS_NEWEST] = 0
    st[_NEWEST] = 0
    st[_LAST_NEW_TAG] = 0
    st[_HAS_LAG_BUCKET] = 0
    st[_LAG_BUCKET] = 0
    st[_SEGMENT_ID] += 1
    st[_RESTARTS] += 1


@_jit
def _window(st, params):
    lag = 0
    for tag in range(4):
        lag = max(lag, st[_LAG_CURRENT + tag], st[_LAG_PREVIOUS + tag])
    window = params[_P_WINDOW]
    if lag == 0:
        return window
    return min(params[_P_MAX_WINDOW], max(window, lag + lag // 4 + 10))


@_jit
def _rotate_lags(st):
    bucket = st[_NEWEST] // LAG_BUCKET_MS
    if st[_HAS_LAG_BUCKET] == 0 or bucket != st[_LAG_BUCKET]:
        consecutive = st[_HAS_LAG_BUCKET] == 1 and bucket == st[_LAG_BUCKET] + 1
        for tag in range(4):
            st[_LAG_PREVIOUS + tag] = st[_LAG_CURRENT + tag] if consecutive else 0
            st[_LAG_CURRENT + tag] = 0
        st[_LAG_BUCKET] = bucket
        st[_HAS_LAG_BUCKET] = 1


@_jit
def _release(st, keys, values, params, out_keys, out_values, n_out):
    threshold = st[_NEWEST] - _window(st, params)
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
    while st[_HEAP_N] > params[_P_MAX_PENDING]:
        _heap_pop(st, keys, values, out_keys, out_values, n_out)
        n_out += 1
        st[_FORCED] += 1
    if n_out > first:
        st[_LAST_RELEASED] = out_keys[n_out - 1, _K_T]
        st[_HAS_LAST_RELEASED] = 1
        st[_RELEASED] += n_out - first
    return n_out


@_jit
def _own_clock(st, tag, t, params):
    """ReferenceTimeOrderer._own_clock: 0 ok, 1 drop, 2 new segment."""
    last = st[_LAST + tag]
    gap = params[_P_GAP]
    if t < last - gap:
        if last - t > params[_P_HORIZON]:
            return 2
        if st[_HAS_LATE + tag] == 0:
            st[_LATE + tag] = t
            st[_HAS_LATE + tag] = 1
            return 1
        return 1 if t - st[_LATE + tag] <= gap else 2
    if t > last + gap:
        return 2
    if t < last:
        return 1
    st[_HAS_LATE + tag] = 0
    return 0


@_jit
def _holding(st, params):
    since_start = st[_NEWEST] - st[_SEGMENT_START]
    tags = 0
    for other in range(4):
        tags += st[_HAS_LAST + other]
    hold = params[_P_HOLD]
    return (tags < 4 and st[_HEAP_N] <= params[_P_MAX_PENDING] and since_start < 4 * hold and (
        since_start < hold or tags < 2 or st[_NEWEST] - st[_LAST_NEW_TAG] < params[_P_WINDOW]))


@_jit
def _lags_behind_newcomer(st, tag, t, max_window):
    """A tag showing up ahead of the others: they are this far behind it."""
    for other in range(4):
        if other != tag and st[_HAS_LAST + other]:
            behind = t - st[_LAST + other]
            if 0 < behind <= max_window and behind > st[_LAG_CURRENT + other]:
                st[_LAG_CURRENT + other] = behind


@_jit
def _push_run(st, keys, values, t_in, tag_in, v_in, payload_in, start, params, out_keys,
              out_values, n_out):
    """ReferenceTimeOrderer._push for samples start.. until one needs its clock offset learned
    (done in Python). Returns (entries in out, index of that sample or len(t_in))."""
    n = t_in.shape[0]
    i = start
    while i < n:
        tag = tag_in[i]
        raw = t_in[i]
        first_of_tag = st[_RESUME] == 1
        if first_of_tag:
            st[_RESUME] = 0
            t = raw + st[_OFFSET + tag]
            st[_LAST_NEW_TAG] = t
        else:
            st[_PUSHED] += 1
            if st[_HAS_OFFSET + tag] == 0:
                return n_out, i
            t = raw + st[_OFFSET + tag]
            verdict = _own_clock(st, tag, t, params)
            if verdict == 1:
                st[_OUT_OF_ORDER] += 1
                i += 1
                continue
            if verdict == 2:
                # A pause, a reboot or another phone: a new time base.
                n_out = _release_all(st, keys, values, out_keys, out_values, n_out)
                _new_segment(st, 1)
                return n_out, i
        if st[_HAS_NEWEST]:
            lateness = st[_NEWEST] - t
            if 0 < lateness <= params[_P_MAX_WINDOW] and lateness > st[_LAG_CURRENT + tag]:
                st[_LAG_CURRENT + tag] = lateness
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
            _rotate_lags(st)
            if first_of_tag:
                _lags_behind_newcomer(st, tag, t, params[_P_MAX_WINDOW])
        st[_SEQUENCE] += 1
        _heap_push(st, keys, values, t, tag, st[_SEQUENCE], payload_in[i], v_in[i])
        i += 1
        if st[_WARM] == 0:
            if _holding(st, params):
                continue
            st[_WARM] = 1
        n_out = _release(st, keys, values, params, out_keys, out_values, n_out)
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
        return OrderedArrays(keys[:n, _K_T].copy(), keys[:n, _K_PRIORITY].copy(), values[:n].copy(),
                             keys[:n, _K_SEQ].copy(), keys[:n, _K_PAYLOAD].copy(),
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

    def __init__(self, window_ms: int = 100, gap_ms: int = 2000,
                 align_threshold_ms: int = 250, max_pending: int = 20_000,
                 restart_gap_ms: int = 1500, startup_hold_ms: int = 250,
                 max_window_ms: int = 500, late_horizon_ms: int = 10_000,
                 session_gap_ms: int = 600_000) -> None:
        self.window_ms = int(window_ms)
        self.gap_ms = int(gap_ms)
        self.align_threshold_ms = int(align_threshold_ms)
        self.max_pending = int(max_pending)
        self.restart_gap_ms = int(restart_gap_ms)
        self.startup_hold_ms = int(startup_hold_ms)
        self.max_window_ms = max(int(max_window_ms), self.window_ms)
        self.late_horizon_ms = int(late_horizon_ms)
        self.session_gap_ms = int(session_gap_ms)
        self._params = np.array([self.window_ms, self.gap_ms, self.max_pending,
                                 self.startup_hold_ms, self.max_window_ms,
                                 self.late_horizon_ms], np.int64)
        self.stats = OrderStats(window_ms=self.window_ms)
        self._state = np.zeros(_STATE_SIZE, np.int64)
        self._state[_REFERENCE] = -1
        self._segment_id = 0
        self._offsets: dict[str, int] = {}
        self._continue_time = False
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
        session_starts: list[int] = []
        while True:
            n_out, index = _push_run(state, self._keys, self._values, t_ms, tag, values,
                                     payload, index, self._params, out_keys, out_values, n_out)
            if index >= n:
                break
            self._sync_segment()
            if self._learn_offset(int(tag[index]), int(t_ms[index])):
                session_starts.append(n_out)
            state[_RESUME] = 1
        self._sync()
        return OrderedArrays.from_keys(out_keys, out_values, n_out, session_starts)

    def flush_arrays(self) -> OrderedArrays:
        """Release everything pending (end of stream). The segment stays open."""
        count = int(self._state[_HEAP_N])
        out_keys = np.empty((count, 4), np.int64)
        out_values = np.empty((count, 4))
        n_out = _flush(self._state, self._keys, self._values, out_keys, out_values) \
            if count else 0
        self._sync()
        return OrderedArrays.from_keys(out_keys, out_values, n_out)

    def restart_arrays(self, continue_time: bool = False) -> OrderedArrays:
        """Reconnect: release what is pending and learn the clocks again for what follows
        (continue_time: see :meth:`ReferenceTimeOrderer.restart`)."""
        out = self.flush_arrays()
        _new_segment(self._state, 0)
        self._continue_time = bool(continue_time)
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

    def snapshot(self) -> dict:
        """The arrays face's whole state (copies: the packed state, the samples held, the learned
        clock offsets), to continue later from exactly here with :meth:`restore` (a replay's
        checkpoints). Statistics are not part of it."""
        held = int(self._state[_HEAP_N])
        return {"state": self._state.copy(), "keys": self._keys[:held].copy(),
                "values": self._values[:held].copy(), "segment_id": self._segment_id,
                "offsets": dict(self._offsets), "continue_time": self._continue_time}

    def restore(self, snapshot: dict) -> None:
        """Continue from a :meth:`snapshot` of an orderer with the same parameters (the counters
        in :attr:`stats` follow the restored state)."""
        state = np.asarray(snapshot["state"], np.int64)
        held = len(snapshot["keys"])
        if state.shape != (_STATE_SIZE,) or held > len(self._keys) or held != state[_HEAP_N]:
            raise ValueError("not a snapshot of this orderer")
        self._state[:] = state
        self._keys[:held] = snapshot["keys"]
        self._values[:held] = snapshot["values"]
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
        lags = [max(int(state[_LAG_CURRENT + c]), int(state[_LAG_PREVIOUS + c]))
                for c in range(4)]
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
        state[_REFERENCE] = tag
        base = int(state[_PREVIOUS_OFFSET + tag]) if state[_HAS_PREVIOUS_OFFSET + tag] else 0
        t = raw + base
        shift = 0
        new_session = False
        last = self.last_released_ms
        if last is not None:
            if self._continue_time:
                if t <= last:
                    shift = last + self.restart_gap_ms - t
            elif t <= last or t - last > self.session_gap_ms:
                state[_HAS_LAST_RELEASED] = 0
                self.stats.sessions += 1
                _append_bounded(self.stats.session_starts, int(state[_RELEASED]))
                new_session = True
        self._continue_time = False
        if state[_RESTARTS] or last is not None:
            _append_bounded(self.stats.restart_times_ms, t + shift)
        state[_SEGMENT_START] = t + shift
        return base + shift, new_session

    def _learn_offset(self, tag: int, raw: int) -> bool:
        """ReferenceTimeOrderer._learn_offset on the packed state; True when a new session
        starts with this sample."""
        state = self._state
        name = FILTER_TAGS[tag]
        new_session = False
        if state[_REFERENCE] < 0:
            offset, new_session = self._start_segment_clock(tag, raw)
        else:
            reference = int(state[_REFERENCE])
            reference_latest = int(state[_LAST + reference])
            reference_offset = int(state[_OFFSET + reference])
            offset = reference_offset
            if abs(raw + reference_offset - reference_latest) > self.align_threshold_ms:
                offset = next((int(state[_OFFSET + other]) for other in range(4)
                               if state[_HAS_OFFSET + other] and abs(
                                   raw + int(state[_OFFSET + other]) - reference_latest)
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
        state[_OFFSET + tag] = offset
        state[_HAS_OFFSET + tag] = 1
        self._offsets[name] = offset
        return new_session


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernels before the first chunk arrives."""
    orderer = TimeOrderer()
    orderer.push_arrays(np.array([1000, 1000, 5000]), np.array([0, 1, 0]), np.zeros((3, 4)))
    orderer.restart_arrays()
    _ = orderer.oldest_pending_sequence


__all__ = ["TimeOrderer", "ReferenceTimeOrderer", "OrderStats", "OrderedArrays", "FILTER_TAGS",
           "effective_window"]
