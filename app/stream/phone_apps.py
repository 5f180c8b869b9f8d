"""What the phyphox and Sensor Logger sources share: samples become Sensor Fusion lines, a
bounded queue hands them to the engine, and the frame conversions both apps need.

Both apps' samples are turned into the Sensor Fusion app's lines (``<ms>\\tACC\\tx\\ty\\tz``,
see ../shared/PROTOCOL.md) before anything downstream sees them, so the parser, the orderer,
the recorder (raw.txt in the Sensor Fusion format), the forwarder, replay and the exports work
on them unchanged. Which conversion each app needs, and the source of each fact, is in
docs/phones.md.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Iterable
from typing import NamedTuple

import numpy as np

from ekf import quaternion as quat

from app.stream.events import Chunk, SourceEvent
from app.stream.protocol import TAG_CODES, Sample, format_line

#: The quaternion that turns a world frame with x north, y west, z up into East-North-Up:
#: a rotation by +90 degrees about z (north (1, 0, 0) -> (0, 1, 0)).
ENU_FROM_NWU = np.array([math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])
#: Standard gravity [m/s^2], the g Sensor Logger assumes (its UNITS.md).
STANDARD_GRAVITY = 9.80665
#: At most this many names are kept per counter of names (unknown sensors, ...).
MAX_NAMES = 32


class PhoneSample(NamedTuple):
    """One sample of a phone app on its way to a Sensor Fusion line: phone time in ms, the
    Sensor Fusion tag and its values (ORI: w, x, y, z)."""

    t_ms: int
    tag: str
    values: tuple[float, ...]


def _order_key(sample: PhoneSample) -> tuple[int, int]:
    return sample.t_ms, TAG_CODES.get(sample.tag, len(TAG_CODES))


def lines_of(samples: Iterable[PhoneSample]) -> bytes:
    """Sensor Fusion lines (each with its LF) for the samples, in time order (at equal times
    GYR, ACC, MAG, ORI, the order the filters are fed in); the sort is stable, so each tag's
    own samples keep their order."""
    ordered = sorted(samples, key=_order_key)
    return b"".join((format_line(Sample(s.t_ms, s.tag, s.values)) + "\n").encode("ascii")
                    for s in ordered)


def count_name(counts: dict[str, int], name: str) -> None:
    """counts[name] += 1, keeping at most MAX_NAMES names (the others are counted as "...")."""
    if name not in counts and len(counts) >= MAX_NAMES:
        name = "..."
    counts[name] = counts.get(name, 0) + 1


def finite(values: Iterable[object]) -> tuple[float, ...] | None:
    """The values as floats, or None when one is missing (JSON null), not a number or not
    finite (phyphox sends NaN and infinities as null)."""
    out = []
    for value in values:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return None
        number = float(value)
        if not math.isfinite(number):
            return None
        out.append(number)
    return tuple(out)


def up_in_device(q_wxyz: Iterable[float]) -> tuple[np.ndarray, np.ndarray]:
    """The world's up (z) in device coordinates for both readings of a quaternion: as the
    rotation device -> world (Q(q)^T e_z) and as world -> device (Q(q) e_z). Any world frame
    with z up (East-North-Up, North-West-Up) gives the same two vectors."""
    m = quat.to_matrix(quat.normalize(np.asarray(list(q_wxyz), float)))
    return m[2, :].copy(), m[:, 2].copy()


def gravity_sign(gravity: Iterable[float], q_wxyz: Iterable[float],
                 min_alignment: float = 0.8) -> int:
    """+1 when a gravity reading points up in the device frame, as the quaternion of the same
    moment says up is (Android's convention, and Sensor Logger's with "Standardise Units &
    Frames" on), -1 when it points down (iOS's own convention), 0 when the two do not line up
    well enough to tell (|cos| < min_alignment, e.g. a quaternion of another sample's time).
    Either reading of the quaternion is tried (device -> world or world -> device), so the
    answer does not depend on which one the app sends."""
    g = np.asarray(list(gravity), float)
    norm = float(np.linalg.norm(g))
    if not norm > 0.0:
        return 0
    best = max((float(np.dot(g, up)) / norm for up in up_in_device(q_wxyz)), key=abs)
    if abs(best) < min_alignment:
        return 0
    return 1 if best > 0 else -1


def enu_from_nwu(q_wxyz: Iterable[float]) -> tuple[float, float, float, float]:
    """A device -> (x north, y west, z up) quaternion as device -> East-North-Up."""
    q = quat.multiply(ENU_FROM_NWU, np.asarray(list(q_wxyz), float))
    return tuple(float(v) for v in q)   # type: ignore[return-value]


def nwu_from_enu(q_wxyz: Iterable[float]) -> tuple[float, float, float, float]:
    """The inverse of :func:`enu_from_nwu` (the Sensor Logger emulator's iOS frame)."""
    q = quat.multiply(quat.conjugate(ENU_FROM_NWU), np.asarray(list(q_wxyz), float))
    return tuple(float(v) for v in q)   # type: ignore[return-value]


class ItemQueue:
    """The items (Chunk | SourceEvent) a phone app's thread hands the engine: thread-safe,
    bounded in bytes. :meth:`room` says whether a producer may add more (the phyphox poller
    then leaves the data on the phone; the Sensor Logger endpoint makes the phone wait)."""

    def __init__(self, max_bytes: int = 16 << 20) -> None:
        self.max_bytes = int(max_bytes)
        self._cond = threading.Condition()
        self._items: collections.deque = collections.deque()
        self._bytes = 0

    def put(self, item: Chunk | SourceEvent) -> None:
        with self._cond:
            self._items.append(item)
            if isinstance(item, Chunk):
                self._bytes += len(item.data)
            self._cond.notify_all()

    def chunk(self, connection: int, data: bytes) -> None:
        """A Chunk of lines now (nothing for no lines)."""
        if data:
            self.put(Chunk(connection, data, time.perf_counter()))

    def event(self, kind: str, connection: int = 0, peer: str | None = None,
              detail: str = "") -> None:
        self.put(SourceEvent(kind, connection, peer, detail, time.perf_counter()))

    def room(self) -> bool:
        with self._cond:
            return self._bytes < self.max_bytes

    def wait_for_room(self, timeout: float) -> bool:
        """Wait up to `timeout` s for the consumer to take enough; whether there is room."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._bytes >= self.max_bytes:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return True

    def get(self, timeout: float = 0.05, max_items: int = 256) -> list[Chunk | SourceEvent]:
        """Wait up to `timeout` s for the first item, then drain without waiting."""
        items: list[Chunk | SourceEvent] = []
        with self._cond:
            if not self._items and timeout > 0:
                self._cond.wait(timeout)
            while self._items and len(items) < max_items:
                item = self._items.popleft()
                if isinstance(item, Chunk):
                    self._bytes -= len(item.data)
                items.append(item)
            if items:
                self._cond.notify_all()
        return items
