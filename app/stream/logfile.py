"""Read a whole log file (the phone's "log to file" output, or our ``raw.txt``) into ordered samples.

The same compiled parser (:class:`~app.stream.fastparse.FastLineParser`) and
:class:`~app.stream.ordering.TimeOrderer` the live stream uses, so a file and the stream it was
recorded from give the same samples; floods of empty or junk lines cost no Python per line (50 MB
of newlines read in about a second). A file with NUL bytes or other junk in places is read with
those lines counted as damaged; only a file that is mostly binary is refused.
"""

from __future__ import annotations

import gzip
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from app.stream.fastparse import TAG_WIDTHS, FastLineParser, ParsedArrays
from app.stream.lines import LogError, check_text, open_log_bytes, why_unreadable
from app.stream.ordering import OrderedArrays, OrderStats, TimeOrderer
from app.stream.protocol import (DEFAULT_LIMITS, FILTER_TAGS, Limits, ParseStats, Sample,
                                 reasons_text)
from app.stream.repeats import Last, repeats

_CHUNK_BYTES = 1 << 22


@dataclass
class LogStats:
    """What reading a log found. ``parse`` counts lines, ``order`` the time ordering."""

    path: str
    parse: ParseStats
    order: OrderStats
    repeated: int = 0       # samples repeated exactly (the estimators use each once)

    @property
    def damaged(self) -> int:
        return self.parse.damaged

    @property
    def unknown(self) -> int:
        return self.parse.unknown

    @property
    def too_long(self) -> int:
        return self.parse.too_long

    @property
    def out_of_order(self) -> int:
        return self.order.out_of_order

    @property
    def clock_quirks(self) -> list[str]:
        return self.order.clock_quirks

    @property
    def first_bad_line_number(self) -> int | None:
        return self.parse.first_bad_line_number

    def summary(self) -> str:
        """One line for stderr, e.g. ``log.txt: 6212 lines (ACC 1767, ...), 2 damaged (first at
        line 1191: ...), 420 out of order, clock quirks: ...``."""
        parse, order = self.parse, self.order
        tags = ", ".join(f"{tag} {count}" for tag, count in sorted(parse.per_tag.items()))
        parts = [f"{Path(self.path).name}: {parse.lines} lines ({tags or 'no samples'})"]
        if parse.damaged:
            parts.append(f"{parse.damaged} damaged ({reasons_text(parse.damaged_reasons)})")
        if parse.unknown:
            names = ", ".join(sorted(parse.unknown_tags)) or "?"
            parts.append(f"{parse.unknown} unknown-tag ({names})")
        if parse.too_long:
            parts.append(f"{parse.too_long} too long")
        if parse.first_bad_line_number is not None:
            parts.append(f"first bad line {parse.first_bad_line_number}: {parse.first_bad_message}")
        if order.out_of_order:
            parts.append(f"{order.out_of_order} out of order (dropped)")
        if self.repeated:
            parts.append(f"{self.repeated} samples repeated exactly (each used once)")
        if order.restarts:
            parts.append(f"{order.restarts} time-base restarts")
        if order.sessions:
            parts.append(f"{order.sessions} new sessions (a clock that does not continue: the "
                         "filter starts afresh)")
        if order.clock_quirks:
            parts.append("clock quirks: " + "; ".join(order.clock_quirks))
        return ", ".join(parts)


@dataclass
class LogArrays:
    """Filter-tag samples on a common time axis.

    t_ms: (N,) int64 distinct sorted aligned phone times, ms. gyr (rad/s), acc (m/s^2),
    mag (uT): (N, 3) float64; ori: (N, 4) float64 w-first. A row is NaN where that tag has no
    sample at that time; when a tag has two samples at one time the last is kept.
    """

    t_ms: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    ori: np.ndarray

    @property
    def t_s(self) -> np.ndarray:
        return self.t_ms.astype(np.float64) / 1000.0


@dataclass
class LogData:
    """samples: the filter tags (GYR, ACC, MAG, ORI) in release order with aligned times;
    other: every other tag's samples in file order, times untouched; session_starts: indices
    into samples where a new session starts (a clock that does not continue the previous one:
    the estimators start afresh there)."""

    path: str
    samples: list[Sample]
    other: list[Sample]
    stats: LogStats
    session_starts: list[int] = field(default_factory=list)
    _arrays: LogArrays | None = field(default=None, repr=False)

    @property
    def first_bad_line_number(self) -> int | None:
        return self.stats.first_bad_line_number

    @property
    def duration_s(self) -> float:
        if not self.samples:
            return 0.0
        return (self.samples[-1].t_ms - self.samples[0].t_ms) / 1000.0

    def to_arrays(self) -> LogArrays:
        """The samples as arrays on the distinct times (see :class:`LogArrays`). Cached."""
        if self._arrays is None:
            self._arrays = samples_to_arrays(self.samples)
        return self._arrays


def samples_to_arrays(samples: list[Sample]) -> LogArrays:
    """Ordered filter-tag samples -> :class:`LogArrays` (other tags ignored)."""
    times = np.fromiter((s.t_ms for s in samples if s.tag in _WIDTH), dtype=np.int64)
    t_ms = np.unique(times)
    columns = {tag: np.full((len(t_ms), width), np.nan) for tag, width in _WIDTH.items()}
    for tag, width in _WIDTH.items():
        chosen = [s for s in samples if s.tag == tag]
        if not chosen:
            continue
        tag_times = np.fromiter((s.t_ms for s in chosen), dtype=np.int64, count=len(chosen))
        values = np.array([s.values for s in chosen], dtype=np.float64).reshape(-1, width)
        rows = np.searchsorted(t_ms, tag_times)
        columns[tag][rows] = values   # fancy assignment: the last of duplicate rows wins
    return LogArrays(t_ms, **{tag.lower(): column for tag, column in columns.items()})


_WIDTH = dict(zip(FILTER_TAGS, TAG_WIDTHS))


class _Collector:
    """Ordered arrays from the orderer, piece by piece, with the session starts as indices
    into the whole."""

    def __init__(self, orderer: TimeOrderer) -> None:
        self.orderer = orderer
        self.pieces: list[OrderedArrays] = []
        self.other: list[Sample] = []
        self.session_starts: list[int] = []
        self.count = 0
        self.repeated = 0
        self._last: Last = None

    def parsed(self, parsed: ParsedArrays) -> None:
        self.other.extend(sample for _, sample in parsed.other)
        if len(parsed.t_ms):
            self.ordered(self.orderer.push_arrays(parsed.t_ms, parsed.tag, parsed.values))

    def ordered(self, ordered: OrderedArrays) -> None:
        if len(ordered.session_starts):
            self._last = None
        mask, self._last = repeats(ordered.t_ms, ordered.tag, ordered.values, self._last)
        self.repeated += int(mask.sum())
        self.session_starts.extend(self.count + int(k) for k in ordered.session_starts)
        self.pieces.append(ordered)
        self.count += len(ordered)

    def samples(self) -> list[Sample]:
        pieces = [piece for piece in self.pieces if len(piece)]
        if not pieces:
            return []
        t_ms = np.concatenate([piece.t_ms for piece in pieces]).tolist()
        tags = np.concatenate([piece.tag for piece in pieces]).tolist()
        values = np.concatenate([piece.values for piece in pieces]).tolist()
        return [Sample(t, FILTER_TAGS[code], tuple(row[:TAG_WIDTHS[code]]))
                for t, code, row in zip(t_ms, tags, values)]


def read_log(path: str | Path, orderer: TimeOrderer | None = None,
             limits: Limits = DEFAULT_LIMITS) -> LogData:
    """Read a log file into ordered samples. Damaged lines (values outside `limits` among
    them) are counted, never fatal.

    Raises LogError when the file is missing, unreadable, empty, mostly binary, or holds no
    line of the phone's format at all.
    """
    path = Path(path)
    parser = FastLineParser(limits=limits)
    collector = _Collector(orderer or TimeOrderer())
    total = 0
    try:
        with open_log_bytes(path) as stream:
            while True:
                chunk = stream.read(_CHUNK_BYTES)
                if not chunk:
                    break
                if total == 0:
                    check_text(path, chunk)
                total += len(chunk)
                collector.parsed(parser.feed_arrays(chunk))
    except (OSError, EOFError, zlib.error) as error:
        raise LogError(f"{path}: cannot read ({why_unreadable(error)})") from None
    collector.parsed(parser.finish_arrays())
    collector.ordered(collector.orderer.flush_arrays())
    stats = LogStats(str(path), parser.stats, collector.orderer.stats, collector.repeated)
    if total == 0:
        raise LogError(f"{path}: empty file")
    if parser.stats.good == 0:
        where = parser.stats.first_bad_line_number
        detail = f" (line {where}: {parser.stats.first_bad_message})" if where else ""
        raise LogError(f"{path}: no line in the phone's format{detail}")
    return LogData(str(path), collector.samples(), collector.other, stats,
                   collector.session_starts)
