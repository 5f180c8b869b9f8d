"""FastLineParser: the compiled parser gives exactly what LineParser gives, in any chunking."""

from __future__ import annotations

import math
import random

import pytest

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from line_helpers import parses as _parses
from app.stream.fastparse import FastLineParser
from app.stream.protocol import (DEFAULT_LIMITS, LineParser, Limits, java_float_text)

# bounds the generated numbers cross often (1, 7, 9, 10, 12, 0.5 ...)
TIGHT = Limits(acc=10.0, gyr=1.0, mag=12.0, ori_tolerance=1e-7, floor=0.5)


def _key(samples):
    # float.hex: -0.0 and 0.0 must differ, and every bit must match
    return [(s.t_ms, s.tag, tuple(float(v).hex() for v in s.values), s.text) for s in samples]


def _reference(data: bytes, pieces: list[int], max_line_bytes: int,
               limits: Limits = DEFAULT_LIMITS):
    raw: list[bytes] = []
    parser = LineParser(raw_sink=raw.append, max_line_bytes=max_line_bytes, limits=limits)
    samples = []
    for piece in _split(data, pieces):
        samples += parser.feed(piece)
    samples += parser.finish()
    return _key(samples), parser.stats, b"".join(raw), len(raw)


def _fast(data: bytes, pieces: list[int], max_line_bytes: int, limits: Limits = DEFAULT_LIMITS):
    raw: list[bytes] = []
    counted = [0]

    def block(chunk: bytes, lines: int) -> None:
        raw.append(chunk)
        counted[0] += lines

    def line(chunk: bytes) -> None:
        raw.append(chunk)
        counted[0] += 1

    parser = FastLineParser(raw_sink=line, raw_block_sink=block, max_line_bytes=max_line_bytes,
                            limits=limits)
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
              b"9007199254740993", b"123456789012345678901", b"1000\t", b"\tACC\t",
              # plausibility and junk: bounds, control bytes, other whitespace, unit quaternions
              b"1e160", b"2000.0", b"2000.0001", b"100.0", b"1.0E20", b"10.0", b"0.7071068",
              b"0.70710677", b"-0.5", b"1.0000001", b"\x00", b"\x01", b"\x7f", b"\x1c", b"\x0b",
              b"\x0c", b"\x1b", b"\t\t", b"  ", b"\n\n\n", b"\xc2\xa0", b"\xc2\x85",
              # digits of other scripts: full-width nine and one, Arabic-Indic three
              b"\xef\xbc\x99", b"\xef\xbc\x91.0", b"\xd9\xa3", b"1000\tACC\t\xef\xbc\x99.8\t0\t0\n",
              b"5\tORI\t0.5\t0.5\t0.5\t0.5\n", b"5\tORI\t-0.5\t0.5\t-0.5\t0.5\n",
              b"6\tORI\t0.9\t0.9\t0.9\n", b"7\tACC\t1e160\t0\t0\n", b"8\tGYR\t1.0E20\t0\t0\n",
              b"9\tMAG\t5000.0\t5000.0\t5000.0\n", b"10\tRAWGYR\t1\t2\t3\t4\t5\t500\n"]
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
       max_line_bytes=st.sampled_from([4096, 40, 12]),
       limits=st.sampled_from([DEFAULT_LIMITS, TIGHT]))
def test_fast_parser_equals_line_parser_on_any_bytes_and_chunking(parts, cuts, max_line_bytes,
                                                                  limits):
    data = b"".join(parts)
    assert _fast(data, cuts, max_line_bytes, limits) == _reference(data, cuts, max_line_bytes,
                                                                   limits)


@pytest.mark.parametrize("end", [b"", b"\n"])
def test_a_time_beyond_int64_is_a_damaged_line_not_a_crash(end):
    """Found by the property test: 34 digits of time glued onto a GYR line."""
    data = b"12345678901234567" * 2 + b"0\tGYR\t0.0\t0.0\t0.0" + end + b"5\tACC\t0\t0\t9.8\n"
    fast = _fast(data, [], 4096)
    assert fast == _reference(data, [], 4096)
    samples, stats = fast[0], fast[1]
    assert stats.damaged == 1 and len(samples) == (1 if end else 0)


@pytest.mark.parametrize("digits", ["\uff19.8", "9.\uff18", "\u0669.8", "\u09ef.8"])
def test_digits_of_other_scripts_are_a_bad_number_never_recorded(digits):
    """Was: "９.8" (a full-width nine) was read as 9.8 and recorded, by both parsers."""
    data = (f"1000\tACC\t{digits}\t0.0\t0.0\n1010\tACC\t9.8\t0.0\t0.0\n").encode()
    fast = _fast(data, [], 4096)
    assert fast == _reference(data, [], 4096)
    samples, stats, recorded, _ = fast
    assert [t for t, *_ in samples] == [1010]
    assert stats.damaged_reasons == {"bad number": 1}
    assert recorded == b"1010\tACC\t9.8\t0.0\t0.0\n"


def test_fast_parser_equals_line_parser_on_real_logs(realphone_dir):
    rng = random.Random(3)
    for path in sorted(realphone_dir.glob("*.txt")):
        data = path.read_bytes()
        cuts = [rng.randrange(len(data)) for _ in range(200)]
        fast = _fast(data, cuts, 4096)
        assert fast == _reference(data, cuts, 4096), path.name
        # the recording is the file without its damaged lines, byte for byte
        assert fast[2] == b"".join(line for line in data.splitlines(keepends=True)
                                   if _parses(line)), path.name
        assert fast[1].damaged == (2 if "standstill" in path.name else 0)



def test_java_float_text_numbers_parse_to_the_same_double():
    rng = np.random.default_rng(7)
    doubles = np.concatenate([rng.standard_normal(3000) * 10.0 ** rng.integers(-12, 12, 3000),
                              rng.standard_normal(3000).astype(np.float32).astype(float)])
    lines = b"".join(f"{k}\tGYR\t{java_float_text(a)}\t{java_float_text(-a)}\t0.0\n".encode()
                     for k, a in enumerate(doubles.tolist()))
    parsed = FastLineParser(limits=Limits(gyr=math.inf)).feed_arrays(lines)
    assert len(parsed.t_ms) == len(doubles)
    assert np.array_equal(parsed.values[:, 0], doubles)
    assert np.array_equal(parsed.values[:, 1], -doubles)


def test_floods_of_empty_and_junk_lines_take_no_python_per_line(monkeypatch):
    """Issue 10, item 3: empty lines, control bytes, lines without a TAB or with a bad time
    and samples out of range are counted in the kernel; Python sees only the first damaged
    lines (for their example messages)."""
    calls = []
    original = LineParser._line

    def counting(self, raw, *args, **kwargs):
        calls.append(raw)
        return original(self, raw, *args, **kwargs)

    monkeypatch.setattr(LineParser, "_line", counting)
    flood = (b"\n" * 200_000 + b"x\n" * 50_000 + b"\x00\x01\n" * 50_000 + b"12a\tACC\n" * 50_000
             + b"  \t \r\n" * 50_000 + b"5\tACC\t1e160\t0\t0\n" * 50_000 + b"6\tACC\t0\t0\t9.8\n")
    parser = FastLineParser()
    parsed = parser.feed_arrays(flood)
    assert len(parsed.t_ms) == 1 and len(calls) == 20
    stats = parser.stats
    assert stats.empty == 250_000 and stats.lines == 450_001 and stats.good == 1
    assert stats.damaged_reasons == {"no tag": 50_000, "binary data": 50_000,
                                     "bad time": 50_000, "ACC out of range": 50_000}
