"""What every source hands the engine, and the one control a replay takes.

Plain frozen dataclasses with no dependencies, so the TCP server, the replay sources, the
engine and the tests all import them from here without a cycle.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Chunk:
    """Bytes received on connection number ``connection`` at host time ``t_host``
    (``time.perf_counter()``, s): raw protocol lines, not necessarily cut at line ends."""

    connection: int
    data: bytes
    t_host: float


@dataclass(frozen=True)
class SourceEvent:
    """Something that happened to a source.

    kind: "listening" | "connected" | "disconnected" | "finished" | "loop" | "seek" | "error" |
    "closed" (the TCP server closed a connection that was not the stream: not allowed, nothing
    valid, ignored, too many waiting; rate-limited, the counts are in the source's info()).
    peer: "ip:port" for connection events; detail: human-readable text.
    """

    kind: str
    connection: int = 0
    peer: str | None = None
    detail: str = ""
    t_host: float = 0.0


@dataclass(frozen=True)
class ReplayControl:
    """Replay only (other sources ignore it): any field left None is unchanged."""

    paused: bool | None = None
    speed: float | None = None    # 1 = original timing, 0 = as fast as possible
    loop: bool | None = None
    seek_s: float | None = None   # position from the start of the log, seconds
    step: int | None = None       # advance N lines while paused (the engine: N < 0 goes back)
    seek_line: int | None = None  # go to this line (the state after the lines before it)


@dataclass(frozen=True)
class AcceptConnection:
    """TCP only: the waiting connection from `peer` ("ip:port"; None: the one waiting longest)
    takes over the stream now; the current one is closed."""

    peer: str | None = None


@dataclass(frozen=True)
class IgnoreConnection:
    """TCP only: close the waiting connection from `peer` (None: every waiting one)."""

    peer: str | None = None


@dataclass(frozen=True)
class SetAllowedNetworks:
    """TCP only: only these addresses or networks ("192.168.1.42", "192.168.1.0/24") may
    connect; others are closed and counted (connections already there too). Empty: anyone."""

    networks: tuple[str, ...] = ()


CONNECTION_COMMANDS = (AcceptConnection, IgnoreConnection, SetAllowedNetworks)
