"""Logs and helpers for the phyphox and Sensor Logger tests: simulated phone logs (known,
deterministic), what a source handed over, parsed."""

from __future__ import annotations

from collections import defaultdict

from ekf.simulate import simulate

from app.stream.events import Chunk, SourceEvent
from app.stream.protocol import Sample, format_line, parse_line


def simulated_lines(duration_s: float = 4.0, seed: int = 3, **options) -> list[bytes]:
    """A simulated session as phone lines (ACC, GYR, MAG, ORI)."""
    session = simulate(duration_s=duration_s, seed=seed, **options)
    return [(format_line(Sample(t, tag, values)) + "\n").encode("ascii")
            for t, tag, values in session.iter_rows()]


class Collected:
    """What a source's read() handed over: the chunks' lines and the events."""

    def __init__(self) -> None:
        self.data: list[bytes] = []
        self.events: list[SourceEvent] = []
        self.connections: list[int] = []

    def take(self, items) -> None:
        for item in items:
            if isinstance(item, Chunk):
                self.data.append(item.data)
                self.connections.append(item.connection)
            else:
                self.events.append(item)

    def line_count(self) -> int:
        return sum(chunk.count(b"\n") for chunk in self.data)

    def samples(self) -> list[Sample]:
        return [parse_line(line.decode("ascii")) for line in b"".join(self.data).splitlines()]

    def kinds(self) -> list[str]:
        return [event.kind for event in self.events]

    def details(self, kind: str) -> list[str]:
        return [event.detail for event in self.events if event.kind == kind]


def by_tag(samples: list[Sample], offset_ms: int = 0) -> dict[str, list[tuple[int, tuple]]]:
    """tag -> [(time - offset, values)] in the order given."""
    out: dict[str, list[tuple[int, tuple]]] = defaultdict(list)
    for sample in samples:
        out[sample.tag].append((sample.t_ms - offset_ms, sample.values))
    return dict(out)


def log_samples(lines: list[bytes]) -> list[Sample]:
    return [parse_line(line.decode("ascii")) for line in lines]
