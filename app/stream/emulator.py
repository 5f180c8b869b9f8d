"""A phone emulator: connects to the server like the Sensor Fusion app and streams a log.

Lines go out verbatim, in file order, with the log's own timing (:func:`pacing_times`) scaled
by ``speed`` (0: as fast as possible). Used by `orientation-lab send`, tests and benchmarks.
"""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

from app.stream.lines import pacing_times, read_lines

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
        pace = pacing_times(lines)
        sent = 0
        while True:
            if speed <= 0:
                block: list[bytes] = []
                size = 0
                for line in lines:
                    block.append(line)
                    size += len(line)
                    if size >= _BLOCK_BYTES:
                        self.send(b"".join(block))
                        block, size = [], 0
                        if stop is not None and stop.is_set():
                            return sent
                if block:
                    self.send(b"".join(block))
                sent += len(lines)
            else:
                start_wall = time.perf_counter()
                index = 0
                while index < len(lines):
                    if stop is not None and stop.is_set():
                        return sent
                    now = (time.perf_counter() - start_wall) * speed
                    end = index
                    while end < len(lines) and pace[end] <= now:
                        end += 1
                    if end > index:
                        self.send(b"".join(lines[index:end]))
                        sent += end - index
                        index = end
                    else:
                        time.sleep(min(0.05, (pace[index] - now) / speed))
            if not loop or (stop is not None and stop.is_set()):
                self.lines_sent = sent
                return sent


def send_log(path: str | Path, host: str = "127.0.0.1", port: int = 3400, speed: float = 1.0,
             loop: bool = False, stop: threading.Event | None = None) -> int:
    """Connect like the phone and stream a log file; returns the number of lines sent."""
    lines = read_lines(path)
    with PhoneEmulator(host, port) as phone:
        return phone.stream_lines(lines, speed, loop, stop)
