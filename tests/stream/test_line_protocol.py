"""Line protocol: parse/format one line and the incremental byte parser."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.stream.protocol import (LineParser, Limits, ParseError, Sample, format_line,
                                 java_float_text, parse_line)

UNBOUNDED = Limits(acc=math.inf, gyr=math.inf, mag=math.inf)


def test_parse_numeric_line_with_java_float_text():
    sample = parse_line("1155756\tGYR\t3.2043457E-4\t-0.0\t9.308941\n")
    assert sample == Sample(1155756, "GYR", (3.2043457e-4, -0.0, 9.308941))
    assert math.copysign(1.0, sample.values[1]) < 0


def test_parse_crlf_and_text_tag_with_spaces():
    sample = parse_line("1585038883072\tRSSWIFI\t90:61:0c:20:d1:c0\tMiFi S1-2298\t2417\t-66\r\n")
    assert sample.tag == "RSSWIFI"
    assert sample.text == ("90:61:0c:20:d1:c0", "MiFi S1-2298", "2417", "-66")
    assert sample.values == ()


def test_ori_three_values_gets_w_and_four_values_get_w_nonnegative():
    three = parse_line("5\tORI\t0.142\t-0.005\t0.03")
    w = math.sqrt(1 - 0.142**2 - 0.005**2 - 0.03**2)
    assert three.values == pytest.approx((w, 0.142, -0.005, 0.03))
    four = parse_line("5\tORI\t-0.5\t0.5\t-0.5\t0.5")
    assert four.values == (0.5, -0.5, 0.5, -0.5)


@pytest.mark.parametrize("line, kind", [
    ("", "empty"),
    ("  \r", "empty"),
    ("123\tACC\t1.0\t2.0", "damaged"),                 # too few values
    ("123\tRAWGYR\t1\t2\t3\t4\t5\t6\t7\t8\t9\t10", "damaged"),
    ("12x\tACC\t1\t2\t3", "damaged"),                  # bad time
    ("-5\tACC\t1\t2\t3", "damaged"),
    ("1234567890123456789\tACC\t1\t2\t3", "damaged"),  # 19 digits: beyond int64 times
    ("123\tACC\t1\tabc\t3", "damaged"),                # bad number
    ("123\tACC\t1\tnan\t3", "damaged"),                # non-finite
    ("123\tACC\t1\t1_0\t3", "damaged"),
    ("123\tACC\t\uff19.8\t0\t0", "damaged"),          # full-width digit nine
    ("123\tGYR\t0.\u0663\t0\t0", "damaged"),           # Arabic-Indic digit three
    ("123\tORI\t\uff11.0\t0.0\t0.0\t0.0", "damaged"),
    ("123 ACC 1 2 3", "damaged"),                      # spaces are not separators
    ("123\tNEWTAG\t1", "unknown_tag"),
    ("123\tAC\ufffdC\t1\t2\t3", "damaged"),            # a broken tag is not a new tag
    ("123\tRSSBLE\tmac\tname", "damaged"),
])
def test_bad_lines_raise_parse_error_by_kind(line, kind):
    with pytest.raises(ParseError) as caught:
        parse_line(line)
    assert caught.value.kind == kind


@pytest.mark.parametrize("value, text", [
    (9.308941, "9.308941"), (3.2043457e-4, "3.2043457E-4"), (-0.0, "-0.0"), (0.0, "0.0"),
    (100.0, "100.0"), (0.001, "0.001"), (1e7, "1.0E7"), (-12.5, "-12.5"), (1234567.0, "1234567.0"),
])
def test_java_float_text(value, text):
    assert java_float_text(value) == text


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_format_line_round_trips_any_float(value):
    sample = Sample(42, "MAG", (value, 1.0, -2.5))
    assert parse_line(format_line(sample), UNBOUNDED) == sample


def test_format_line_reproduces_phone_lines(realphone_dir):
    for path in sorted(realphone_dir.glob("*.txt")):
        for line in path.read_text().splitlines()[:400]:
            try:
                sample = parse_line(line)
            except ParseError:
                continue
            assert format_line(sample) == line


def test_parser_reassembles_split_lines_and_crlf():
    parser = LineParser()
    data = b"1\tACC\t1.0\t2.0\t3.0\r\n2\tGYR\t0.1\t0.2\t0.3\n3\tMAG\t4.0\t5.0\t6.0"
    out = []
    for index in range(len(data)):
        out += parser.feed(data[index:index + 1])
    assert [s.tag for s in out] == ["ACC", "GYR"]
    out += parser.finish()
    assert [s.t_ms for s in out] == [1, 2, 3]
    assert parser.stats.lines == 3 and parser.stats.good == 3


def test_parser_counts_bad_lines_and_keeps_going():
    parser = LineParser()
    data = (b"1\tACC\t1\t2\t3\n\xff\xfe garbage\n2\tXYZ\t1\n\n3\tACC\t1\t2\n"
            b"4\tRSSWIFI\tmac\t\xc3\xa9t\xe9\t2417\t-66\n5\tGYR\t1\t2\t3\n")
    samples = parser.feed(data)
    assert [s.t_ms for s in samples] == [1, 4, 5]
    assert samples[1].text[1] == "\u00e9t\ufffd"     # invalid UTF-8 replaced, text kept
    stats = parser.stats
    assert (stats.damaged, stats.unknown, stats.empty, stats.good) == (2, 1, 1, 3)
    assert stats.unknown_tags == {"XYZ": 1}
    assert stats.first_bad_line_number == 2
    assert stats.per_tag == {"ACC": 1, "RSSWIFI": 1, "GYR": 1}


def test_parser_discards_long_line_with_bounded_buffer():
    parser = LineParser()
    assert parser.feed(b"1\tACC\t1\t2\t3\n") != []
    for _ in range(256):                       # 1 MiB without a newline
        assert parser.feed(b"9" * 4096) == []
        assert len(parser._pending) <= 4097
    assert [s.t_ms for s in parser.feed(b"77\n2\tACC\t1\t2\t3\n")] == [2]
    assert parser.stats.too_long == 1
    long_in_one_chunk = b"1\tACC\t" + b"1" * 5000 + b"\n3\tACC\t1\t2\t3\n"
    assert [s.t_ms for s in parser.feed(long_in_one_chunk)] == [3]
    assert parser.stats.too_long == 2
    parser.feed(b"x" * 5000)
    parser.finish()
    assert parser.stats.too_long == 3


def test_line_of_exactly_the_limit_is_kept():
    line = b"1\tRSSBLE\tmac\t" + b"n" * 100 + b"\t-5"
    parser = LineParser(max_line_bytes=len(line))
    assert len(parser.feed(line + b"\r\n")) == 1
    parser_short = LineParser(max_line_bytes=len(line) - 1)
    assert parser_short.feed(line + b"\r\n") == [] and parser_short.stats.too_long == 1


def test_raw_sink_gets_only_lines_that_parse_verbatim():
    """A recording holds only lines our tools read back: a damaged known-tag line (RAWGYR with
    2 values), one with a NUL byte or a value out of range is counted, never recorded."""
    raw: list[bytes] = []
    parser = LineParser(raw_sink=raw.append)
    data = (b"1\tACC\t1\t2\t3\r\n2\tNEW\t1\n3\tRAWGYR\t1\t2\n\xff\n5\tACC\t1\x00\t2\t3\n"
            b"6\tACC\t1e160\t0\t0\n4\tGYR\t1\t2\t3")
    parser.feed(data)
    parser.finish()
    assert raw == [b"1\tACC\t1\t2\t3\r\n", b"4\tGYR\t1\t2\t3\n"]
    assert parser.stats.damaged_reasons == {"value count": 1, "no tag": 1, "binary data": 1,
                                            "ACC out of range": 1}


_LINE = st.sampled_from([
    b"1\tACC\t1.0\t2.0\t3.0\n", b"2\tGYR\t-0.0\t1E-4\t3\r\n", b"\xff\xc3\n", b"\n",
    b"3\tORI\t0.1\t0.2\t0.3\n", b"4\tFOO\t1\n", b"5\tMAG\t1\t2\n", b"6\tRSSWIFI\ta\tb c\td\te\n",
    b"x" * 40, b"\r",
])


def _parse_in_chunks(data: bytes, cuts: list[int], max_line_bytes: int) -> tuple[list, tuple]:
    parser = LineParser(max_line_bytes=max_line_bytes)
    out = []
    start = 0
    for cut in sorted(set(c % (len(data) + 1) for c in cuts)) + [len(data)]:
        out += parser.feed(data[start:cut])
        start = cut
    out += parser.finish()
    s = parser.stats
    return out, (s.lines, s.good, s.damaged, s.unknown, s.too_long, s.empty)


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.binary(max_size=300), st.lists(_LINE, max_size=30).map(b"".join)),
       st.lists(st.integers(min_value=0, max_value=10_000), max_size=12),
       st.sampled_from([16, 60, 4096]))
def test_any_bytes_any_chunking_same_samples_never_raises(data, cuts, max_line_bytes):
    whole = _parse_in_chunks(data, [], max_line_bytes)
    assert _parse_in_chunks(data, cuts, max_line_bytes) == whole


@pytest.mark.parametrize("make", [LineParser, "fast"])
def test_a_torn_ori_line_is_damaged_and_a_three_value_stream_is_fine(make):
    """Was: an ORI line torn to 3 values was taken as a 3-value ORI. Its vector part always has
    a norm <= 1, so what gives it away is the stream: 4-value ORI lines before it."""
    from app.stream.fastparse import FastLineParser
    parser = LineParser() if make is LineParser else FastLineParser()
    four = b"1\tORI\t0.9\t0.3\t0.3\t0.1\n"
    torn = b"2\tORI\t0.9\t0.3\t0.3\n"
    assert [s.t_ms for s in parser.feed(four + torn + four)] == [1, 1]
    assert parser.stats.damaged_reasons == {"value count": 1}
    assert "torn" in parser.stats.bad_examples[0][2]
    parser.reset_line()                                  # a new connection
    three = parser.feed(b"5\tORI\t0.142\t-0.005\t0.03\n6\tORI\t0.9\t0.9\t0.9\n")
    assert [s.t_ms for s in three] == [5]                # the second is no vector part
    assert parser.stats.damaged_reasons == {"value count": 1, "ORI out of range": 1}
