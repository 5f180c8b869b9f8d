"""Where samples come from: the phone over TCP, a log file replayed, or the simulator.

Every source has the same small interface (:class:`Source`): ``start()``, ``stop()``,
``read(timeout)`` -> a list of :class:`~app.stream.events.Chunk` (raw bytes of protocol lines)
and :class:`~app.stream.events.SourceEvent` items, ``control(ReplayControl)`` and ``info()``.
Replays hand over the file's lines verbatim, so everything downstream (parser, time ordering,
estimators, recorder) is identical whichever source feeds it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ekf.simulate import simulate

from app.stream.demo import DEMO_SESSION_PATH as DEMO_SESSION
from app.stream.events import CONNECTION_COMMANDS, Chunk, SourceEvent
from app.stream.lines import LogError, line_starts, pacing_array, read_log_bytes
from app.stream.protocol import DEFAULT_LIMITS, Limits, Sample, format_line
from app.stream.tcp_server import DEFAULT_PORT, TcpServer, lan_ipv4_addresses

_MAX_LINES_PER_CHUNK = 4096
# Paced replay hands out what is due at most this often [s]: a 500 Hz log at 10x would otherwise
# wake the engine for every few lines, and the per-chunk Python work would crowd out the GUI.
# Well under one display frame, so the window still sees every frame's samples in time.
REPLAY_MIN_INTERVAL_S = 0.01


@dataclass(frozen=True)
class Capabilities:
    """What a source can do; the engine asks these, never the source's kind.

    pause: be paused and stepped (ReplayControl paused / step); seek: be sought (seek_s, a
    checkpoint's jump); pace: play at a speed, loop; reconnect: a live phone that connects,
    goes away and comes back (its connection state and peer come from its events); forward:
    its lines are a live phone's stream, which ``--forward`` hands on."""

    pause: bool = False
    seek: bool = False
    pace: bool = False
    reconnect: bool = False
    forward: bool = False


LIVE_PHONE = Capabilities(reconnect=True, forward=True)
REPLAY = Capabilities(pause=True, seek=True, pace=True)


class Source:
    """Interface of every sample source. ``kind`` names it for people (session.json's
    "source", logs): "tcp" | "phyphox" | "sensor-logger" | "replay" | "simulator";
    :attr:`capabilities` says what it can do."""

    kind = "source"
    capabilities = Capabilities()

    def start(self) -> None:
        """Begin producing (bind the port, open the file...). May raise OSError/LogError."""

    def stop(self) -> None:
        """Release everything. Idempotent."""

    def ready(self) -> None:
        """The consumer is ready for samples now (its kernels are loaded): a paced replay
        starts its clock here. Nothing for a live source."""

    def read(self, timeout: float = 0.05) -> list[Chunk | SourceEvent]:
        """What arrived since the previous call; waits at most `timeout` s when nothing has."""
        raise NotImplementedError

    def control(self, command: Any) -> None:
        """Apply a ReplayControl (replays) or a connection command (TCP); others ignore it."""

    def connect_hint(self) -> str:
        """One line for the user: how the phone reaches this source ("" when it plays a
        file)."""
        return ""

    def played(self) -> LineReplaySource | None:
        """The replay this source plays now (its lines, seeks and file), None while a live
        phone streams."""
        return None

    def info(self) -> dict[str, Any]:
        """Health fields: connection_state, peer, port, listen_addresses, replay (dict or None);
        TCP also waiting_peers, connections_closed, allowed."""
        return {"connection_state": "waiting", "peer": None, "port": None,
                "listen_addresses": [], "replay": None}


class TcpSource(Source):
    """The phone over TCP (see :class:`~app.stream.tcp_server.TcpServer` for the connection
    policy: one stream, newcomers wait, `allow`, junk closed)."""

    kind = "tcp"
    capabilities = LIVE_PHONE

    def __init__(self, host: str = "0.0.0.0", port: int = DEFAULT_PORT,
                 max_queued: int = 256, allow=(), takeover_after_s: float = 3.0,
                 limits: Limits = DEFAULT_LIMITS, **server_options: Any) -> None:
        self.server = TcpServer(host, port, max_queued=max_queued, allow=allow,
                                takeover_after_s=takeover_after_s, limits=limits,
                                **server_options)
        self._addresses: list[str] = []

    def start(self) -> None:
        """Bind and listen (OSError when the port is taken); again: nothing more."""
        self.server.start()
        if self.server.host in ("0.0.0.0", ""):
            self._addresses = lan_ipv4_addresses()
        else:
            self._addresses = [self.server.host]

    def stop(self) -> None:
        self.server.stop()

    @property
    def port(self) -> int | None:
        return self.server.port

    def read(self, timeout: float = 0.05) -> list[Chunk | SourceEvent]:
        return self.server.get(timeout)

    def control(self, command: Any) -> None:
        if isinstance(command, CONNECTION_COMMANDS):
            self.server.control(command)

    def connect_hint(self) -> str:
        addresses = ", ".join(self._addresses or [self.server.host])
        return (f"listening on port {self.port}; type one of these into the phone app: "
                f"{addresses}")

    def info(self) -> dict[str, Any]:
        state = self.server.state
        return {"connection_state": "waiting" if state == "stopped" else state,
                "peer": self.server.peer, "port": self.server.port,
                "listen_addresses": list(self._addresses), "replay": None,
                "connect_to": [f"{address}:{self.server.port}" for address in self._addresses],
                "connect_hint": self.connect_hint(), **self.server.info()}


class LineReplaySource(Source):
    """Replays protocol lines with their original timing, scaled by ``speed`` (0: as fast as
    possible), optionally looping; pause, step, seek and speed changes via :meth:`control`.

    The lines live in one bytes buffer with their offsets (an hour at 100 Hz is 1.3 million
    lines: a list of that many bytes objects would cost more than the text itself), each with
    the time it is due (:func:`~app.stream.lines.pacing_array`).

    Events: "connected" at start, "loop" when wrapping around, "seek" before lines that start
    again from the beginning after :meth:`seek` (the consumer resets its filter: the lines up to
    the seek target then come unpaced so the filter is re-synced), "finished" at the end.
    :meth:`jump` is the engine's seek: it restored its state at line `start` itself (a
    checkpoint) and gets the lines from there, unpaced up to the target.
    """

    kind = "replay"
    capabilities = REPLAY

    def __init__(self, lines: list[bytes] | bytes, name: str, speed: float = 1.0,
                 loop: bool = False, paused: bool = False) -> None:
        self.name = name
        if not isinstance(lines, bytes):
            lines = b"".join(line if line.endswith(b"\n") else line + b"\n" for line in lines)
        elif lines and not lines.endswith(b"\n"):
            lines = lines + b"\n"
        self.data = lines
        self.starts = line_starts(lines)
        self.pace = pacing_array(lines, self.starts)
        self.speed = max(0.0, float(speed))
        self.loop = bool(loop)
        self.paused = bool(paused)
        self._index = 0
        self._fast_until = 0          # lines before this index go out unpaced (seek re-sync)
        self._steps = 0
        self._events: list[SourceEvent] = []
        self._connection = 1
        self._anchor_wall = 0.0
        self._anchor_pace = 0.0
        self._last_chunk_wall = -math.inf
        self._started = False
        self._finished = False
        self.loops = 0

    @property
    def line_count(self) -> int:
        return len(self.pace)

    @property
    def line_index(self) -> int:
        """The next line to go out (the target while re-syncing after a seek)."""
        return max(self._index, self._fast_until)

    @property
    def lines_out(self) -> int:
        """The lines gone out so far (a seek's re-sync lines included)."""
        return self._index

    def played(self) -> LineReplaySource:
        return self

    def line(self, index: int) -> bytes:
        return self.data[self.starts[index]:self.starts[index + 1]]

    def lines_between(self, first: int, last: int) -> bytes:
        """Lines first..last-1 as one bytes object."""
        return self.data[self.starts[first]:self.starts[last]]

    @property
    def duration_s(self) -> float:
        return float(self.pace[-1]) if len(self.pace) else 0.0

    @property
    def position_s(self) -> float:
        index = self.line_index
        return float(self.pace[index]) if index < len(self.pace) else self.duration_s

    def line_at(self, position_s: float) -> int:
        """The first line due at or after `position_s` (the line count past the end)."""
        return int(np.searchsorted(self.pace, position_s, side="left"))

    def start(self) -> None:
        self._started = True
        self._anchor()
        self._events.append(SourceEvent("connected", self._connection, self.name,
                                        "replay", time.perf_counter()))

    def ready(self) -> None:
        self._anchor()

    def _anchor(self) -> None:
        self._anchor_wall = time.perf_counter()
        self._anchor_pace = self.position_s

    def control(self, command: Any) -> None:
        if getattr(command, "speed", None) is not None:
            self.speed = max(0.0, float(command.speed))
            self._anchor()
        if getattr(command, "loop", None) is not None:
            self.loop = bool(command.loop)
        if getattr(command, "paused", None) is not None:
            self.paused = bool(command.paused)
            self._anchor()
        if getattr(command, "step", None):
            self._steps += max(0, int(command.step))
        if getattr(command, "seek_s", None) is not None:
            self.seek(float(command.seek_s))

    def seek(self, position_s: float) -> None:
        """Go to `position_s` from the start; the consumer re-runs the filter from the start."""
        self._connection += 1
        self._events.append(SourceEvent("seek", self._connection, self.name,
                                        f"{position_s:.3f} s", time.perf_counter()))
        self.jump(0, self.line_at(position_s), clear_events=False)

    def jump(self, start: int, target: int, clear_events: bool = True) -> None:
        """Go on from line `start` (the consumer's state is that after lines 0..start-1),
        unpaced up to line `target`, then with the original timing from there."""
        line_count = len(self.pace)
        target = max(0, min(int(target), line_count))
        start = max(0, min(int(start), target))
        if clear_events:
            self._events = [e for e in self._events if e.kind == "connected"]
        self._index = start
        self._fast_until = target
        self._steps = 0
        self._finished = False
        self._anchor_pace = float(self.pace[target]) if target < line_count else self.duration_s
        self._anchor_wall = time.perf_counter()

    def read(self, timeout: float = 0.05) -> list[Chunk | SourceEvent]:
        out: list[Chunk | SourceEvent] = self._events
        self._events = []
        if not self._started or self._finished:
            if not out:
                time.sleep(timeout)
            return out
        pace = self.pace
        count = len(pace)
        start = self._index
        end = start
        limit = min(count, start + _MAX_LINES_PER_CHUNK)
        if end < self._fast_until:
            end = min(self._fast_until, limit)
        elif self.paused:
            if self._steps:
                end = min(limit, start + self._steps)
                self._steps -= end - start
        elif self.speed == 0.0:
            end = limit
        else:
            since = time.perf_counter() - self._last_chunk_wall
            if since < REPLAY_MIN_INTERVAL_S and not out:
                time.sleep(min(timeout, REPLAY_MIN_INTERVAL_S - since))
            now_pace = self._anchor_pace + (time.perf_counter() - self._anchor_wall) * self.speed
            end = max(start, min(limit, int(np.searchsorted(pace, now_pace, side="right"))))
            if end == start and end < count and not out:
                wait = (pace[end] - now_pace) / self.speed
                time.sleep(max(0.0, min(timeout, wait)))
                return out
        if end > start:
            self._last_chunk_wall = time.perf_counter()
            out.append(Chunk(self._connection, self.lines_between(start, end),
                             self._last_chunk_wall))
            self._index = end
        elif self.paused and not out:
            time.sleep(timeout)
        if self._index >= count:
            self._at_end(out)
        return out

    def _at_end(self, out: list[Chunk | SourceEvent]) -> None:
        if self.loop and len(self.pace):
            self.loops += 1
            self._connection += 1
            self._index = 0
            self._fast_until = 0          # a seek's re-sync target is behind us
            out.append(SourceEvent("loop", self._connection, self.name, "",
                                   time.perf_counter()))
            self._anchor()
        else:
            self._finished = True
            out.append(SourceEvent("finished", self._connection, self.name, "",
                                   time.perf_counter()))

    def info(self) -> dict[str, Any]:
        state = "finished" if self._finished else "replaying"
        return {"connection_state": state, "peer": self.name, "port": None,
                "listen_addresses": [],
                "replay": {"position_s": self.position_s, "duration_s": self.duration_s,
                           "speed": self.speed, "paused": self.paused, "loop": self.loop,
                           "finished": self._finished, "name": self.name,
                           "line": self.line_index, "lines": len(self.pace)}}


class LogFileSource(LineReplaySource):
    """A log file (.txt or .txt.gz; the phone's or our raw.txt) replayed like a phone.

    A recording's raw.txt (a session.json beside it) always ends with a whole line; one that
    does not was cut by a crash: its torn last line is left out (it could parse to a wrong
    value) and counted (:attr:`torn_lines`)."""

    def __init__(self, path: str | Path, speed: float = 1.0, loop: bool = False,
                 paused: bool = False) -> None:
        path = Path(path)
        data = read_log_bytes(path, add_newline=False)
        self.torn_lines = 0
        if not data.endswith(b"\n"):
            if path.with_name("session.json").is_file():
                data = data[:data.rfind(b"\n") + 1]
                self.torn_lines = 1
                if not data:
                    raise LogError(f"{path}: no whole line (a recording cut at its start)")
            else:
                data += b"\n"
        # a recording is named by its folder (its raw.txt says nothing)
        name = path.parent.name if self.torn_lines or path.with_name("session.json").is_file() \
            and path.name == "raw.txt" else path.name
        super().__init__(data, name, speed, loop, paused)
        self.path = path


class SimulatorSource(LineReplaySource):
    """A simulated session (ekf.simulate) streamed as phone lines."""

    kind = "simulator"

    def __init__(self, duration_s: float = 120.0, rates_hz: dict[str, float] | None = None,
                 seed: int = 0, speed: float = 1.0, loop: bool = True, **simulate_options) -> None:
        session = simulate(duration_s=duration_s, rates_hz=rates_hz, seed=seed,
                           **simulate_options)
        lines = [(format_line(Sample(t, tag, values)) + "\n").encode("ascii")
                 for t, tag, values in session.iter_rows()]
        super().__init__(lines, f"simulator (seed {seed})", speed, loop)
        self.session = session


def demo_source(speed: float = 1.0) -> LogFileSource:
    """The bundled demo session (app/resources/demo_session.txt.gz), looping at real speed."""
    if not DEMO_SESSION.exists():
        raise LogError(f"{DEMO_SESSION}: demo session missing")
    return LogFileSource(DEMO_SESSION, speed=speed, loop=True)


class DemoOrPhoneSource(Source):
    """The demo session, played while the TCP server listens; the phone takes over as soon as it
    connects (the demo stops), so `--demo` still shows where to point the phone."""

    def __init__(self, demo: Source, phone: TcpSource) -> None:
        self.demo = demo
        self.phone = phone
        self.phone_active = False

    @property
    def kind(self) -> str:  # type: ignore[override]
        return self.phone.kind if self.phone_active else self.demo.kind

    @property
    def capabilities(self) -> Capabilities:  # type: ignore[override]
        return self.phone.capabilities if self.phone_active else self.demo.capabilities

    def start(self) -> None:
        self.phone.start()
        self.demo.start()

    def ready(self) -> None:
        self.demo.ready()

    def stop(self) -> None:
        self.demo.stop()
        self.phone.stop()

    def read(self, timeout: float = 0.05) -> list[Chunk | SourceEvent]:
        if self.phone_active:
            return self.phone.read(timeout)
        incoming = self.phone.read(0.0)
        if any(isinstance(x, Chunk) or x.kind == "connected" for x in incoming):
            # The phone's "connected" event makes the engine restart its time base.
            self.phone_active = True
            self.demo.stop()
            return incoming
        return incoming + self.demo.read(timeout)

    def control(self, command: Any) -> None:
        if isinstance(command, CONNECTION_COMMANDS):
            self.phone.control(command)
        elif not self.phone_active:
            self.demo.control(command)

    def connect_hint(self) -> str:
        return self.phone.connect_hint()

    def played(self) -> LineReplaySource | None:
        return None if self.phone_active else self.demo.played()

    def info(self) -> dict[str, Any]:
        if self.phone_active:
            return self.phone.info()
        info = dict(self.demo.info())
        phone = self.phone.info()
        for key in ("port", "listen_addresses", "waiting_peers", "connections_closed",
                    "allowed", "connect_to", "connect_hint"):
            info[key] = phone.get(key)
        return info
