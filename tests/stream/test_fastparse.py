"""FastLineParser: the compiled parser gives exactly what LineParser gives, in any chunking."""

from __future__ import annotations

import random

import pytest

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from app.stream.fastparse import FastLineParser
from app.stream.protocol import LineParser, java_float_text


def _key(samples):
    # float.hex: -0.0 and 0.0 must differ, and every bit must match
    return [(s.t_ms, s.tag, tuple(float(v).hex() for v in s.values), s.text) for s in samples]


def _reference(data: bytes, pieces: list[int], max_line_bytes: int):
    raw: list[bytes] = []
    parser = LineParser(raw_sink=raw.append, max_line_bytes=max_line_bytes)
    samples = []
    for piece in _split(data, pieces):
        samples += parser.feed(piece)
    samples += parser.finish()
    return _key(samples), parser.stats, b"".join(raw), len(raw)


def _fast(data: bytes, pieces: list[int], max_line_bytes: int):
    raw: list[bytes] = []
    counted = [0]

    def block(chunk: bytes, lines: int) -> None:
        raw.append(chunk)
        counted[0] += lines

    def line(chunk: bytes) -> None:
        raw.append(chunk)
        counted[0] += 1

    parser = FastLineParser(raw_sink=line, raw_block_sink=block, max_line_bytes=max_line_bytes)
    samples = []
    for piece in _split(data, pieces):
        samples += parser.feed_arrays(piece).to_samples()
    samples += parser.finish_arrays().to_samples()
    return _key(samples), parser.stats, b"".join(raw), counted[0]


def _split(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({min(len(data), max(0, c)) for c in cuts})
    out, previous = [], 0
    for point in points + [len(data)]:
        out.append(data[previous:point])
        previous = point
    return out


_FRAGMENTS = [b"\t", b"\n", b"\r\n", b"\r", b"GYR", b"ACC", b"MAG", b"ORI", b"GPS", b"RSSWIFI",
              b"NEWTAG", b"gyr", b"-", b"+", b".", b"E", b"e", b"E-", b"0", b"1", b"7", b"9",
              b"12", b"0.5", b"9.81", b"-0.0", b"3.2043457E-4", b"1.0E22", b"1e23", b"NaN",
              b"Infinity", b"1_0", b" ", b"\xff", b"\xc3\xa9", b"12345678901234567",
              b"9007199254740993", b"123456789012345678901", b"1000\t", b"\tACC\t"]
_LINES = st.builds(
    lambda t, tag, values, end: (f"{t}\t{tag}\t" + "\t".join(values)).encode() + end,
    st.integers(0, 10**13), st.sampled_from(["GYR", "ACC", "MAG", "ORI", "ORI", "PRX"]),
    st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(java_float_text),
                       st.floats(width=32).map(java_float_text),
                       st.integers(-10**20, 10**20).map(str)), min_size=1, max_size=5),
    st.sampled_from([b"\n", b"\r\n", b"", b"\n"]))


@settings(max_examples=300, deadline=None)
@given(parts=st.lists(st.one_of(st.sampled_from(_FRAGMENTS), _LINES, st.binary(max_size=6)),
                      max_size=60),
       cuts=st.lists(st.integers(0, 400), max_size=6),
       max_line_bytes=st.sampled_from([4096, 40, 12]))
def test_fast_parser_equals_line_parser_on_any_bytes_and_chunking(parts, cuts, max_line_bytes):
    data = b"".join(parts)
    assert _fast(data, cuts, max_line_bytes) == _reference(data, cuts, max_line_bytes)


@pytest.mark.parametrize("end", [b"", b"\n"])
def test_a_time_beyond_int64_is_a_damaged_line_not_a_crash(end):
    """Found by the property test: 34 digits of time glued onto a GYR line."""
    data = b"12345678901234567" * 2 + b"0\tGYR\t0.0\t0.0\t0.0" + end + b"5\tACC\t0\t0\t9.8\n"
    fast = _fast(data, [], 4096)
    assert fast == _reference(data, [], 4096)
    samples, stats = fast[0], fast[1]
    assert stats.damaged == 1 and len(samples) == (1 if end else 0)


def test_fast_parser_equals_line_parser_on_real_logs(realphone_dir):
    rng = random.Random(3)
    for path in sorted(realphone_dir.glob("*.txt")):
        data = path.read_bytes()
        cuts = [rng.randrange(len(data)) for _ in range(200)]
        fast = _fast(data, cuts, 4096)
        assert fast == _reference(data, cuts, 4096), path.name
        assert fast[2] == data                       # the recording is the file, byte for byte


def test_java_float_text_numbers_parse_to_the_same_double():
    rng = np.random.default_rng(7)
    doubles = np.concatenate([rng.standard_normal(3000) * 10.0 ** rng.integers(-12, 12, 3000),
                              rng.standard_normal(3000).astype(np.float32).astype(float)])
    lines = b"".join(f"{k}\tGYR\t{java_float_text(a)}\t{java_float_text(-a)}\t0.0\n".encode()
                     for k, a in enumerate(doubles.tolist()))
    parsed = FastLineParser().feed_arrays(lines)
    assert len(parsed.t_ms) == len(doubles)
    assert np.array_equal(parsed.values[:, 0], doubles)
    assert np.array_equal(parsed.values[:, 1], -doubles)
