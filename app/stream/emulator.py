"""A phone emulator: connects to the server like the Sensor Fusion app and streams a log.

Lines go out verbatim, in file order, with the log's own timing
(:func:`~app.stream.lines.pacing_times`) scaled by ``speed`` (0: as fast as possible); a file is
read and sent block by block, so memory does not grow with its size. Used by `orientation-lab
send`, tests and benchmarks.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from app.stream.lines import Pacer, line_blocks, line_starts

_BLOCK_BYTES = 1 << 18


class PhoneEmulator:
    """A TCP client that behaves like the phone: connect, send lines, close. Context manager."""

    def __init__(self, host: str = "127.0.0.1", port: int = 3400, timeout: float = 5.0) -> None:
        self.host = host
        self.port = port
        self.timeout = timeout
        self.sock: socket.socket | None = None
        self.bytes_sent = 0
        self.lines_sent = 0

    def connect(self) -> PhoneEmulator:
        self.sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return self

    def send(self, data: bytes) -> None:
        if self.sock is None:
            raise OSError("not connected")
        self.sock.sendall(data)
        self.bytes_sent += len(data)

    def close(self) -> None:
        if self.sock is not None:
            try:
                self.sock.shutdown(socket.SHUT_WR)
            except OSError:
                pass
            self.sock.close()
            self.sock = None

    def __enter__(self) -> PhoneEmulator:
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.close()

    def stream_lines(self, lines: list[bytes], speed: float = 1.0, loop: bool = False,
                     stop: threading.Event | None = None) -> int:
        """Send `lines` (each with its LF) with their original timing / speed (0: at once).
        Returns the number of lines sent; ends early when `stop` is set."""
        data = b"".join(lines)
        return self.stream_blocks(lambda: [data], speed, loop, stop)

    def stream_blocks(self, blocks: Callable[[], Iterable[bytes]], speed: float = 1.0,
                      loop: bool = False, stop: threading.Event | None = None) -> int:
        """Send the lines of ``blocks()`` (blocks of whole lines, :func:`~app.stream.lines.
        line_blocks`; called again for each pass of a loop) with their original timing / speed
        (0: at once), holding one block at a time. Returns the number of lines sent; ends early
        when `stop` is set."""
        sent = 0
        while True:
            pacer = Pacer()
            start_wall = time.perf_counter()
            for block in blocks():
                if speed <= 0 or not block.endswith(b"\n"):
                    for first in range(0, len(block), _BLOCK_BYTES):
                        piece = block[first:first + _BLOCK_BYTES]
                        self.send(piece)
                        sent += piece.count(b"\n")
                        if stop is not None and stop.is_set():
                            return self._sent(sent)
                    continue
                starts = line_starts(block)
                pace = pacer.times(block, starts)
                index = 0
                while index < len(pace):
                    if stop is not None and stop.is_set():
                        return self._sent(sent)
                    now = (time.perf_counter() - start_wall) * speed
                    end = int(np.searchsorted(pace, now, side="right"))
                    if end > index:
                        self.send(block[starts[index]:starts[end]])
                        sent += end - index
                        index = end
                    else:
                        time.sleep(min(0.05, (pace[index] - now) / speed))
            if not loop or (stop is not None and stop.is_set()):
                return self._sent(sent)

    def _sent(self, count: int) -> int:
        self.lines_sent = count
        return count


def send_log(path: str | Path, host: str = "127.0.0.1", port: int = 3400, speed: float = 1.0,
             loop: bool = False, stop: threading.Event | None = None) -> int:
    """Connect like the phone and stream a log file (read block by block, never whole);
    returns the number of lines sent."""
    with PhoneEmulator(host, port) as phone:
        return phone.stream_blocks(lambda: line_blocks(path), speed, loop, stop)
