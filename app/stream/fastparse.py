"""A compiled line parser for the live path: bytes -> arrays, identical to :class:`LineParser`.

:class:`FastLineParser` is a :class:`~app.stream.protocol.LineParser` whose :meth:`feed_arrays`
scans the received bytes in one nogil numba kernel. The kernel handles the lines that make up
a live stream -- ``<time>\\tGYR|ACC|MAG\\t<3 numbers>`` and ``<time>\\tORI\\t<4 numbers>`` in
plain Java float text -- and hands every other line (other tags, 3-value ORI, NaN/Infinity,
long mantissas, bad lines, lines over MAX_LINE_BYTES, non-ASCII bytes) to the inherited Python
:meth:`LineParser._line`, in line order, so every sample, count, example message and recorded
byte is exactly what :class:`LineParser` gives, whatever the chunking.

Numbers: a mantissa of at most 17 significant digits with an integer value M <= 2^53 and a
decimal exponent |e| <= 22 is converted as M * 10^e or M / 10^-e: both operands are exact
doubles, so the one IEEE operation rounds correctly and equals Python's ``float(text)``
(Clinger's fast path). Other valid, certainly finite numbers (e.g. 17-digit doubles) are
validated by the kernel and converted by Python's ``float()`` on their bytes; anything else
sends the whole line to Python.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from app.stream.protocol import FILTER_TAGS, MAX_LINE_BYTES, LineParser, Sample

#: Tag codes of the array form (equal to their priority at equal times: GYR < ACC < MAG < ORI).
TAG_CODES: dict[str, int] = {tag: code for code, tag in enumerate(FILTER_TAGS)}
TAG_WIDTHS = (3, 3, 3, 4)

_POW10 = np.array([float(10 ** k) for k in range(23)])   # exact doubles
_TWO_POW_53 = 2 ** 53
_MAX_TIME_DIGITS = 18            # fits int64; longer times go to Python (damaged there)

_jit = njit(cache=True, nogil=True)


@_jit
def _number(buf, p, e, pow10):
    """Parse one Java float at buf[p:...] ending at a TAB or at e.

    Returns (value, next p, exact): exact=True when value is the correctly rounded double;
    exact=False when the text is valid and certainly finite but outside the fast path (Python's
    float() converts it); next p = -1 when the text is outside the handled subset."""
    negative = False
    if p < e and buf[p] == 45:           # '-'
        negative = True
        p += 1
    mantissa = 0
    digits = 0                           # significant digits in mantissa
    exponent = 0
    integer_digits = 0
    start = p
    while p < e and 48 <= buf[p] <= 57:
        d = buf[p] - 48
        if mantissa != 0 or d != 0:
            digits += 1
            if digits <= 17:
                mantissa = mantissa * 10 + d
            else:
                exponent += 1            # digits dropped: only for the finiteness bound
        p += 1
    integer_digits = p - start
    if p == start:
        return 0.0, -1, False            # at least one digit before any '.'
    if p < e and buf[p] == 46:           # '.'
        p += 1
        start = p
        while p < e and 48 <= buf[p] <= 57:
            d = buf[p] - 48
            if mantissa != 0 or d != 0:
                digits += 1
                if digits <= 17:
                    mantissa = mantissa * 10 + d
                    exponent -= 1
            else:
                exponent -= 1
            p += 1
        if p == start:
            return 0.0, -1, False
    explicit = 0
    if p < e and (buf[p] == 69 or buf[p] == 101):   # 'E' / 'e'
        p += 1
        sign = 1
        if p < e and (buf[p] == 45 or buf[p] == 43):
            if buf[p] == 45:
                sign = -1
            p += 1
        start = p
        value = 0
        while p < e and 48 <= buf[p] <= 57:
            value = value * 10 + (buf[p] - 48)
            p += 1
            if p - start > 3:
                return 0.0, -1, False
        if p == start:
            return 0.0, -1, False
        explicit = sign * value
        exponent += explicit
    if p < e and buf[p] != 9:
        return 0.0, -1, False
    if digits > 17 or mantissa > 9007199254740992 or exponent > 22 or exponent < -22:
        # |value| < 10^(integer digits + explicit exponent): finite when that is <= 300
        if integer_digits + explicit > 300:
            return 0.0, -1, False
        return 0.0, p, False
    if mantissa == 0:
        result = 0.0
    elif exponent == 0:
        result = float(mantissa)
    elif exponent > 0:
        result = float(mantissa) * pow10[exponent]
    else:
        result = float(mantissa) / pow10[-exponent]
    if negative:
        result = -result
    return result, p, True


@_jit
def _parse_line(buf, a, b, max_line_bytes, pow10, out_t, out_tag, out_v, k, slow, n_slow):
    """Line buf[a:b] (b = index of its LF). Fills row k; returns (kind, n_slow): kind 1 when
    the line is handled here, 2 when also some numbers need Python's float() (their (row,
    column, start, end) appended to slow), 0 when Python must parse the whole line."""
    e = b
    if e > a and buf[e - 1] == 13:       # CRLF
        e -= 1
    if e - a > max_line_bytes:
        return 0, n_slow
    p = a
    t = 0
    while p < e and 48 <= buf[p] <= 57:
        t = t * 10 + (buf[p] - 48)
        p += 1
        if p - a > _MAX_TIME_DIGITS:
            return 0, n_slow
    if p == a or p + 5 > e or buf[p] != 9 or buf[p + 4] != 9:
        return 0, n_slow
    c0 = buf[p + 1]
    c1 = buf[p + 2]
    c2 = buf[p + 3]
    if c0 == 71 and c1 == 89 and c2 == 82:        # GYR
        tag = 0
    elif c0 == 65 and c1 == 67 and c2 == 67:      # ACC
        tag = 1
    elif c0 == 77 and c1 == 65 and c2 == 71:      # MAG
        tag = 2
    elif c0 == 79 and c1 == 82 and c2 == 73:      # ORI
        tag = 3
    else:
        return 0, n_slow
    count = 4 if tag == 3 else 3
    p += 5
    first_slow = n_slow
    for j in range(count):
        if j > 0:
            if p >= e or buf[p] != 9:
                return 0, first_slow
            p += 1
        field_start = p
        value, p, exact = _number(buf, p, e, pow10)
        if p < 0:
            return 0, first_slow
        out_v[k, j] = value
        if not exact:
            slow[n_slow, 0] = k
            slow[n_slow, 1] = j
            slow[n_slow, 2] = field_start
            slow[n_slow, 3] = p
            n_slow += 1
    if p != e:
        return 0, first_slow
    if count == 3:
        out_v[k, 3] = np.nan
    elif n_slow == first_slow and out_v[k, 0] < 0.0:   # q and -q: keep w >= 0 (parse_line)
        for j in range(4):
            out_v[k, j] = -out_v[k, j]
    out_t[k] = t
    out_tag[k] = tag
    return (1 if n_slow == first_slow else 2), n_slow


@_jit
def _scan(buf, max_line_bytes, pow10, out_t, out_tag, out_v, out_kind, out_start, out_end,
          slow):
    """Every LF-terminated line of buf: its span and, when handled here, its sample.
    Returns (lines, numbers left to Python in slow)."""
    n = 0
    n_slow = 0
    line_start = 0
    size = buf.shape[0]
    capacity = out_t.shape[0]
    p = 0
    while p < size and n < capacity:
        if buf[p] == 10:
            out_start[n] = line_start
            out_end[n] = p
            kind, n_slow = _parse_line(buf, line_start, p, max_line_bytes, pow10, out_t,
                                       out_tag, out_v, n, slow, n_slow)
            out_kind[n] = kind
            n += 1
            line_start = p + 1
        p += 1
    return n, n_slow


@dataclass
class ParsedArrays:
    """The samples of a chunk of lines, in line order.

    Filter tags (GYR, ACC, MAG, ORI) as arrays: t_ms (n,) int64 phone ms; tag (n,) int64 codes
    of :data:`TAG_CODES`; values (n, 4) float64 (NaN in column 3 for 3-value tags; ORI w >= 0);
    line (n,) the line's index in the chunk. other: (line index, Sample) of every other tag.
    """

    t_ms: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    tag: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    values: np.ndarray = field(default_factory=lambda: np.empty((0, 4)))
    line: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    other: list[tuple[int, Sample]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.t_ms) + len(self.other)

    def filter_samples(self) -> list[Sample]:
        """The filter-tag rows as Samples (values as Python floats)."""
        return [Sample(int(t), FILTER_TAGS[tag], tuple(row[:TAG_WIDTHS[tag]]))
                for t, tag, row in zip(self.t_ms.tolist(), self.tag.tolist(),
                                       self.values.tolist())]

    def to_samples(self) -> list[Sample]:
        """All samples in line order (what :meth:`LineParser.feed` returns)."""
        filtered = list(zip(self.line.tolist(), self.filter_samples()))
        if not self.other:
            return [sample for _, sample in filtered]
        merged = sorted(filtered + self.other, key=lambda item: item[0])
        return [sample for _, sample in merged]


def samples_to_arrays(samples: list[Sample]) -> ParsedArrays:
    """Samples -> :class:`ParsedArrays` (other tags into ``other``), line = position."""
    rows = [(index, s) for index, s in enumerate(samples) if s.tag in TAG_CODES]
    other = [(index, s) for index, s in enumerate(samples) if s.tag not in TAG_CODES]
    n = len(rows)
    values = np.full((n, 4), np.nan)
    for k, (_, s) in enumerate(rows):
        values[k, :len(s.values)] = s.values
    return ParsedArrays(np.fromiter((s.t_ms for _, s in rows), np.int64, n),
                        np.fromiter((TAG_CODES[s.tag] for _, s in rows), np.int64, n),
                        values, np.fromiter((i for i, _ in rows), np.int64, n), other)


class FastLineParser(LineParser):
    """:class:`LineParser` with a compiled :meth:`feed_arrays` (see the module docstring).

    raw_block_sink, when given (with or instead of raw_sink), gets runs of consecutive fast
    lines as one bytes object with their line count: ``raw_block_sink(data, lines)``; lines
    handled by Python still go to raw_sink one by one, in order.
    """

    def __init__(self, raw_sink: Callable[[bytes], None] | None = None,
                 max_line_bytes: int = MAX_LINE_BYTES,
                 raw_block_sink: Callable[[bytes, int], None] | None = None) -> None:
        super().__init__(raw_sink, max_line_bytes)
        self.raw_block_sink = raw_block_sink

    def feed(self, data: bytes) -> list[Sample]:
        return self.feed_arrays(data).to_samples()

    def feed_arrays(self, data: bytes) -> ParsedArrays:
        """Parse the complete lines in pending + data; keep the unfinished tail (bounded)."""
        self.stats.bytes += len(data)
        if not data:
            return ParsedArrays()
        head = None
        if self._discarding:
            newline = data.find(b"\n")
            if newline < 0:
                return ParsedArrays()
            self._discarding = False
            self._pending = b""
            self._count_bad("too_long", "line longer than %d bytes discarded" % self.max_line_bytes)
            data = data[newline + 1:]
        buffer = self._pending + data if self._pending else data
        last_newline = buffer.rfind(b"\n")
        if last_newline >= 0:
            head = self._lines(buffer, buffer.count(b"\n", 0, last_newline + 1))
            tail = buffer[last_newline + 1:]
        else:
            tail = buffer
        if len(tail) > self.max_line_bytes + 1:   # +1: the tail may end in the CR of a CRLF
            self._pending = b""
            self._discarding = True
        else:
            self._pending = tail
        return head if head is not None else ParsedArrays()

    def finish_arrays(self) -> ParsedArrays:
        """End of stream (see :meth:`LineParser.finish`), as arrays."""
        return samples_to_arrays(self.finish())

    # -- internals -------------------------------------------------------------------------

    def _lines(self, buffer: bytes, count: int) -> ParsedArrays:
        array = np.frombuffer(buffer, dtype=np.uint8)
        t_ms = np.empty(count, np.int64)
        tag = np.empty(count, np.int64)
        values = np.empty((count, 4))
        kind = np.empty(count, np.int64)
        starts = np.empty(count, np.int64)
        ends = np.empty(count, np.int64)
        slow_numbers = np.empty((4 * count, 4), np.int64)
        n, n_slow = _scan(array, self.max_line_bytes, _POW10, t_ms, tag, values, kind, starts,
                          ends, slow_numbers)
        assert n == count
        if n_slow:
            # Valid, finite numbers beyond the exact fast path: Python's own conversion.
            rows, columns, first, last = slow_numbers[:n_slow].T.tolist()
            values[rows, columns] = [float(buffer[a:b]) for a, b in zip(first, last)]
            ori = np.unique(np.asarray(rows)[tag[rows] == 3])
            flip = ori[values[ori, 0] < 0.0]
            values[flip] = -values[flip]          # q and -q: keep w >= 0 (parse_line)
        fast = kind != 0
        slow = np.flatnonzero(~fast)
        if len(slow) == 0:
            self._account_fast(buffer, tag, starts, ends, 0, count)
            return ParsedArrays(t_ms, tag, values, np.arange(count, dtype=np.int64))
        keep = fast.copy()
        other: list[tuple[int, Sample]] = []
        previous = 0
        for index in slow.tolist():
            self._account_fast(buffer, tag, starts, ends, previous, index)
            out: list[Sample] = []
            self._line(buffer[starts[index]:ends[index]], True, out)
            if out:
                sample = out[0]
                code = TAG_CODES.get(sample.tag)
                if code is None:
                    other.append((index, sample))
                else:
                    t_ms[index] = sample.t_ms
                    tag[index] = code
                    values[index] = np.nan
                    values[index, :len(sample.values)] = sample.values
                    keep[index] = True
            previous = index + 1
        self._account_fast(buffer, tag, starts, ends, previous, count)
        lines = np.flatnonzero(keep)
        return ParsedArrays(t_ms[lines], tag[lines], values[lines], lines, other)

    def _account_fast(self, buffer: bytes, tag: np.ndarray, starts: np.ndarray,
                      ends: np.ndarray, first: int, stop: int) -> None:
        """Counters and recording for the fast lines first..stop-1 (consecutive)."""
        count = stop - first
        if count <= 0:
            return
        stats = self.stats
        stats.lines += count
        stats.good += count
        per_tag = stats.per_tag
        counts = np.bincount(tag[first:stop], minlength=4).tolist()
        present = [code for code in range(4) if counts[code]]
        if any(FILTER_TAGS[code] not in per_tag for code in present):
            # A tag seen for the first time: keep per_tag in first-seen order, like LineParser.
            present.sort(key=lambda code: int(np.argmax(tag[first:stop] == code)))
        for code in present:
            name = FILTER_TAGS[code]
            per_tag[name] = per_tag.get(name, 0) + counts[code]
        if self.raw_block_sink is not None:
            self.raw_block_sink(buffer[starts[first]:ends[stop - 1] + 1], count)
        elif self.raw_sink is not None:
            sink = self.raw_sink
            for start, end in zip(starts[first:stop].tolist(), ends[first:stop].tolist()):
                sink(buffer[start:end + 1])


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernel before the first chunk arrives."""
    FastLineParser().feed_arrays(b"1\tGYR\t1.0\t-2.5E-3\t0\n2\tORI\t-1.0\t0.0\t0.0\t0.0\n")
