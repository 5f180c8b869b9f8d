"""Put the filter tags' samples back in time order, on one clock, before a filter sees them.

Real phones write each sensor when its batch arrives, so lines are not in global time order
(each tag's own times increase); some tags sit on another clock (one phone's ACC runs exactly
131,072,000 ms ahead of its GYR and MAG). See ../shared/PROTOCOL.md, "Time".

:class:`TimeOrderer` handles only the filter tags (GYR, ACC, MAG, ORI); other tags pass
through untouched (RSSWIFI/GPS may carry epoch ms and never reach a filter's dt).

- Clock alignment, per segment: the first filter tag seen is the reference clock. A tag whose
  first sample is more than ``align_threshold_ms`` away from the reference's latest time gets
  a constant offset that aligns it (snapped to whole seconds when within window_ms / 2 of
  them), reported in ``stats.clock_quirks``. At the start of a segment releases wait at least
  ``startup_hold_ms``, until two tags are there and no new tag has shown up for ``window_ms``
  (at most 4 x startup_hold_ms), so a sensor starting a little late keeps its first samples.
- Reordering: a k-way merge with a watermark. A sample at aligned time t is released once
  every *active* tag has reached t (a tag lagging the newest time by more than ``window_ms``
  is inactive: it stopped or is late), or when more than ``max_pending`` samples wait.
  Released samples are sorted by (t, GYR < ACC < MAG < ORI).
- A sample older than the last released time, or a tag going back in its own time (by at
  most ``gap_ms``), is dropped and counted in ``stats.out_of_order``.
- A jump of a tag's own clock by more than ``gap_ms`` (forward: a pause; backward: a reboot or
  another phone) or a :meth:`restart` call (reconnect) starts a new segment: pending samples
  are released, alignment is learned again. Output times never go backwards: a segment that
  would start before the last released time is shifted to start ``restart_gap_ms`` after it,
  so a filter sees dt > 1 s, restarts its time base and keeps its orientation.

The output depends only on the sequence of samples pushed, never on wall time or chunking.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable
from dataclasses import dataclass, field

from app.io.protocol import FILTER_TAGS, TAG_PRIORITY, Sample

_MAX_QUIRKS = 20


@dataclass
class OrderStats:
    """Counters of a :class:`TimeOrderer`."""

    pushed: int = 0                 # filter-tag samples pushed
    released: int = 0
    out_of_order: int = 0           # dropped: older than released, or a tag going back in time
    forced: int = 0                 # released early because the buffer bound was reached
    restarts: int = 0               # segments started after the first
    restart_times_ms: list[int] = field(default_factory=list)   # aligned start of the last 100
    clock_quirks: list[str] = field(default_factory=list)
    offsets_ms: dict[str, int] = field(default_factory=dict)    # current tag -> aligned offset

    def copy(self) -> OrderStats:
        return OrderStats(self.pushed, self.released, self.out_of_order, self.forced,
                          self.restarts, list(self.restart_times_ms), list(self.clock_quirks),
                          dict(self.offsets_ms))


class TimeOrderer:
    """Streaming reorder + clock alignment of filter-tag samples (see the module docstring).

    push(sample) -> the samples released by it (aligned t_ms), flush() at end of stream.
    """

    def __init__(self, window_ms: int = 100, gap_ms: int = 2000,
                 align_threshold_ms: int = 10_000, max_pending: int = 20_000,
                 restart_gap_ms: int = 1500, startup_hold_ms: int = 250) -> None:
        self.window_ms = int(window_ms)
        self.gap_ms = int(gap_ms)
        self.align_threshold_ms = int(align_threshold_ms)
        self.max_pending = int(max_pending)
        self.restart_gap_ms = int(restart_gap_ms)
        self.startup_hold_ms = int(startup_hold_ms)
        self.stats = OrderStats()
        self._heap: list[tuple[int, int, int, Sample]] = []
        self._sequence = 0
        self.last_released_ms: int | None = None
        self._new_segment(first=True)

    # -- public ------------------------------------------------------------------------------

    def push(self, sample: Sample) -> list[Sample]:
        """Take one sample (any tag); return what it releases, in release order."""
        if sample.tag not in TAG_PRIORITY:
            return [sample]
        out: list[Sample] = []
        self._push(sample, out)
        return out

    def push_many(self, samples: Iterable[Sample]) -> list[Sample]:
        out: list[Sample] = []
        for sample in samples:
            if sample.tag in TAG_PRIORITY:
                self._push(sample, out)
            else:
                out.append(sample)
        return out

    def flush(self) -> list[Sample]:
        """Release everything pending (end of stream). The segment stays open."""
        out: list[Sample] = []
        self._release_all(out)
        return out

    def restart(self) -> list[Sample]:
        """Reconnect: release what is pending and learn the clocks again for what follows."""
        out = self.flush()
        self._new_segment(first=False)
        return out

    @property
    def pending(self) -> int:
        return len(self._heap)

    # -- internals -----------------------------------------------------------------------------

    def _new_segment(self, first: bool) -> None:
        self._offsets: dict[str, int] = {}
        self._last: dict[str, int] = {}          # tag -> latest aligned time in this segment
        self._reference: str | None = None
        self._segment_start: int | None = None
        self._warm = False           # hold releases for startup_hold_ms: lets every tag show up
        self._newest: int | None = None
        self._last_new_tag_ms = 0
        self.stats.offsets_ms = self._offsets
        if not first:
            self.stats.restarts += 1

    def _quirk(self, text: str) -> None:
        quirks = self.stats.clock_quirks
        if text not in quirks:
            quirks.append(text)
            del quirks[:-_MAX_QUIRKS]

    def _learn_offset(self, sample: Sample) -> int:
        raw = sample.t_ms
        if self._reference is None:
            self._reference = sample.tag
            shift = 0
            if self.last_released_ms is not None and raw <= self.last_released_ms:
                shift = self.last_released_ms + self.restart_gap_ms - raw
            if self.stats.restarts or self.last_released_ms is not None:
                times = self.stats.restart_times_ms
                times.append(raw + shift)
                del times[:-100]
            self._segment_start = raw + shift
            return shift
        reference_latest = self._last[self._reference]
        reference_offset = self._offsets[self._reference]
        if abs(raw + reference_offset - reference_latest) > self.align_threshold_ms:
            offset = reference_latest - raw
            # The estimate is off by the batching delay (~10 ms); the known quirk is a whole
            # number of seconds (131,072 s), so snap to one when this close to it.
            whole_seconds = round((offset - reference_offset) / 1000) * 1000 + reference_offset
            if abs(offset - whole_seconds) <= self.window_ms // 2:
                offset = whole_seconds
            difference = -(offset - reference_offset)
            self._quirk(f"{sample.tag} clock {difference:+d} ms vs {self._reference} (aligned)")
            return offset
        return reference_offset

    def _push(self, sample: Sample, out: list[Sample]) -> None:
        stats = self.stats
        stats.pushed += 1
        tag = sample.tag
        offset = self._offsets.get(tag)
        if offset is not None:
            t = sample.t_ms + offset
            last = self._last[tag]
            if t > last + self.gap_ms or t < last - self.gap_ms:
                # A pause, a reboot or another phone: a new time base, same orientation.
                self._release_all(out)
                self._new_segment(first=False)
                offset = None
            elif t < last:
                stats.out_of_order += 1
                return
        if offset is None:
            offset = self._learn_offset(sample)
            self._offsets[tag] = offset
            t = sample.t_ms + offset
            self._last_new_tag_ms = t
        if self.last_released_ms is not None and t < self.last_released_ms:
            stats.out_of_order += 1
            # The tag still moves on: later samples are compared with this one.
            self._last[tag] = t
            return
        self._last[tag] = t
        if self._newest is None or t > self._newest:
            self._newest = t
        if offset:
            sample = sample._replace(t_ms=t)
        self._sequence += 1
        heapq.heappush(self._heap, (t, TAG_PRIORITY[tag], self._sequence, sample))
        if not self._warm:
            # Hold until two tags are there and no new tag has shown up for window_ms (a sensor
            # starting late keeps its first samples): at least startup_hold_ms, at most
            # 4 x startup_hold_ms.
            since_start = self._newest - self._segment_start
            if len(self._heap) <= self.max_pending and since_start < 4 * self.startup_hold_ms \
                    and (since_start < self.startup_hold_ms or len(self._last) < 2
                         or self._newest - self._last_new_tag_ms < self.window_ms):
                return
            self._warm = True
        self._release(out)

    def _release(self, out: list[Sample]) -> None:
        heap = self._heap
        threshold = self._newest - self.window_ms
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


__all__ = ["TimeOrderer", "OrderStats", "FILTER_TAGS"]
