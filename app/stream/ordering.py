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

The algorithm is written twice, as twins: :class:`TimeOrderer` runs it on a packed state (one
int64 array) in nogil numba kernels, learning a tag's clock offset (a few times per segment)
in Python; :class:`app.stream.ordering_reference.ReferenceTimeOrderer` is its executable
specification in plain Python. The kernels below named without a leading underscore are the
steps of the algorithm, in the order the reference defines them as methods (a test compares
the names; the steps the compiled twin runs in Python are :class:`TimeOrderer` methods of the
same name). What both twins share is the first section of this module: the parameters
(:class:`OrderOptions`), the counters (:class:`OrderStats`), the window rule
(:func:`effective_window`) and the clock alignment (:func:`segment_clock`,
:func:`clock_offset`).
"""

from __future__ import annotations

from collections import namedtuple
from collections.abc import Iterable
from dataclasses import dataclass, field, fields, replace

import numpy as np

from ekf.fast.jit import check_cache

from app.stream.protocol import (FILTER_TAGS, MAX_WIDTH, N_FILTER_TAGS, TABLE_KEY, TAG_CODES,
                                 Sample, jit)


#: Clock quirks kept in OrderStats.clock_quirks (the latest ones).
MAX_QUIRKS = 20
LAG_BUCKET_MS = 5000     # lags are the largest of the current and the previous 5 s of phone time


@dataclass(frozen=True)
class OrderOptions:
    """The orderers' parameters, in phone ms (their meaning: :mod:`app.stream.ordering`).

    window_ms: the least reorder window; gap_ms: a tag's own clock jumping this far starts a
    new segment; align_threshold_ms: a tag starting this far from the reference clock is on
    another clock; max_pending: samples held at most; restart_gap_ms: the pause a looping
    replay gets; startup_hold_ms: the start-up hold; max_window_ms: the largest window (at
    least window_ms); late_horizon_ms: how far back a late block may lie; session_gap_ms: a
    segment starting this much later than the last release starts a new session."""

    window_ms: int = 100
    gap_ms: int = 2000
    align_threshold_ms: int = 250
    max_pending: int = 20_000
    restart_gap_ms: int = 1500
    startup_hold_ms: int = 250
    max_window_ms: int = 500
    late_horizon_ms: int = 10_000
    session_gap_ms: int = 600_000

    def __post_init__(self) -> None:
        for item in fields(self):
            object.__setattr__(self, item.name, int(getattr(self, item.name)))
        object.__setattr__(self, "max_window_ms", max(self.max_window_ms, self.window_ms))

    @staticmethod
    def of(options: OrderOptions | None = None, **overrides: int) -> OrderOptions:
        """`options` (default: the defaults) with `overrides` by field name (TypeError for a
        name that is none)."""
        return replace(options or OrderOptions(), **overrides)


@dataclass
class OrderStats:
    """Counters of a :class:`TimeOrderer`."""

    pushed: int = 0                 # filter-tag samples pushed
    released: int = 0
    out_of_order: int = 0           # dropped: older than released, a tag going back, late blocks
    forced: int = 0                 # released early because the buffer bound was reached
    restarts: int = 0               # segments started after the first
    restart_times_ms: list[int] = field(default_factory=list)   # aligned start of the last 100
    clock_quirks: list[str] = field(default_factory=list)
    offsets_ms: dict[str, int] = field(default_factory=dict)    # current tag -> aligned offset
    sessions: int = 0               # new sessions (a clock that did not continue) after the first
    session_starts: list[int] = field(default_factory=list)     # `released` at the last 100
    window_ms: int = 0              # the reorder window now
    lags_ms: dict[str, int] = field(default_factory=dict)       # tag -> learned lag (> 0 only)

    def note_clock(self, tag: str, reference: str, offset_ms: int) -> None:
        """`tag` was aligned to the reference clock with `offset_ms` more than the reference's
        own offset (a clock quirk, said once)."""
        text = f"{tag} clock {-offset_ms:+d} ms vs {reference} (aligned)"
        if text not in self.clock_quirks:
            _append_bounded(self.clock_quirks, text, MAX_QUIRKS)

    def start_session(self, released: int) -> None:
        """A new session starts after `released` samples."""
        self.sessions += 1
        _append_bounded(self.session_starts, released)

    def start_segment(self, t_ms: int) -> None:
        """A segment after the first starts at aligned time `t_ms`."""
        _append_bounded(self.restart_times_ms, t_ms)

    def copy(self) -> OrderStats:
        return OrderStats(self.pushed, self.released, self.out_of_order, self.forced,
                          self.restarts, list(self.restart_times_ms), list(self.clock_quirks),
                          dict(self.offsets_ms), self.sessions, list(self.session_starts),
                          self.window_ms, dict(self.lags_ms))


@jit
def effective_window(lag_ms: int, window_ms: int, max_window_ms: int) -> int:
    """The reorder window for the largest learned lag (0: none learned). Compiled: the kernels
    and both twins' statistics call it."""
    if lag_ms == 0:
        return window_ms
    return min(max_window_ms, max(window_ms, lag_ms + lag_ms // 4 + 10))


def _append_bounded(values: list, value, keep: int = 100) -> None:
    values.append(value)
    del values[:-keep]


def segment_clock(t: int, last_released: int | None, continue_time: bool,
                  options: OrderOptions) -> tuple[int, bool]:
    """The reference tag of a new segment, its first sample at time t (its previous offset in
    this stream applied): (the shift of the segment's times, whether a new session starts).

    A clock that does not continue the previous one (at or before the last release, or later
    by more than session_gap_ms) starts a new session, on its own times (never shifted by an
    earlier stream's); the consumer starts afresh. continue_time (a looping replay) shifts a
    segment that does not continue to start restart_gap_ms after the last release instead."""
    if last_released is None:
        return 0, False
    if continue_time:
        return (last_released + options.restart_gap_ms - t if t <= last_released else 0), False
    return 0, t <= last_released or t - last_released > options.session_gap_ms


def clock_offset(raw: int, reference_latest: int, reference_offset: int,
                 offsets: Iterable[int], options: OrderOptions) -> int | None:
    """A tag's first sample in a segment, at raw time `raw` on its own clock: its clock offset,
    or None when it is on the reference tag's clock (whose latest aligned time and offset are
    given). `offsets`: the offsets learned in the segment, in tag code order."""
    threshold = options.align_threshold_ms
    if abs(raw + reference_offset - reference_latest) <= threshold:
        return None
    # Another tag's clock (a phone's GYR and MAG share one)? Then its offset, exactly.
    offset = next((other for other in offsets
                   if abs(raw + other - reference_latest) <= threshold), None)
    if offset is None:
        offset = reference_latest - raw
        # The estimate is off by the batching delay (~10 ms); the known quirk is a whole
        # number of seconds (131,072 s), so snap to one when this close to it.
        whole_seconds = round((offset - reference_offset) / 1000) * 1000 + reference_offset
        if abs(offset - whole_seconds) <= options.window_ms // 2:
            offset = whole_seconds
    return offset


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


# -- the compiled twin's packed state ----------------------------------------------------------
#
# Its state is one int64 array; ``S`` gives the offsets into it (never numbered by hand): the
# scalars of SCALARS, then for each name in PER_TAG one slot per filter tag code
# (app.stream.protocol.FILTER_TAGS), so ``st[S.last + tag]`` is tag's latest aligned time.
# ``P`` indexes the int64 parameters array (PARAMETERS, fields of OrderOptions), ``K`` the
# columns of a held sample's key (time, priority = tag code, push sequence, the caller's
# payload id; compared in that order), ``U`` a held suspect's. numba freezes these namedtuples
# as compile-time constants.

#: The state's scalars: name, meaning.
SCALARS: tuple[tuple[str, str], ...] = (
    ("newest", "the newest aligned time pushed"),
    ("has_newest", "1: newest is set"),
    ("last_released", "the time of the latest released sample"),
    ("has_last_released", "1: last_released is set"),
    ("reference", "the tag code of the reference clock, -1: none yet"),
    ("segment_start", "the aligned time the segment started at"),
    ("warm", "1: the start-up hold is over"),
    ("last_new_tag", "the time a tag was last seen for the first time in the segment"),
    ("sequence", "the push sequence number of the latest sample held"),
    ("pushed", "samples pushed (stats.pushed)"),
    ("released", "samples released (stats.released)"),
    ("out_of_order", "samples dropped (stats.out_of_order)"),
    ("forced", "releases forced by max_pending (stats.forced)"),
    ("restarts", "segments started (stats.restarts)"),
    ("heap_n", "samples held"),
    ("segment_id", "+1 per new segment (the Python side rebuilds its offsets dict)"),
    ("resume", "1: the next sample was counted and its offset just learned"),
    ("lag_bucket", "the phone-time bucket of lag_current"),
    ("has_lag_bucket", "1: lag_bucket is set"),
    ("suspects", "samples held because their own clock jumped (rows of the suspect arrays)"),
)
#: The state's blocks with one slot per filter tag code: name, meaning.
PER_TAG: tuple[tuple[str, str], ...] = (
    ("offset", "the tag's clock offset"),
    ("has_offset", "1: offset learned"),
    ("last", "the tag's latest aligned time"),
    ("has_last", "1: last is set"),
    ("late", "the first sample of the tag's late block"),
    ("has_late", "1: a late block runs"),
    ("lag_current", "the tag's largest lag in the current bucket"),
    ("lag_previous", "... in the previous bucket"),
    ("previous_offset", "the offset of the previous segment of this stream"),
    ("has_previous_offset", "1: previous_offset applies"),
    ("suspect_count", "the tag's held samples"),
    ("suspect_first", "the aligned time of the first of them"),
    ("suspect_last", "the aligned time of the latest of them"),
)
#: The parameters array: OrderOptions fields in this order.
PARAMETERS = ("window_ms", "gap_ms", "max_pending", "startup_hold_ms", "max_window_ms",
              "late_horizon_ms")
#: A held sample's key columns, compared lexicographically up to payload.
KEY_COLUMNS = ("t", "priority", "seq", "payload")
K_COLUMNS = len(KEY_COLUMNS)
#: A suspect's columns (a sample whose own clock jumped, as it was pushed): its raw time,
#: tag code and the caller's payload id; its values are kept beside them.
SUSPECT_COLUMNS = ("raw", "tag", "payload")


def _offsets() -> dict[str, int]:
    offsets: dict[str, int] = {}
    for name, _ in SCALARS:
        offsets[name] = len(offsets)
    size = len(SCALARS)
    for name, _ in PER_TAG:
        offsets[name] = size
        size += N_FILTER_TAGS
    offsets["size"] = size
    return offsets


S = namedtuple("StateLayout", _offsets())(**_offsets())
P = namedtuple("Parameters", PARAMETERS)(*range(len(PARAMETERS)))
K = namedtuple("KeyColumns", KEY_COLUMNS)(*range(K_COLUMNS))
U = namedtuple("SuspectColumns", SUSPECT_COLUMNS)(*range(len(SUSPECT_COLUMNS)))


# -- the compiled twin: heap helpers, then the steps in the reference's order ---------------------

@jit
def _less(keys, i, j):
    for c in range(K.payload):         # t, priority, seq: seq is unique, so the order is total
        if keys[i, c] != keys[j, c]:
            return keys[i, c] < keys[j, c]
    return False


@jit
def _swap(keys, values, i, j):
    for c in range(K_COLUMNS):
        keys[i, c], keys[j, c] = keys[j, c], keys[i, c]
    for c in range(MAX_WIDTH):
        values[i, c], values[j, c] = values[j, c], values[i, c]


@jit
def _heap_push(st, keys, values, t, priority, seq, payload, v):
    i = st[S.heap_n]
    st[S.heap_n] = i + 1
    keys[i, K.t] = t
    keys[i, K.priority] = priority
    keys[i, K.seq] = seq
    keys[i, K.payload] = payload
    for c in range(MAX_WIDTH):
        values[i, c] = v[c]
    while i > 0:
        parent = (i - 1) // 2
        if not _less(keys, i, parent):
            break
        _swap(keys, values, i, parent)
        i = parent


@jit
def _heap_pop(st, keys, values, out_keys, out_values, k):
    """Move the smallest entry to out[k]."""
    n = st[S.heap_n] - 1
    for c in range(K_COLUMNS):
        out_keys[k, c] = keys[0, c]
    for c in range(MAX_WIDTH):
        out_values[k, c] = values[0, c]
    st[S.heap_n] = n
    if n == 0:
        return
    for c in range(K_COLUMNS):
        keys[0, c] = keys[n, c]
    for c in range(MAX_WIDTH):
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


@jit
def _clear_suspects(st):
    st[S.suspects] = 0
    for tag in range(N_FILTER_TAGS):
        st[S.suspect_count + tag] = 0


@jit
def new_segment(st, keep_offsets):
    for tag in range(N_FILTER_TAGS):
        st[S.previous_offset + tag] = st[S.offset + tag]
        st[S.has_previous_offset + tag] = st[S.has_offset + tag] if keep_offsets else 0
        for block in (S.offset, S.has_offset, S.last, S.has_last, S.late, S.has_late,
                      S.lag_current, S.lag_previous):
            st[block + tag] = 0
    st[S.reference] = -1
    st[S.segment_start] = 0
    st[S.warm] = 0
    st[S.has_newest] = 0
    st[S.newest] = 0
    st[S.last_new_tag] = 0
    st[S.has_lag_bucket] = 0
    st[S.lag_bucket] = 0
    st[S.segment_id] += 1
    st[S.restarts] += 1


@jit
def window(st, params):
    lag = 0
    for tag in range(N_FILTER_TAGS):
        lag = max(lag, st[S.lag_current + tag], st[S.lag_previous + tag])
    return effective_window(lag, params[P.window_ms], params[P.max_window_ms])


@jit
def late(st, tag, t, last, params):
    """A sample more than gap_ms behind its tag's latest: a block written late (dropped),
    unless beyond the horizon or such samples have gone on for more than gap_ms of their own
    time (then the clock really went back)."""
    if last - t > params[P.late_horizon_ms]:
        return False
    if st[S.has_late + tag] == 0:
        st[S.late + tag] = t
        st[S.has_late + tag] = 1
        return True
    return t - st[S.late + tag] <= params[P.gap_ms]


@jit
def own_clock(st, tag, t, params):
    """0 ok, 1 drop (counted), 2 new segment, for a sample at aligned time t of a tag already
    seen in this segment."""
    last = st[S.last + tag]
    gap = params[P.gap_ms]
    if t < last - gap:
        return 1 if late(st, tag, t, last, params) else 2
    if t > last + gap:
        return 2
    if t < last:
        return 1
    st[S.has_late + tag] = 0
    return 0


@jit
def place(st, keys, values, sus, sus_values, t_in, tag_in, v_in, payload_in, start, counted,
          params, out_keys, out_values, n_out):
    """Place samples start.. until one needs its clock offset learned (done in Python) or held
    samples start a new segment. Samples before index `counted` are such held samples pushed
    again (not counted in pushed). Returns (entries in out, index of the sample to learn or of
    the next one after a confirmed jump or len(t_in), the number of held samples to push again
    before it: 0 unless a jump was confirmed)."""
    n = t_in.shape[0]
    i = start
    while i < n:
        tag = tag_in[i]
        raw = t_in[i]
        first_of_tag = st[S.resume] == 1
        if first_of_tag:
            st[S.resume] = 0
            t = raw + st[S.offset + tag]
            st[S.last_new_tag] = t
        else:
            if i >= counted:
                st[S.pushed] += 1
            if st[S.has_offset + tag] == 0:
                return n_out, i, 0
            t = raw + st[S.offset + tag]
            verdict = own_clock(st, tag, t, params)
            if verdict == 2:
                # A pause, a reboot or another phone -- or one bad time stamp: held until
                # another sample confirms the new clock or the tag's old clock goes on.
                if suspect(st, sus, sus_values, raw, tag, t, payload_in[i], v_in[i], params):
                    held = st[S.suspects]
                    _clear_suspects(st)
                    n_out = release_all(st, keys, values, out_keys, out_values, n_out)
                    new_segment(st, 1)
                    return n_out, i + 1, held
                i += 1
                continue
            if st[S.suspect_count + tag] > 0:
                refute(st, sus, sus_values, tag)
            if verdict == 1:
                st[S.out_of_order] += 1
                i += 1
                continue
        if st[S.has_newest]:
            lateness = st[S.newest] - t
            if 0 < lateness <= params[P.max_window_ms] and lateness > st[S.lag_current + tag]:
                st[S.lag_current + tag] = lateness
        if st[S.has_last_released] and t < st[S.last_released]:
            st[S.out_of_order] += 1
            st[S.last + tag] = t           # the tag still moves on
            st[S.has_last + tag] = 1
            i += 1
            continue
        st[S.last + tag] = t
        st[S.has_last + tag] = 1
        if st[S.has_newest] == 0 or t > st[S.newest]:
            st[S.newest] = t
            st[S.has_newest] = 1
            rotate_lags(st)
            if first_of_tag:
                lags_behind_newcomer(st, tag, t, params[P.max_window_ms])
        st[S.sequence] += 1
        _heap_push(st, keys, values, t, tag, st[S.sequence], payload_in[i], v_in[i])
        i += 1
        if st[S.warm] == 0:
            if holding(st, params):
                continue
            st[S.warm] = 1
        n_out = release(st, keys, values, params, out_keys, out_values, n_out)
    return n_out, n, 0


@jit
def lags_behind_newcomer(st, tag, t, max_window):
    """A tag showing up ahead of the others: they are this far behind it."""
    for other in range(N_FILTER_TAGS):
        if other != tag and st[S.has_last + other]:
            behind = t - st[S.last + other]
            if 0 < behind <= max_window and behind > st[S.lag_current + other]:
                st[S.lag_current + other] = behind


@jit
def suspect(st, sus, sus_values, raw, tag, t, payload, v, params):
    """Hold a sample whose own clock jumped; True when the jump is confirmed (the caller then
    starts the new segment with the held samples)."""
    k = st[S.suspects]
    sus[k, U.raw] = raw
    sus[k, U.tag] = tag
    sus[k, U.payload] = payload
    for c in range(MAX_WIDTH):
        sus_values[k, c] = v[c]
    st[S.suspects] = k + 1
    if st[S.suspect_count + tag] == 0:
        st[S.suspect_first + tag] = t
    st[S.suspect_last + tag] = t
    st[S.suspect_count + tag] += 1
    gap = params[P.gap_ms]
    alone = True
    for other in range(N_FILTER_TAGS):
        if other == tag:
            continue
        if st[S.suspect_count + other] > 0 and abs(t - st[S.suspect_last + other]) <= gap:
            return True
        if st[S.has_last + other]:
            alone = False
    return (alone or abs(t - st[S.suspect_first + tag]) > gap
            or st[S.suspects] + st[S.heap_n] > params[P.max_pending])


@jit
def refute(st, sus, sus_values, tag):
    """The tag's clock went on where it was: its held samples were bad time stamps (dropped,
    counted)."""
    kept = 0
    for k in range(st[S.suspects]):
        if sus[k, U.tag] == tag:
            continue
        if kept != k:
            for c in range(sus.shape[1]):
                sus[kept, c] = sus[k, c]
            for c in range(MAX_WIDTH):
                sus_values[kept, c] = sus_values[k, c]
        kept += 1
    st[S.out_of_order] += st[S.suspects] - kept
    st[S.suspects] = kept
    st[S.suspect_count + tag] = 0


@jit
def holding(st, params):
    since_start = st[S.newest] - st[S.segment_start]
    tags = 0
    for other in range(N_FILTER_TAGS):
        tags += st[S.has_last + other]
    hold = params[P.startup_hold_ms]
    return (tags < N_FILTER_TAGS and st[S.heap_n] <= params[P.max_pending]
            and since_start < 4 * hold
            and (since_start < hold or tags < 2
                 or st[S.newest] - st[S.last_new_tag] < params[P.window_ms]))


@jit
def rotate_lags(st):
    bucket = st[S.newest] // LAG_BUCKET_MS
    if st[S.has_lag_bucket] == 0 or bucket != st[S.lag_bucket]:
        consecutive = st[S.has_lag_bucket] == 1 and bucket == st[S.lag_bucket] + 1
        for tag in range(N_FILTER_TAGS):
            st[S.lag_previous + tag] = st[S.lag_current + tag] if consecutive else 0
            st[S.lag_current + tag] = 0
        st[S.lag_bucket] = bucket
        st[S.has_lag_bucket] = 1


@jit
def release(st, keys, values, params, out_keys, out_values, n_out):
    threshold = st[S.newest] - window(st, params)
    watermark = 0
    found = False
    for tag in range(N_FILTER_TAGS):
        if st[S.has_last + tag]:
            last = st[S.last + tag]
            if last >= threshold and (not found or last < watermark):
                watermark = last
                found = True
    first = n_out
    while st[S.heap_n] > 0 and keys[0, K.t] <= watermark:
        _heap_pop(st, keys, values, out_keys, out_values, n_out)
        n_out += 1
    while st[S.heap_n] > params[P.max_pending]:
        _heap_pop(st, keys, values, out_keys, out_values, n_out)
        n_out += 1
        st[S.forced] += 1
    if n_out > first:
        st[S.last_released] = out_keys[n_out - 1, K.t]
        st[S.has_last_released] = 1
        st[S.released] += n_out - first
    return n_out


@jit
def release_all(st, keys, values, out_keys, out_values, n_out):
    count = st[S.heap_n]
    if count == 0:
        return n_out
    st[S.released] += count
    while st[S.heap_n] > 0:
        _heap_pop(st, keys, values, out_keys, out_values, n_out)
        n_out += 1
    st[S.last_released] = out_keys[n_out - 1, K.t]
    st[S.has_last_released] = 1
    return n_out


@jit
def _oldest_pending_sequence(st, keys):
    oldest = st[S.sequence] + 1
    for i in range(st[S.heap_n]):
        if keys[i, K.seq] < oldest:
            oldest = keys[i, K.seq]
    return oldest


class TimeOrderer:
    """Streaming reorder + clock alignment of filter-tag samples (see the module docstring).

    The algorithm of :class:`~app.stream.ordering_reference.ReferenceTimeOrderer` (same
    releases, counters and quirk texts) run by nogil numba kernels; only learning a tag's clock
    offset (a few times per segment) runs in Python. Two faces: Samples (:meth:`push`,
    :meth:`push_many`, :meth:`flush`, :meth:`restart`) and arrays (:meth:`push_arrays`,
    :meth:`flush_arrays`, :meth:`restart_arrays`) for the live engine.
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
            n_out, index, held = place(state, self._keys, self._values, self._suspects,
                                       self._suspect_values, t_ms, tag, values, payload, index,
                                       counted, self._params, out_keys, out_values, n_out)
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
        self._update_stats()
        return OrderedArrays.from_keys(out_keys, out_values, n_out, session_starts)

    def flush_arrays(self) -> OrderedArrays:
        """Release everything pending (end of stream). The segment stays open; samples whose
        jump no other sample confirmed are dropped (counted)."""
        self._state[S.out_of_order] += self._state[S.suspects]
        _clear_suspects(self._state)
        count = int(self._state[S.heap_n])
        out_keys = np.empty((count, K_COLUMNS), np.int64)
        out_values = np.empty((count, MAX_WIDTH))
        n_out = release_all(self._state, self._keys, self._values, out_keys, out_values, 0) \
            if count else 0
        self._update_stats()
        return OrderedArrays.from_keys(out_keys, out_values, n_out)

    def restart_arrays(self, continue_time: bool = False) -> OrderedArrays:
        """Reconnect: release what is pending and learn the clocks again for what follows
        (continue_time: a looping replay shifts the next segment after the last release
        instead of starting a new session when its clock goes back)."""
        out = self.flush_arrays()
        new_segment(self._state, 0)
        self._continue_time = bool(continue_time)
        self._update_stats()
        return out

    @property
    def oldest_pending_sequence(self) -> int:
        """The push sequence number of the oldest sample still in the reorder buffer (the
        next one when none): every sample that entered the buffer before it has been released.
        (A sample held because its own clock jumped enters the buffer once the jump is
        confirmed.)"""
        return int(_oldest_pending_sequence(self._state, self._keys))

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
        self._update_stats()

    # -- Sample face ---------------------------------------------------------------------------

    def push(self, sample: Sample) -> list[Sample]:
        """Take one sample (any tag); return what it releases, in release order."""
        if sample.tag not in TAG_CODES:
            return [sample]
        return self._push_samples([sample])

    def push_many(self, samples: Iterable[Sample]) -> list[Sample]:
        out: list[Sample] = []
        run: list[Sample] = []
        for sample in samples:
            if sample.tag in TAG_CODES:
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
                               np.fromiter((TAG_CODES[s.tag] for s in samples), np.int64, n),
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

    def _update_stats(self) -> None:
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

    def _start_segment_clock(self, tag: int, raw: int) -> tuple[int, bool]:
        """The reference tag of a new segment: (its offset, whether a new session starts)."""
        state = self._state
        state[S.reference] = tag
        base = int(state[S.previous_offset + tag]) if state[S.has_previous_offset + tag] else 0
        t = raw + base
        last = self.last_released_ms
        shift, new_session = segment_clock(t, last, self._continue_time, self.options)
        if new_session:
            state[S.has_last_released] = 0
            self.stats.start_session(int(state[S.released]))
        self._continue_time = False
        if state[S.restarts] or last is not None:
            self.stats.start_segment(t + shift)
        state[S.segment_start] = t + shift
        return base + shift, new_session

    def _learn_offset(self, tag: int, raw: int) -> bool:
        """The clock offset of a tag's first sample in the segment; True when a new session
        starts with it."""
        state = self._state
        new_session = False
        if state[S.reference] < 0:
            offset, new_session = self._start_segment_clock(tag, raw)
        else:
            reference = int(state[S.reference])
            reference_offset = int(state[S.offset + reference])
            offset = clock_offset(raw, int(state[S.last + reference]), reference_offset,
                                  [int(state[S.offset + other]) for other in range(N_FILTER_TAGS)
                                   if state[S.has_offset + other]], self.options)
            if offset is None:
                offset = reference_offset
            else:
                self.stats.note_clock(FILTER_TAGS[tag], FILTER_TAGS[reference],
                                      offset - reference_offset)
        state[S.offset + tag] = offset
        state[S.has_offset + tag] = 1
        self._offsets[FILTER_TAGS[tag]] = offset
        return new_session


# -- repeats: samples repeated exactly, after release ----------------------------------------------

# the samples of the previous chunk's last time: (t_ms, tag, values)
Last = tuple[np.ndarray, np.ndarray, np.ndarray] | None


def _same_values(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return ((a == b) | (np.isnan(a) & np.isnan(b))).all(axis=-1)


def repeats(t_ms: np.ndarray, tag: np.ndarray, values: np.ndarray,
            last: Last) -> tuple[np.ndarray, Last]:
    """(mask of the samples that repeat an earlier one, what to carry into the next chunk).
    t_ms, tag (n,), values (n, 4) in release order (times never going back); last: what the
    previous chunk returned (None at the start).

    A repeat is a line the phone (or a copy of a log) wrote twice: a sample with the same time,
    tag and values as one released before it (release times never go back, so only the samples
    of the latest time need remembering); the estimators use it once (the runner drops it) and
    the log's summary counts it. A sample at the same time with other values is not a repeat:
    both are used, as the phone sent them."""
    n = len(t_ms)
    if n == 0:
        return np.zeros(0, bool), last
    t = np.asarray(t_ms, np.int64)
    g = np.asarray(tag, np.int64)
    v = np.asarray(values, np.float64).reshape(n, -1)
    carried = 0
    if last is not None and len(last[0]) and last[0][-1] == t[0]:
        carried = len(last[0])
        t, g, v = (np.concatenate([last[0], t]), np.concatenate([last[1], g]),
                   np.concatenate([last[2], v]))
    mask = np.zeros(len(t), bool)
    lag = 1
    while lag < len(t):
        same_time = t[lag:] == t[:-lag]
        if not same_time.any():
            break
        mask[lag:] |= same_time & (g[lag:] == g[:-lag]) & _same_values(v[lag:], v[:-lag])
        lag += 1
    group = len(t) - 1
    while group > 0 and t[group - 1] == t[-1]:
        group -= 1
    return mask[carried:], (t[group:].copy(), g[group:].copy(), v[group:].copy())


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernels before the first chunk arrives."""
    orderer = TimeOrderer()
    orderer.push_arrays(np.array([1000, 1000, 5000]), np.array([0, 1, 0]),
                        np.zeros((3, MAX_WIDTH)))
    orderer.restart_arrays()
    _ = orderer.oldest_pending_sequence


@jit
def _table_key():
    return TABLE_KEY


check_cache(_table_key, globals(), TABLE_KEY)
