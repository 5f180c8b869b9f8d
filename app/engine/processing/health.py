"""Stream health for the snapshots: rates per tag, lines per second, counts, warnings.

:class:`HealthTracker` follows the parsed samples (each tag's own times, for its rate over the
last RATE_WINDOW_MS of phone time) and builds the :class:`~app.engine.snapshot.StreamHealth`
the window and `serve` show, from the pipeline's parser and orderer statistics.
"""

from __future__ import annotations

import math
import time
from collections import deque
from typing import Any

import numpy as np

from app.engine.snapshot import StreamHealth
from app.stream.fastparse import ParsedArrays
from app.stream.protocol import FILTER_TAGS

RATE_WINDOW_MS = 2000          # per-tag rates are measured over this much phone time
WARNING_INTERVAL_S = 5.0       # one warning of a kind per this many seconds


def _jumped(times: deque[int], t_ms: int) -> bool:
    """Whether a tag's next time does not continue its times (a seek, a reconnect, a pause):
    back in time, or later than ten of its intervals and 250 ms. Its rate then starts anew."""
    if not times:
        return False
    gap = t_ms - times[-1]
    interval = (times[-1] - times[0]) / (len(times) - 1) if len(times) > 1 else 0.0
    return gap < 0 or gap > max(250.0, 10.0 * interval)


class HealthTracker:
    """Rates, line rate and rate-limited warnings."""

    def __init__(self) -> None:
        self.warnings: deque[str] = deque(maxlen=5)
        self._warned_at: dict[str, float] = {}
        self._tag_times: dict[str, deque[int]] = {}
        self._line_rate_marks: deque[tuple[float, int]] = deque()

    def warn(self, kind: str, message: str, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._warned_at.get(kind, -math.inf) < WARNING_INTERVAL_S:
            return
        self._warned_at[kind] = now
        self.warnings.append(message)

    def track(self, parsed: ParsedArrays) -> None:
        """Remember each tag's own (unaligned) times, in line order, for :meth:`rates`."""
        times = self._tag_times
        if parsed.other:
            # Rare tags: keep the line order among all tags (deque creation order = first seen).
            samples = parsed.to_samples()
        elif len(parsed.t_ms):
            codes = parsed.tag
            present = sorted(set(codes.tolist()), key=lambda c: int(np.argmax(codes == c)))
            for code in present:
                tag = FILTER_TAGS[code]
                queue_ = times.get(tag)
                if queue_ is None:
                    queue_ = times[tag] = deque()
                new = parsed.t_ms[codes == code]
                if _jumped(queue_, int(new[0])):
                    queue_.clear()
                queue_.extend(new.tolist())
            return
        else:
            return
        for sample in samples:
            queue_ = times.get(sample.tag)
            if queue_ is None:
                queue_ = times[sample.tag] = deque()
            if _jumped(queue_, sample.t_ms):
                queue_.clear()
            queue_.append(sample.t_ms)

    def rates(self) -> dict[str, float]:
        rates = {}
        for tag, times in self._tag_times.items():
            if not times:
                continue
            newest = times[-1]
            while times and (times[0] < newest - RATE_WINDOW_MS or times[0] > newest):
                times.popleft()
            if len(times) >= 2 and times[-1] > times[0]:
                rates[tag] = round((len(times) - 1) * 1000.0 / (times[-1] - times[0]), 1)
        return rates

    def lines_per_s(self, now: float, lines: int) -> float:
        marks = self._line_rate_marks
        marks.append((now, lines))
        while len(marks) > 2 and now - marks[1][0] >= 1.0:
            marks.popleft()
        first_time, first_lines = marks[0]
        if now - first_time <= 0:
            return 0.0
        return (lines - first_lines) / (now - first_time)

    def health(self, now: float, info: dict[str, Any], parser: Any, orderer: Any,
               order_retired: int, state: str, peer: str | None,
               recording: str | None) -> StreamHealth:
        parse = parser.stats
        reasons = dict(parse.damaged_reasons)
        order = orderer.stats
        return StreamHealth(
            connection_state=state, peer=info.get("peer") or peer,
            listen_addresses=list(info.get("listen_addresses") or []), port=info.get("port"),
            rates_hz=self.rates(), lines_per_s=round(self.lines_per_s(now, parse.lines), 1),
            lines_total=parse.lines, damaged=parse.damaged, unknown=parse.unknown,
            too_long=parse.too_long, out_of_order=order.out_of_order + order_retired,
            clock_quirks=list(order.clock_quirks), warnings=list(self.warnings),
            damaged_reasons=reasons, sessions=order.sessions,
            reorder_window_ms=order.window_ms, lags_ms=dict(order.lags_ms),
            waiting_peers=list(info.get("waiting_peers") or []),
            connections_closed=dict(info.get("connections_closed") or {}),
            allowed=list(info.get("allowed") or []), recording=recording,
            connect_to=list(info.get("connect_to") or []),
            connect_hint=str(info.get("connect_hint") or ""))


def stats_dict(health: StreamHealth) -> dict[str, Any]:
    """Stream statistics for session.json."""
    return {"lines": health.lines_total, "damaged": health.damaged,
            "damaged_reasons": dict(health.damaged_reasons),
            "unknown": health.unknown, "too_long": health.too_long,
            "out_of_order": health.out_of_order, "clock_quirks": list(health.clock_quirks),
            "sessions": health.sessions, "rates_hz": dict(health.rates_hz),
            "connections_closed": dict(health.connections_closed)}
