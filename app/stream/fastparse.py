"""A compiled line parser for the live path: bytes -> arrays, identical to :class:`LineParser`.

:class:`FastLineParser` is a :class:`~app.stream.protocol.LineParser` whose :meth:`feed_arrays`
scans the received bytes in one nogil numba kernel. The kernel handles the lines that make up
a live stream -- ``<time>\\tGYR|ACC|MAG\\t<3 numbers>`` and ``<time>\\tORI\\t<4 numbers>`` in
plain Java float text, checked against the physical bounds -- and the junk a flood is made of:
empty lines, lines with control bytes ("binary data"), lines without a TAB ("no tag") or with
a bad time, and samples out of range are counted in the kernel, without a Python call per line.
Every other line (other tags, 3-value ORI, NaN/Infinity, long mantissas, other bad lines, lines
over MAX_LINE_BYTES, non-ASCII bytes) goes to the inherited Python :meth:`LineParser._line`, in
line order (as do the first damaged lines, for their example messages), so every sample,
count, example message and recorded byte is exactly what :class:`LineParser` gives, whatever
the chunking.

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
from pathlib import Path

import numpy as np

from ekf.fast.jit import check_cache

from app.stream.protocol import (DEFAULT_LIMITS, FILTER_TAGS, KERNEL_BOUND_SLOTS, KERNEL_FLOORS,
                                 KERNEL_NAMES, KERNEL_WIDTHS, MAX_BAD_EXAMPLES, MAX_LINE_BYTES,
                                 MAX_TIME_DIGITS, MAX_WIDTH, N_FILTER_TAGS, REFERENCE_CODE,
                                 TABLE_KEY, TAG_CODES, WIDTHS, Limits, LineParser, ParseError,
                                 Sample, jit, parse_line)

_POW10 = np.array([float(10 ** k) for k in range(23)])   # exact doubles
# Kernel kinds of a line: Python parses it / compiled sample / compiled sample with numbers
# Python converts / empty / damaged (reason code below)
_PYTHON, _FAST, _FAST_SLOW, _EMPTY, _DAMAGED = 0, 1, 2, 3, 4
#: Reason codes of the lines the kernel finds damaged.
KERNEL_REASONS = {1: "binary data", 2: "no tag", 3: "bad time",
                  **{4 + code: f"{name} out of range" for code, name in enumerate(FILTER_TAGS)}}



@jit
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


@jit
def _in_bounds(v, tag, bounds):
    """The physical bounds of protocol.check_limits, with the same arithmetic (squared norms
    added left to right against the same squared bounds)."""
    slot = KERNEL_BOUND_SLOTS[tag]
    if slot >= 0:
        norm2 = (v[0] * v[0] + v[1] * v[1]) + v[2] * v[2]
        return norm2 <= bounds[slot] and (not KERNEL_FLOORS[tag] or norm2 >= bounds[5])
    for j in range(4):
        if not -1.0 <= v[j] <= 1.0:
            return False
    norm2 = ((v[0] * v[0] + v[1] * v[1]) + v[2] * v[2]) + v[3] * v[3]
    return bounds[3] <= norm2 <= bounds[4]


@jit
def _parse_line(buf, a, b, max_line_bytes, pow10, bounds, out_t, out_tag, out_v, k, slow,
                n_slow):
    """Line buf[a:b] (b = index of its LF). Fills row k; returns (kind, n_slow, reason): kind
    _FAST when the line is a sample handled here, _FAST_SLOW when also some numbers need
    Python's float() (their (row, column, start, end) appended to slow; bounds checked after),
    _DAMAGED (reason 4 + tag) for a sample out of bounds, _PYTHON when Python must parse it."""
    e = b
    if e > a and buf[e - 1] == 13:       # CRLF
        e -= 1
    if e - a > max_line_bytes:
        return _PYTHON, n_slow, 0
    p = a
    t = 0
    while p < e and 48 <= buf[p] <= 57:
        t = t * 10 + (buf[p] - 48)
        p += 1
        if p - a > MAX_TIME_DIGITS:
            return _PYTHON, n_slow, 0
    if p == a or p + 5 > e or buf[p] != 9 or buf[p + 4] != 9:
        return _PYTHON, n_slow, 0
    c0 = buf[p + 1]
    c1 = buf[p + 2]
    c2 = buf[p + 3]
    tag = -1
    for code in range(KERNEL_NAMES.shape[0]):
        if c0 == KERNEL_NAMES[code, 0] and c1 == KERNEL_NAMES[code, 1] \
                and c2 == KERNEL_NAMES[code, 2]:
            tag = code
            break
    if tag < 0:
        return _PYTHON, n_slow, 0
    count = KERNEL_WIDTHS[tag]
    quaternion = KERNEL_BOUND_SLOTS[tag] < 0
    p += 5
    first_slow = n_slow
    for j in range(count):
        if j > 0:
            if p >= e or buf[p] != 9:
                return _PYTHON, first_slow, 0
            p += 1
        field_start = p
        value, p, exact = _number(buf, p, e, pow10)
        if p < 0:
            return _PYTHON, first_slow, 0
        out_v[k, j] = value
        if not exact:
            if n_slow >= slow.shape[0]:
                return _PYTHON, first_slow, 0
            slow[n_slow, 0] = k
            slow[n_slow, 1] = j
            slow[n_slow, 2] = field_start
            slow[n_slow, 3] = p
            n_slow += 1
    if p != e:
        return _PYTHON, first_slow, 0
    for j in range(count, out_v.shape[1]):
        out_v[k, j] = np.nan
    if n_slow == first_slow:
        if not _in_bounds(out_v[k], tag, bounds):
            return _DAMAGED, first_slow, 4 + tag
        if quaternion and out_v[k, 0] < 0.0:   # q and -q: keep w >= 0 (parse_line)
            for j in range(4):
                out_v[k, j] = -out_v[k, j]
    out_t[k] = t
    out_tag[k] = tag
    return (_FAST if n_slow == first_slow else _FAST_SLOW), n_slow, 0


@jit
def _classify(buf, a, b, max_line_bytes):
    """A line the sample path did not take: (kind, reason) as parse_line would judge it, for
    the cases decided by ASCII bytes alone -- _EMPTY (whitespace only), _DAMAGED for a control
    byte (1), no TAB (2) or a bad time (3) -- else _PYTHON."""
    e = b
    if e > a and buf[e - 1] == 13:       # the CR of a CRLF (LineParser._line)
        e -= 1
    if e - a > max_line_bytes:
        return _PYTHON, 0                # too long: Python counts it
    if e > a and buf[e - 1] == 13:       # parse_line strips one more CR
        e -= 1
    blank = True
    high = False
    tab = -1
    for p in range(a, e):
        c = buf[p]
        if c < 9 or 14 <= c <= 27 or c == 127:
            return _DAMAGED, 1           # control byte: never whitespace, whatever else
        if c >= 128:
            high = True                  # UTF-8 (or not): Python decides
        elif not (c == 9 or c == 11 or c == 12 or c == 13 or 28 <= c <= 32):
            blank = False
        if c == 9 and tab < 0:
            tab = p
    if high:
        return _PYTHON, 0
    if blank:
        return _EMPTY, 0
    if tab < 0:
        return _DAMAGED, 2
    if tab == a or tab - a > MAX_TIME_DIGITS:
        return _DAMAGED, 3
    for p in range(a, tab):
        if not 48 <= buf[p] <= 57:
            return _DAMAGED, 3
    return _PYTHON, 0


@jit
def _scan(buf, max_line_bytes, pow10, bounds, out_t, out_tag, out_v, out_kind, out_reason,
          out_start, out_end, out_line, slow):
    """Every LF-terminated line of buf. Empty lines are only counted; every other line gets a
    row: its span, its index among all lines (out_line), its kind and, when handled here, its
    sample. Returns (rows, numbers left to Python in slow, empty lines, lines)."""
    n = 0
    n_slow = 0
    n_empty = 0
    ordinal = 0
    line_start = 0
    size = buf.shape[0]
    for p in range(size):
        if buf[p] != 10:
            continue
        if p == line_start:
            n_empty += 1
        else:
            kind, n_slow, reason = _parse_line(buf, line_start, p, max_line_bytes, pow10,
                                               bounds, out_t, out_tag, out_v, n, slow, n_slow)
            if kind == _PYTHON:
                kind, reason = _classify(buf, line_start, p, max_line_bytes)
            if kind == _EMPTY:
                n_empty += 1
            else:
                out_kind[n] = kind
                out_reason[n] = reason
                out_start[n] = line_start
                out_end[n] = p
                out_line[n] = ordinal
                n += 1
        ordinal += 1
        line_start = p + 1
    return n, n_slow, n_empty, ordinal


@jit
def _count_good(buf, max_line_bytes, pow10, bounds, at_most, candidates):
    """The complete lines of buf the sample path parses within bounds, counted up to at_most;
    with the spans of up to len(candidates) lines only Python can judge in candidates (the
    count, the candidates found)."""
    out_t = np.empty(1, np.int64)
    out_tag = np.empty(1, np.int64)
    out_v = np.empty((1, MAX_WIDTH))
    slow = np.empty((MAX_WIDTH, 4), np.int64)
    n_good = 0
    n_candidates = 0
    line_start = 0
    for p in range(buf.shape[0]):
        if buf[p] != 10:
            continue
        if p > line_start:
            kind, _, _ = _parse_line(buf, line_start, p, max_line_bytes, pow10, bounds,
                                     out_t, out_tag, out_v, 0, slow, 0)
            if kind == _FAST:
                n_good += 1
                if n_good >= at_most:
                    return n_good, n_candidates
            elif kind == _FAST_SLOW or (kind == _PYTHON and _classify(
                    buf, line_start, p, max_line_bytes)[0] == _PYTHON):
                if n_candidates < candidates.shape[0]:
                    candidates[n_candidates, 0] = line_start
                    candidates[n_candidates, 1] = p
                    n_candidates += 1
        line_start = p + 1
    return n_good, n_candidates


def count_good_lines(data: bytes, limits: Limits = DEFAULT_LIMITS, at_most: int = 1,
                     max_candidates: int = 8) -> int:
    """How many complete lines of `data` parse to a sample within `limits`, counted up to
    `at_most` (the count stops there). The TCP server's measure of "this connection streams
    valid lines, at this rate": compiled; of the lines the kernel cannot judge, at most
    `max_candidates` go to parse_line."""
    if b"\n" not in data:
        return 0
    at_most = max(1, int(at_most))
    candidates = np.empty((max_candidates, 2), np.int64)
    good, count = _count_good(np.frombuffer(data, np.uint8), MAX_LINE_BYTES, _POW10,
                              np.array(limits.squared), at_most, candidates)
    for start, end in candidates[:count].tolist():
        if good >= at_most:
            break
        try:
            parse_line(data[start:end].decode("utf-8", "replace"), limits)
        except ParseError:
            continue
        good += 1
    return good


@dataclass
class ParsedArrays:
    """The samples of a chunk of lines, in line order.

    Filter tags (GYR, ACC, MAG, ORI) as arrays: t_ms (n,) int64 phone ms; tag (n,) int64 codes
    of :data:`TAG_CODES`; values (n, 4) float64 (NaN in column 3 for 3-value tags; ORI w >= 0);
    line (n,) the line's index in the chunk. other: (line index, Sample) of every other tag.
    """

    t_ms: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    tag: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    values: np.ndarray = field(default_factory=lambda: np.empty((0, MAX_WIDTH)))
    line: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    other: list[tuple[int, Sample]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.t_ms) + len(self.other)

    def filter_samples(self) -> list[Sample]:
        """The filter-tag rows as Samples (values as Python floats)."""
        return [Sample(int(t), FILTER_TAGS[tag], tuple(row[:WIDTHS[tag]]))
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
    values = np.full((n, MAX_WIDTH), np.nan)
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
                 raw_block_sink: Callable[[bytes, int], None] | None = None,
                 limits: Limits = DEFAULT_LIMITS) -> None:
        super().__init__(raw_sink, max_line_bytes, limits)
        self.raw_block_sink = raw_block_sink
        self._bounds = np.array(limits.squared)

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
        """The `count` complete lines of buffer: one kernel call, then Python for the lines
        it leaves (see the module docstring) and bulk counts for the rest."""
        t_ms = np.empty(count, np.int64)
        tag = np.empty(count, np.int64)
        values = np.empty((count, MAX_WIDTH))
        kind = np.empty(count, np.int8)
        reason = np.empty(count, np.int8)
        starts = np.empty(count, np.int64)
        ends = np.empty(count, np.int64)
        line = np.empty(count, np.int64)
        # a sample line has at least 12 bytes for its at most 4 numbers
        slow_numbers = np.empty((min(MAX_WIDTH * count, len(buffer) // 3 + 4), 4), np.int64)
        n, n_slow, n_empty, lines = _scan(np.frombuffer(buffer, dtype=np.uint8),
                                          self.max_line_bytes, _POW10, self._bounds, t_ms, tag,
                                          values, kind, reason, starts, ends, line,
                                          slow_numbers)
        assert lines == count
        if n_slow:
            self._convert_slow(buffer, slow_numbers[:n_slow], tag, values, kind, reason)
        stats = self.stats
        base = stats.lines
        keep = (kind[:n] == _FAST) | (kind[:n] == _FAST_SLOW)
        fast = np.flatnonzero(keep)
        good = keep.copy()          # every line that gave a sample: the recorded ones
        fast_ori = np.flatnonzero(keep & (tag[:n] == REFERENCE_CODE))
        first_ori = int(fast_ori[0]) if len(fast_ori) else n
        other = self._python_lines(buffer, kind[:n], reason[:n], starts, ends, line, keep,
                                   good, t_ms, tag, values, base, first_ori)
        if len(fast_ori):
            self._ori4_seen = True
        stats.lines = base + count
        stats.empty += n_empty
        self._count_fast(tag[fast])
        recorded = np.flatnonzero(good)
        self._record(buffer, starts[recorded], ends[recorded])
        rows = np.flatnonzero(keep)
        if len(rows) == count and not other:
            return ParsedArrays(t_ms, tag, values, line)
        return ParsedArrays(t_ms[rows], tag[rows], values[rows], line[rows], other)

    def _convert_slow(self, buffer: bytes, slow: np.ndarray, tag: np.ndarray,
                      values: np.ndarray, kind: np.ndarray, reason: np.ndarray) -> None:
        """Valid, finite numbers beyond the exact fast path (1e160 among them): Python's own
        conversion, then the bounds (a row outside them is damaged, "<TAG> out of range": the
        line is well formed, so that is what parse_line finds too)."""
        rows, columns, first, last = slow.T.tolist()
        values[rows, columns] = [float(buffer[a:b]) for a, b in zip(first, last)]
        rows = np.unique(np.asarray(rows))
        v = values[rows]
        codes = tag[rows]
        squared = np.asarray(self.limits.squared)
        _, _, _, low2, high2, floor2 = self.limits.squared
        with np.errstate(invalid="ignore", over="ignore"):    # inf is out of range: fine
            norm3 = (v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1]) + v[:, 2] * v[:, 2]
            norm4 = norm3 + v[:, 3] * v[:, 3]
            ori_ok = (np.abs(v) <= 1.0).all(axis=1) & (low2 <= norm4) & (norm4 <= high2)
        slots = KERNEL_BOUND_SLOTS[codes]
        quaternion = slots < 0
        vector_ok = (norm3 <= squared[np.maximum(slots, 0)]) \
            & (~KERNEL_FLOORS[codes] | (norm3 >= floor2))
        ok = np.where(quaternion, ori_ok, vector_ok)
        kind[rows[~ok]] = _DAMAGED
        reason[rows[~ok]] = 4 + codes[~ok]
        ori = rows[ok & quaternion]
        flip = ori[values[ori, 0] < 0.0]
        values[flip] = -values[flip]          # q and -q: keep w >= 0 (parse_line)

    def _python_lines(self, buffer: bytes, kind: np.ndarray, reason: np.ndarray,
                      starts: np.ndarray, ends: np.ndarray, line: np.ndarray, keep: np.ndarray,
                      good: np.ndarray, t_ms: np.ndarray, tag: np.ndarray, values: np.ndarray,
                      base: int, first_ori: int) -> list[tuple[int, Sample]]:
        """The lines Python parses, in line order, numbered as LineParser numbers them; the
        damaged lines the kernel found are counted by reason (the first ones through Python,
        for their example messages). Returns the other-tag samples with their line index."""
        stats = self.stats
        python_rows = np.flatnonzero(kind == _PYTHON)
        damaged_rows = np.flatnonzero(kind == _DAMAGED)
        wanted = max(0, MAX_BAD_EXAMPLES - len(stats.bad_examples))
        visit = np.union1d(python_rows, damaged_rows[:wanted]) if wanted else python_rows
        other: list[tuple[int, Sample]] = []
        for index in visit.tolist():
            stats.lines = base + int(line[index])
            if index > first_ori:
                self._ori4_seen = True   # a 4-value ORI line came before (compiled)
            if kind[index] == _DAMAGED and len(stats.bad_examples) >= MAX_BAD_EXAMPLES:
                self._count_bad("damaged", "", KERNEL_REASONS[int(reason[index])])
                continue
            out: list[Sample] = []
            if not self._line(buffer[starts[index]:ends[index]], True, out, record=False):
                continue
            sample = out[0]
            good[index] = True
            code = TAG_CODES.get(sample.tag)
            if code is None:
                other.append((int(line[index]), sample))
                continue
            t_ms[index] = sample.t_ms
            tag[index] = code
            values[index] = np.nan
            values[index, :len(sample.values)] = sample.values
            keep[index] = True
        bulk = damaged_rows[wanted:]
        if len(bulk):
            stats.damaged += len(bulk)
            reasons = stats.damaged_reasons
            for code, number in enumerate(np.bincount(reason[bulk]).tolist()):
                if number:
                    name = KERNEL_REASONS[code]
                    reasons[name] = reasons.get(name, 0) + number
        return other

    def _count_fast(self, tags: np.ndarray) -> None:
        if not len(tags):
            return
        stats = self.stats
        stats.good += len(tags)
        per_tag = stats.per_tag
        counts = np.bincount(tags, minlength=N_FILTER_TAGS).tolist()
        present = [code for code in range(N_FILTER_TAGS) if counts[code]]
        if any(FILTER_TAGS[code] not in per_tag for code in present):
            # A tag seen for the first time: keep per_tag in first-seen order, like LineParser.
            present.sort(key=lambda code: int(np.argmax(tags == code)))
        for code in present:
            name = FILTER_TAGS[code]
            per_tag[name] = per_tag.get(name, 0) + counts[code]

    def _record(self, buffer: bytes, starts: np.ndarray, ends: np.ndarray) -> None:
        """The good lines (spans in line order, LF included) to the sinks: runs of adjacent
        lines as one block each."""
        if not len(starts) or (self.raw_block_sink is None and self.raw_sink is None):
            return
        stops = ends + 1
        if self.raw_block_sink is None:
            for start, stop in zip(starts.tolist(), stops.tolist()):
                self.raw_sink(buffer[start:stop])
            return
        breaks = np.flatnonzero(starts[1:] != stops[:-1]) + 1
        if not len(breaks):
            data = buffer[int(starts[0]):int(stops[-1])]
        else:
            first = starts[np.concatenate(([0], breaks))].tolist()
            last = stops[np.concatenate((breaks - 1, [len(stops) - 1]))].tolist()
            data = b"".join(buffer[a:b] for a, b in zip(first, last))
        self.raw_block_sink(data, len(starts))


@jit
def _table_key():
    return TABLE_KEY


check_cache(_table_key, globals(), TABLE_KEY)


def kernel_cached() -> bool | None:
    """Whether numba's on-disk cache holds the parser's kernel (None when that is unknown): a
    first start after an install has none."""
    try:
        return Path(_scan._cache._cache_file._index_path).exists()
    except (AttributeError, OSError):
        return None


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernel before the first chunk arrives."""
    FastLineParser().feed_arrays(b"1\tGYR\t1.0\t-2.5E-3\t0\n2\tORI\t-1.0\t0.0\t0.0\t0.0\n")
    count_good_lines(b"x\n1\tGYR\t1.0\t-2.5E-3\t0\n")    # the TCP server's measure
