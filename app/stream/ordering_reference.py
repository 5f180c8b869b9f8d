"""The executable specification of :class:`app.stream.ordering.TimeOrderer`, in plain Python.

The algorithm is described in :mod:`app.stream.ordering`, which also holds what both twins
share (their parameters, counters, the window rule and the clock alignment). Its steps are the
private methods below, in the order the compiled twin defines them (a test compares the
names); tests compare the two orderers' releases and counters.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable
from dataclasses import fields

from app.stream.ordering import (LAG_BUCKET_MS, OrderOptions, OrderStats, clock_offset,
                                 effective_window, segment_clock)
from app.stream.protocol import FILTER_TAGS, TAG_CODES, Sample


class ReferenceTimeOrderer:
    """Streaming reorder + clock alignment of filter-tag samples (see the module docstring),
    in plain Python: the executable specification of :class:`TimeOrderer` (tests compare them).

    push(sample) -> the samples released by it (aligned t_ms), flush() at end of stream.
    """

    def __init__(self, options: OrderOptions | None = None, **overrides: int) -> None:
        self.options = OrderOptions.of(options, **overrides)
        for item in fields(self.options):
            setattr(self, item.name, getattr(self.options, item.name))
        self.stats = OrderStats(window_ms=self.window_ms)
        self._heap: list[tuple[int, int, int, Sample]] = []
        self._sequence = 0
        self.last_released_ms: int | None = None
        self._offsets: dict[str, int] = {}
        self._continue_time = False
        self._suspects: list[Sample] = []             # samples that jumped, in arrival order
        self._suspect_span: dict[str, tuple[int, int]] = {}   # tag -> (first, latest) time
        self._new_segment(keep_offsets=False)
        self.stats.restarts = 0          # the first segment is no restart

    # -- public ------------------------------------------------------------------------------

    def push(self, sample: Sample) -> list[Sample]:
        """Take one sample (any tag); return what it releases, in release order."""
        if sample.tag not in TAG_CODES:
            return [sample]
        out: list[Sample] = []
        self.stats.pushed += 1
        self._place(sample, out)
        self._update_stats()
        return out

    def push_many(self, samples: Iterable[Sample]) -> list[Sample]:
        out: list[Sample] = []
        for sample in samples:
            if sample.tag in TAG_CODES:
                self.stats.pushed += 1
                self._place(sample, out)
            else:
                out.append(sample)
        self._update_stats()
        return out

    def flush(self) -> list[Sample]:
        """Release everything pending (end of stream). The segment stays open; samples whose
        jump no other sample confirmed are dropped (counted)."""
        out: list[Sample] = []
        self.stats.out_of_order += len(self._suspects)
        self._suspects = []
        self._suspect_span = {}
        self._release_all(out)
        return out

    def restart(self, continue_time: bool = False) -> list[Sample]:
        """Reconnect: release what is pending and learn the clocks again for what follows.
        continue_time (a looping replay): shift the next segment after the last release
        instead of starting a new session when its clock goes back."""
        out = self.flush()
        self._new_segment(keep_offsets=False)
        self._continue_time = bool(continue_time)
        self._update_stats()
        return out

    @property
    def pending(self) -> int:
        return len(self._heap) + len(self._suspects)

    # -- internals: the steps, in the compiled twin's order ---------------------------------------

    def _new_segment(self, keep_offsets: bool) -> None:
        # within one stream the reference tag keeps its clock offset into the next segment
        self._previous_offsets = dict(self._offsets) if keep_offsets else {}
        self._offsets = {}
        self._last: dict[str, int] = {}          # tag -> latest aligned time in this segment
        self._reference: str | None = None
        self._segment_start: int | None = None
        self._warm = False           # hold releases for startup_hold_ms: lets every tag show up
        self._newest: int | None = None
        self._last_new_tag_ms = 0
        self._late_since: dict[str, int] = {}    # tag -> first sample of its late block
        self._lag_current: dict[str, int] = {}   # tag -> largest lag in this lag bucket
        self._lag_previous: dict[str, int] = {}  # ... in the bucket before
        self._lag_bucket: int | None = None
        self.stats.offsets_ms = self._offsets
        self.stats.restarts += 1

    def _update_stats(self) -> None:
        lags = {tag: max(self._lag_current.get(tag, 0), self._lag_previous.get(tag, 0))
                for tag in FILTER_TAGS}
        self.stats.lags_ms = {tag: lag for tag, lag in lags.items() if lag > 0}
        self.stats.window_ms = self._window()

    def _window(self) -> int:
        lag = max([0] + list(self._lag_current.values()) + list(self._lag_previous.values()))
        return effective_window(lag, self.window_ms, self.max_window_ms)

    def _start_segment_clock(self, sample: Sample) -> int:
        """The reference tag of a new segment: its offset (a new session may start)."""
        self._reference = sample.tag
        base = self._previous_offsets.get(sample.tag, 0)
        t = sample.t_ms + base
        last = self.last_released_ms
        shift, new_session = segment_clock(t, last, self._continue_time, self.options)
        if new_session:
            self.last_released_ms = None
            self.stats.start_session(self.stats.released)
        self._continue_time = False
        if self.stats.restarts or last is not None:
            self.stats.start_segment(t + shift)
        self._segment_start = t + shift
        return base + shift

    def _learn_offset(self, sample: Sample) -> int:
        if self._reference is None:
            return self._start_segment_clock(sample)
        reference_offset = self._offsets[self._reference]
        offset = clock_offset(sample.t_ms, self._last[self._reference], reference_offset,
                              [self._offsets[tag] for tag in FILTER_TAGS if tag in self._offsets],
                              self.options)
        if offset is None:
            return reference_offset
        self.stats.note_clock(sample.tag, self._reference, offset - reference_offset)
        return offset

    def _late(self, tag: str, t: int, last: int) -> bool:
        """A sample more than gap_ms behind its tag's latest: a block written late (dropped),
        unless beyond the horizon or such samples have gone on for more than gap_ms of their
        own time (then the clock really went back)."""
        if last - t > self.late_horizon_ms:
            return False
        since = self._late_since.get(tag)
        if since is None:
            self._late_since[tag] = t
            return True
        return t - since <= self.gap_ms

    def _own_clock(self, tag: str, t: int) -> str:
        """"ok", "drop" (counted) or "segment" (a new time base) for a sample at aligned time
        t of a tag already seen in this segment."""
        last = self._last[tag]
        if t < last - self.gap_ms:
            return "drop" if self._late(tag, t, last) else "segment"
        if t > last + self.gap_ms:
            return "segment"
        if t < last:
            return "drop"
        self._late_since.pop(tag, None)
        return "ok"

    def _place(self, sample: Sample, out: list[Sample]) -> None:
        stats = self.stats
        tag = sample.tag
        offset = self._offsets.get(tag)
        if offset is not None:
            t = sample.t_ms + offset
            verdict = self._own_clock(tag, t)
            if verdict == "segment":
                # A pause, a reboot or another phone -- or one bad time stamp: held until
                # another sample confirms the new clock or the tag's old clock goes on.
                self._suspect(sample, t, out)
                return
            if tag in self._suspect_span:
                self._refute(tag)
            if verdict == "drop":
                stats.out_of_order += 1
                return
        first_of_tag = offset is None
        if first_of_tag:
            offset = self._learn_offset(sample)
            self._offsets[tag] = offset
            t = sample.t_ms + offset
            self._last_new_tag_ms = t
        newest = self._newest
        if newest is not None and 0 < newest - t <= self.max_window_ms \
                and newest - t > self._lag_current.get(tag, 0):
            self._lag_current[tag] = newest - t        # this tag arrives this far behind
        if self.last_released_ms is not None and t < self.last_released_ms:
            stats.out_of_order += 1
            # The tag still moves on: later samples are compared with this one.
            self._last[tag] = t
            return
        self._last[tag] = t
        if newest is None or t > newest:
            self._newest = t
            self._rotate_lags()
            if first_of_tag:
                self._lags_behind_newcomer(tag, t)
        if offset:
            sample = sample._replace(t_ms=t)
        self._sequence += 1
        heapq.heappush(self._heap, (t, TAG_CODES[tag], self._sequence, sample))
        if not self._warm:
            if self._holding():
                return
            self._warm = True
        self._release(out)

    def _lags_behind_newcomer(self, tag: str, t: int) -> None:
        """A tag showing up ahead of the others: they are this far behind it (the tags already
        there cannot show it by arriving late until their next sample)."""
        for other, last in self._last.items():
            if other != tag and 0 < t - last <= self.max_window_ms \
                    and t - last > self._lag_current.get(other, 0):
                self._lag_current[other] = t - last

    def _suspect(self, sample: Sample, t: int, out: list[Sample]) -> None:
        """Hold a sample whose own clock jumped (aligned time t on the segment's clocks);
        start the new segment with the held samples once the jump is confirmed: by another
        tag jumping to within gap_ms of it, by the tag's own samples on the new clock for more
        than gap_ms, or at once when no other tag is seen in the segment (or the hold is
        full)."""
        tag = sample.tag
        first = self._suspect_span.get(tag, (t, t))[0]
        self._suspect_span[tag] = (first, t)
        self._suspects.append(sample)
        confirmed = (
            any(other != tag and abs(t - latest) <= self.gap_ms
                for other, (_, latest) in self._suspect_span.items())
            or all(other == tag for other in self._last)
            or abs(t - first) > self.gap_ms
            or len(self._suspects) + len(self._heap) > self.max_pending)
        if not confirmed:
            return
        held, self._suspects, self._suspect_span = self._suspects, [], {}
        self._release_all(out)
        self._new_segment(keep_offsets=True)
        for suspect in held:
            self._place(suspect, out)

    def _refute(self, tag: str) -> None:
        """The tag's clock went on where it was: its held samples were bad time stamps."""
        kept = [s for s in self._suspects if s.tag != tag]
        self.stats.out_of_order += len(self._suspects) - len(kept)
        self._suspects = kept
        del self._suspect_span[tag]

    def _holding(self) -> bool:
        # Hold until two tags are there and no new tag has shown up for window_ms (a sensor
        # starting late keeps its first samples): at least startup_hold_ms, at most
        # 4 x startup_hold_ms; all four filter tags there: none can start late any more.
        since_start = self._newest - self._segment_start
        return (len(self._last) < len(FILTER_TAGS) and len(self._heap) <= self.max_pending
                and since_start < 4 * self.startup_hold_ms
                and (since_start < self.startup_hold_ms or len(self._last) < 2
                     or self._newest - self._last_new_tag_ms < self.window_ms))

    def _rotate_lags(self) -> None:
        bucket = self._newest // LAG_BUCKET_MS
        if self._lag_bucket is None or bucket != self._lag_bucket:
            consecutive = self._lag_bucket is not None and bucket == self._lag_bucket + 1
            self._lag_previous = self._lag_current if consecutive else {}
            self._lag_current = {}
            self._lag_bucket = bucket

    def _release(self, out: list[Sample]) -> None:
        heap = self._heap
        threshold = self._newest - self._window()
        watermark = None
        for last in self._last.values():
            if last >= threshold and (watermark is None or last < watermark):
                watermark = last
        released = 0
        while heap and heap[0][0] <= watermark:
            out.append(heapq.heappop(heap)[3])
            released += 1
        while len(heap) > self.max_pending:
            out.append(heapq.heappop(heap)[3])
            released += 1
            self.stats.forced += 1
        if released:
            self.last_released_ms = out[-1].t_ms
            self.stats.released += released

    def _release_all(self, out: list[Sample]) -> None:
        heap = self._heap
        if not heap:
            return
        self.stats.released += len(heap)
        while heap:
            out.append(heapq.heappop(heap)[3])
        self.last_released_ms = out[-1].t_ms
