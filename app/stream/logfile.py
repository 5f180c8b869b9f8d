"""Read a log file (the phone's "log to file" output, or our ``raw.txt``) into ordered samples:
chunk by chunk (:class:`LogFile`: memory for one chunk whatever the file's size) or whole
(:func:`read_log`). Either gives :class:`LogData`, the ordered samples as arrays (a whole log, or a
chunk of one); no object per sample.

The same compiled parser (:class:`~app.stream.fastparse.FastLineParser`) and
:class:`~app.stream.ordering.TimeOrderer` the live stream uses, so a file and the stream it was
recorded from give the same samples, and a log read in chunks of any size gives the samples it
gives read whole; floods of empty or junk lines cost no Python per line (50 MB of newlines read
in about a second). A file with NUL bytes or other junk in places is read with those lines
counted as damaged; only a file that is mostly binary is refused.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from app.stream.fastparse import FastLineParser, samples_to_arrays
from app.stream.lines import CHUNK_BYTES, LogError, log_chunks
from app.stream.ordering import Last, OrderedArrays, OrderStats, TimeOrderer, repeats
from app.stream.protocol import (DEFAULT_LIMITS, FILTER_TAGS, MAX_WIDTH, REFERENCE_CODE, WIDTHS,
                                 Limits, ParseStats, Sample, reasons_text)


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
    """Ordered filter-tag samples as arrays: a whole log (:func:`read_log`) or a chunk of one
    (:meth:`LogFile.chunks`, :meth:`chunks`). The one form in which the offline path takes a log:
    `filter` and `evaluate`, Tune's re-runs and the auto-tune, the smoother and calibration.

    t_ms (n,) int64 aligned phone ms; tag (n,) int64 codes (GYR 0, ACC 1, MAG 2, ORI 3);
    values (n, 4) float64 (rad/s, m/s^2, uT; ORI w x y z; NaN in column 3 for the 3-value
    tags), in release order (at equal times GYR, ACC, MAG, ORI). session_starts: indices where
    a new session starts (a clock that does not continue the previous one: the estimators start
    afresh there; an index may be n, before the next chunk's first sample). stats: what reading
    the whole log found (None for a chunk).
    """

    path: str
    t_ms: np.ndarray
    tag: np.ndarray
    values: np.ndarray
    session_starts: tuple[int, ...] = ()
    stats: LogStats | None = None
    _arrays: LogArrays | None = field(default=None, repr=False)
    _ori_times: np.ndarray | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.t_ms)

    @property
    def ori_times(self) -> np.ndarray:
        """The distinct times of the phone's orientation (ORI) samples, sorted. Cached."""
        if self._ori_times is None:
            self._ori_times = np.unique(self.t_ms[self.tag == REFERENCE_CODE])
        return self._ori_times

    @property
    def start_ms(self) -> int:
        return int(self.t_ms[0]) if len(self.t_ms) else 0

    def until(self, t_end_ms: float | None) -> LogData:
        """The samples up to and including t_end_ms (None: all): a run scored up to there needs
        nothing later."""
        if t_end_ms is None:
            return self
        n = int(np.searchsorted(self.t_ms, t_end_ms, side="right"))
        return LogData(self.path, self.t_ms[:n], self.tag[:n], self.values[:n],
                       tuple(k for k in self.session_starts if k < n),
                       _ori_times=self.ori_times[self.ori_times <= t_end_ms])

    @property
    def first_bad_line_number(self) -> int | None:
        return None if self.stats is None else self.stats.first_bad_line_number

    @property
    def duration_s(self) -> float:
        if not len(self.t_ms):
            return 0.0
        return int(self.t_ms[-1] - self.t_ms[0]) / 1000.0

    def chunks(self, size: int = 1 << 16) -> Iterator[LogData]:
        """The samples in chunks of `size` (what :meth:`LogFile.chunks` gives for a file)."""
        starts = np.asarray(self.session_starts, np.int64)
        for first in range(0, max(len(self), 1), size):
            last = min(first + size, len(self))
            final = last == len(self)
            local = starts[(starts >= first) & ((starts < last) | final)] - first
            yield LogData(self.path, self.t_ms[first:last], self.tag[first:last],
                          self.values[first:last], tuple(int(k) for k in local))

    def to_arrays(self) -> LogArrays:
        """The samples as arrays on the distinct times (see :class:`LogArrays`). Cached."""
        if self._arrays is None:
            t_ms = np.unique(self.t_ms)
            columns = {}
            for code, (tag, width) in enumerate(zip(FILTER_TAGS, WIDTHS)):
                column = np.full((len(t_ms), width), np.nan)
                chosen = self.tag == code
                # fancy assignment: the last of duplicate rows wins
                column[np.searchsorted(t_ms, self.t_ms[chosen])] = self.values[chosen, :width]
                columns[tag.lower()] = column
            self._arrays = LogArrays(t_ms, **columns)
        return self._arrays

    @staticmethod
    def from_samples(samples: Iterable[Sample], path: str = "samples") -> LogData:
        """Samples already in time order (a simulation, a test's lines) as a LogData; other
        tags are left out."""
        arrays = samples_to_arrays(list(samples))
        return LogData(path, arrays.t_ms, arrays.tag, arrays.values)

    @staticmethod
    def concatenate(path: str, chunks: list[LogData], stats: LogStats | None = None) -> LogData:
        """One LogData of chunks in order."""
        starts: list[int] = []
        count = 0
        for chunk in chunks:
            starts.extend(count + k for k in chunk.session_starts)
            count += len(chunk)
        if not chunks:
            return LogData(path, np.empty(0, np.int64), np.empty(0, np.int64),
                           np.empty((0, MAX_WIDTH)), tuple(starts), stats)
        return LogData(path, np.concatenate([c.t_ms for c in chunks]),
                       np.concatenate([c.tag for c in chunks]),
                       np.concatenate([c.values for c in chunks]), tuple(starts), stats)


class LogFile:
    """A log file read chunk by chunk through the compiled parser and the time orderer: each
    :meth:`chunks` is one pass over the file (read again), holding one chunk at a time.

    Raises LogError (from the iteration) when the file is missing, unreadable, empty, mostly
    binary, or holds no line of the phone's format at all; damaged lines (values outside
    `limits` among them) are counted, never fatal."""

    def __init__(self, path: str | Path, limits: Limits = DEFAULT_LIMITS,
                 chunk_bytes: int = CHUNK_BYTES) -> None:
        self.path = str(path)
        self.limits = limits
        self.chunk_bytes = chunk_bytes
        self.stats: LogStats | None = None      # what the latest complete pass found
        self._read = 0                          # bytes of the file the current pass has read

    @property
    def fraction_read(self) -> float:
        """How much of the file the current (or latest) pass has read, 0 to 1."""
        try:
            size = Path(self.path).stat().st_size
        except OSError:
            return 0.0
        return min(1.0, self._read / size) if size else 1.0

    def _on_read(self, position: int) -> None:
        self._read = position

    def chunks(self) -> Iterator[LogData]:
        """The ordered samples, chunk by chunk (:class:`LogData` pieces, session starts as
        indices into each); :attr:`stats` is set when the pass completes."""
        parser = FastLineParser(limits=self.limits)
        orderer = TimeOrderer()
        repeated = 0
        last: Last = None

        def piece(ordered: OrderedArrays) -> LogData:
            nonlocal last, repeated
            if len(ordered.session_starts):
                last = None
            mask, last = repeats(ordered.t_ms, ordered.tag, ordered.values, last)
            repeated += int(mask.sum())
            return LogData(self.path, ordered.t_ms, ordered.tag, ordered.values,
                           tuple(int(k) for k in ordered.session_starts))

        path = Path(self.path)
        for data in log_chunks(path, self.chunk_bytes, self._on_read):
            parsed = parser.feed_arrays(data)
            if len(parsed.t_ms):
                ordered = orderer.push_arrays(parsed.t_ms, parsed.tag, parsed.values)
                if len(ordered) or len(ordered.session_starts):
                    yield piece(ordered)
        parsed = parser.finish_arrays()
        for ordered in ((orderer.push_arrays(parsed.t_ms, parsed.tag, parsed.values)
                         if len(parsed.t_ms) else None), orderer.flush_arrays()):
            if ordered is not None and (len(ordered) or len(ordered.session_starts)):
                yield piece(ordered)
        if parser.stats.good == 0:
            where = parser.stats.first_bad_line_number
            detail = f" (line {where}: {parser.stats.first_bad_message})" if where else ""
            raise LogError(f"{path}: no line in the phone's format{detail}")
        self.stats = LogStats(self.path, parser.stats, orderer.stats, repeated)


def read_log(path: str | Path, limits: Limits = DEFAULT_LIMITS,
             chunk_bytes: int = CHUNK_BYTES) -> LogData:
    """Read a whole log file into ordered samples (:class:`LogData`, with its stats). Damaged
    lines (values outside `limits` among them) are counted, never fatal.

    Raises LogError when the file is missing, unreadable, empty, mostly binary, or holds no
    line of the phone's format at all.
    """
    log = LogFile(path, limits, chunk_bytes)
    chunks = list(log.chunks())
    return LogData.concatenate(str(path), chunks, log.stats)
