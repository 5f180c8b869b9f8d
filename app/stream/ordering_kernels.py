"""The compiled orderer's kernels and its packed state, laid out from the tag table.

:class:`app.stream.ordering.TimeOrderer` runs the algorithm of
:class:`~app.stream.ordering_reference.ReferenceTimeOrderer` on arrays: its state is one int64
array, ``S`` gives the offsets into it (never numbered by hand): the scalars of
:data:`SCALARS`, then for each name in :data:`PER_TAG` one slot per filter tag code
(:data:`app.stream.tags.FILTER_TAGS`), so ``st[S.last + tag]`` is tag's latest aligned time.
``P`` indexes the int64 parameters array (:data:`PARAMETERS`, fields of
:class:`~app.stream.ordering_reference.OrderOptions`), ``K`` the columns of a held sample's key
(time, priority = tag code, push sequence, the caller's payload id; compared in that order).
numba freezes these namedtuples as compile-time constants.
"""

from __future__ import annotations

from collections import namedtuple

from app.stream.kernels import check_cache, jit
from app.stream.ordering_reference import LAG_BUCKET_MS
from app.stream.tags import MAX_WIDTH, N_FILTER_TAGS, TABLE_KEY

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
def _release_all(st, keys, values, out_keys, out_values, n_out):
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
def new_segment(st, keep_offsets):
    for tag in range(N_FILTER_TAGS):
        st[S.previous_offset + tag] = st[S.offset + tag]
        st[S.has_previous_offset + tag] = st[S.has_offset + tag] if keep_offsets else 0
        for block in (S.offset, S.has_offset, S.last, S.has_last, S.late, S.has_late, S.lag_current,
                      S.lag_previous):
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
def _window(st, params):
    lag = 0
    for tag in range(N_FILTER_TAGS):
        lag = max(lag, st[S.lag_current + tag], st[S.lag_previous + tag])
    window = params[P.window_ms]
    if lag == 0:
        return window
    return min(params[P.max_window_ms], max(window, lag + lag // 4 + 10))


@jit
def _rotate_lags(st):
    bucket = st[S.newest] // LAG_BUCKET_MS
    if st[S.has_lag_bucket] == 0 or bucket != st[S.lag_bucket]:
        consecutive = st[S.has_lag_bucket] == 1 and bucket == st[S.lag_bucket] + 1
        for tag in range(N_FILTER_TAGS):
            st[S.lag_previous + tag] = st[S.lag_current + tag] if consecutive else 0
            st[S.lag_current + tag] = 0
        st[S.lag_bucket] = bucket
        st[S.has_lag_bucket] = 1


@jit
def _release(st, keys, values, params, out_keys, out_values, n_out):
    threshold = st[S.newest] - _window(st, params)
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
def _own_clock(st, tag, t, params):
    """ReferenceTimeOrderer._own_clock: 0 ok, 1 drop, 2 new segment."""
    last = st[S.last + tag]
    gap = params[P.gap_ms]
    if t < last - gap:
        if last - t > params[P.late_horizon_ms]:
            return 2
        if st[S.has_late + tag] == 0:
            st[S.late + tag] = t
            st[S.has_late + tag] = 1
            return 1
        return 1 if t - st[S.late + tag] <= gap else 2
    if t > last + gap:
        return 2
    if t < last:
        return 1
    st[S.has_late + tag] = 0
    return 0


@jit
def _holding(st, params):
    since_start = st[S.newest] - st[S.segment_start]
    tags = 0
    for other in range(N_FILTER_TAGS):
        tags += st[S.has_last + other]
    hold = params[P.startup_hold_ms]
    return (tags < N_FILTER_TAGS and st[S.heap_n] <= params[P.max_pending] and since_start < 4 * hold and (
        since_start < hold or tags < 2 or st[S.newest] - st[S.last_new_tag] < params[P.window_ms]))


@jit
def _lags_behind_newcomer(st, tag, t, max_window):
    """A tag showing up ahead of the others: they are this far behind it."""
    for other in range(N_FILTER_TAGS):
        if other != tag and st[S.has_last + other]:
            behind = t - st[S.last + other]
            if 0 < behind <= max_window and behind > st[S.lag_current + other]:
                st[S.lag_current + other] = behind


@jit
def _hold_suspect(st, sus, sus_values, raw, tag, t, payload, v, params):
    """ReferenceTimeOrderer._suspect up to the decision: keep the sample; True when the jump
    is confirmed."""
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
def refute_suspects(st, sus, sus_values, tag):
    """ReferenceTimeOrderer._refute: the tag's held samples are dropped (counted)."""
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
def clear_suspects(st):
    st[S.suspects] = 0
    for tag in range(N_FILTER_TAGS):
        st[S.suspect_count + tag] = 0


@jit
def push_run(st, keys, values, sus, sus_values, t_in, tag_in, v_in, payload_in, start, counted,
             params, out_keys, out_values, n_out):
    """ReferenceTimeOrderer._push for samples start.. until one needs its clock offset learned
    (done in Python) or held samples start a new segment. Samples before index `counted` are
    such held samples pushed again (not counted in pushed). Returns (entries in out, index of
    the sample to learn or of the next one after a confirmed jump or len(t_in), the number of
    held samples to push again before it: 0 unless a jump was confirmed)."""
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
            verdict = _own_clock(st, tag, t, params)
            if verdict == 2:
                # A pause, a reboot or another phone -- or one bad time stamp: held until
                # another sample confirms the new clock or the tag's old clock goes on.
                if _hold_suspect(st, sus, sus_values, raw, tag, t, payload_in[i], v_in[i],
                                 params):
                    held = st[S.suspects]
                    clear_suspects(st)
                    n_out = _release_all(st, keys, values, out_keys, out_values, n_out)
                    new_segment(st, 1)
                    return n_out, i + 1, held
                i += 1
                continue
            if st[S.suspect_count + tag] > 0:
                refute_suspects(st, sus, sus_values, tag)
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
            _rotate_lags(st)
            if first_of_tag:
                _lags_behind_newcomer(st, tag, t, params[P.max_window_ms])
        st[S.sequence] += 1
        _heap_push(st, keys, values, t, tag, st[S.sequence], payload_in[i], v_in[i])
        i += 1
        if st[S.warm] == 0:
            if _holding(st, params):
                continue
            st[S.warm] = 1
        n_out = _release(st, keys, values, params, out_keys, out_values, n_out)
    return n_out, n, 0


@jit
def flush_all(st, keys, values, out_keys, out_values):
    return _release_all(st, keys, values, out_keys, out_values, 0)


@jit
def oldest_pending_sequence(st, keys):
    oldest = st[S.sequence] + 1
    for i in range(st[S.heap_n]):
        if keys[i, K.seq] < oldest:
            oldest = keys[i, K.seq]
    return oldest


@jit
def _table_key():
    return TABLE_KEY


check_cache(_table_key, globals())
