"""Blocks handed to Octave while it works go together as one request, and its reply is split back
into the blocks handed over (app.engine.userfilter.octave_remote): every row, its output, the
row where the filter paused, the row of the latest output and the innovations land in the block
they were handed over in. Pure bookkeeping: no Octave needed."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from app.engine.userfilter.octave_remote import _Part, _split
from app.engine.userfilter.remote import BlockResult


@st.composite
def replies(draw):
    sizes = draw(st.lists(st.integers(1, 6), min_size=1, max_size=6))
    n = sum(sizes)
    t = np.cumsum(draw(st.lists(st.floats(0.001, 0.05), min_size=n, max_size=n))) + 10.0
    paused_at = draw(st.integers(-1, n - 1))
    last_out = draw(st.integers(-1, n - 1 if paused_at < 0 else paused_at - 1))
    rows = draw(st.lists(st.integers(0, n - 1), max_size=8))
    innovations = [(float(t[r]), "acc", np.zeros(3), np.eye(3), True) for r in sorted(rows)]
    q = np.arange(4 * n, dtype=float).reshape(n, 4)
    result = BlockResult(7, t, np.ones((n, 3), bool), q, np.zeros((n, 3), np.int8), paused_at,
                         last_out, np.eye(4), innovations, 0.01)
    parts = [_Part(-(i + 1), size, 100.0 + 0.01 * i) for i, size in enumerate(sizes)]
    return result, parts


@settings(max_examples=200, deadline=None)
@given(replies())
def test_a_reply_to_blocks_sent_together_is_split_back_into_them(case):
    result, parts = case
    split = _split(result, parts, sent=100.05)
    assert [r.id for r in split] == [p.block for p in parts]
    assert np.array_equal(np.concatenate([r.q for r in split]), result.q)
    assert np.array_equal(np.concatenate([r.t_s for r in split]), result.t_s)
    assert sum(len(r.innovations) for r in split) == len(result.innovations)
    start = 0
    for part, piece in zip(parts, split):
        end = start + part.rows
        assert all(piece.t_s[0] <= item[0] <= piece.t_s[-1] for item in piece.innovations)
        if result.paused_at < 0 or result.paused_at >= end:
            assert piece.paused_at == -1                       # not paused within or before it
        else:
            assert piece.paused_at == max(0, result.paused_at - start)
        if result.last_out < start:
            assert piece.last_out == -1
        else:
            assert piece.last_out == min(result.last_out, end - 1) - start
        assert piece.lag_s == result.lag_s + max(0.0, 100.05 - part.at)
        start = end
    assert split[-1].P is result.P and all(piece.P is None for piece in split[:-1])
