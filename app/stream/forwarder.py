"""Forward the phone's lines, verbatim and in order, to another TCP server (`--forward HOST:PORT`).

The course's MATLAB kit (``StreamSensorDataReader``) is a server the phone connects to; with
the forwarder, Orientation Lab receives the phone and hands every line on to the kit, so a
student can run ``filterTemplate`` in MATLAB while this app records and shows the same stream.

The phone link never waits for the receiver: :meth:`LineForwarder.feed` only appends to a
bounded queue (whole lines; a line cut by a disconnect is never sent), and a background thread
(plain ``threading``, no Qt) sends it. A slow receiver fills the queue and the lines that do
not fit are dropped and counted; while there is no receiver the lines are dropped and counted
too (a receiver that connects late gets the stream from then on, not a stale backlog). The
thread reconnects by itself, every ``reconnect_s`` on its clock (``time.monotonic`` unless a
test gives another).
"""

from __future__ import annotations

import select
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

DEFAULT_MAX_QUEUED_BYTES = 4 << 20
SEND_TIMEOUT_S = 5.0
CLOCK_POLL_S = 0.05     # waiting to reconnect, the thread reads its clock this often


@dataclass
class ForwardStatus:
    """What the forwarder did. state: "connecting" | "connected" | "reconnecting" | "stopped".
    lines_queued: waiting or being sent; lines_dropped counts lines never sent:
    dropped_no_receiver while nothing was connected, dropped_full when the receiver was too
    slow for the queue (or its connection broke with them queued or in flight). Every line fed
    is in exactly one of lines_forwarded, lines_queued, lines_dropped."""

    target: str
    state: str = "connecting"
    lines_forwarded: int = 0
    bytes_forwarded: int = 0
    lines_queued: int = 0
    dropped_no_receiver: int = 0
    dropped_full: int = 0
    connections: int = 0
    last_error: str = ""

    @property
    def lines_dropped(self) -> int:
        return self.dropped_no_receiver + self.dropped_full

    def summary(self) -> str:
        """One line for `serve` and the window, e.g. "forward 127.0.0.1:3401 connected,
        1200 lines sent, 3 dropped"."""
        dropped = f", {self.lines_dropped} dropped" if self.lines_dropped else ""
        return (f"forward {self.target} {self.state}, {self.lines_forwarded} lines sent"
                f"{dropped}")


class LineForwarder:
    """Send every line fed to it to host:port, in order, from a background thread.

    ``feed(data, connection)`` takes received bytes (not necessarily cut at line ends) of
    connection number ``connection``; only complete lines are queued. ``max_queued_bytes``
    bounds the queue. clock: the monotonic seconds the reconnection delays count in;
    :attr:`next_attempt` is the clock time of the next connection attempt (None: now).
    """

    def __init__(self, host: str, port: int, max_queued_bytes: int = DEFAULT_MAX_QUEUED_BYTES,
                 reconnect_s: float = 1.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.host = host
        self.port = int(port)
        self.max_queued_bytes = int(max_queued_bytes)
        self.reconnect_s = float(reconnect_s)
        self._clock = clock
        self.next_attempt: float | None = None
        self._status = ForwardStatus(f"{host}:{port}")
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._queue: deque[tuple[bytes, int]] = deque()   # (block of whole lines, line count)
        self._queued_bytes = 0
        self._partial = b""
        self._partial_connection: int | None = None
        self._connected = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- lifecycle ------------------------------------------------------------------------------

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="forwarder", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread and close the connection. Idempotent."""
        self._stop.set()
        with self._wake:
            self._wake.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        with self._lock:
            self._status.state = "stopped"

    def __enter__(self) -> LineForwarder:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- the receiving side (the engine thread) ---------------------------------------------------

    def feed(self, data: bytes, connection: int = 0) -> None:
        """Queue the complete lines in `data` (the rest waits for the next call of the same
        connection; a new connection drops a cut line). Never blocks on the network."""
        with self._lock:
            if connection != self._partial_connection:
                self._partial = b""
                self._partial_connection = connection
            if self._partial:
                data = self._partial + data
            end = data.rfind(b"\n") + 1
            self._partial = data[end:]
            if end == 0:
                return
            block = data[:end] if end < len(data) else data
            lines = block.count(b"\n")
            status = self._status
            if not self._connected:
                status.dropped_no_receiver += lines
            elif self._queued_bytes + len(block) > self.max_queued_bytes:
                status.dropped_full += lines
            else:
                self._queue.append((block, lines))
                self._queued_bytes += len(block)
                status.lines_queued += lines
                self._wake.notify()

    def status(self) -> ForwardStatus:
        """A copy of the counters and state."""
        with self._lock:
            s = self._status
            return ForwardStatus(s.target, s.state, s.lines_forwarded, s.bytes_forwarded,
                                 s.lines_queued, s.dropped_no_receiver, s.dropped_full,
                                 s.connections, s.last_error)

    # -- the sending thread ---------------------------------------------------------------------

    def _connect(self) -> socket.socket | None:
        try:
            sock = socket.create_connection((self.host, self.port), timeout=2.0)
        except OSError as error:
            with self._lock:
                self._status.last_error = str(error.strerror or error)
            return None
        sock.settimeout(SEND_TIMEOUT_S)
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError:
            pass
        with self._lock:
            self._connected = True
            self._status.state = "connected"
            self._status.connections += 1
            self._status.last_error = ""
        return sock

    def _disconnect(self, sock: socket.socket, reason: str, lost: int = 0) -> None:
        try:
            sock.close()
        except OSError:
            pass
        with self._lock:
            self._connected = False
            self._status.state = "stopped" if self._stop.is_set() else "reconnecting"
            self._status.last_error = reason
            # what was queued for this connection is not sent to the next one (stale by then);
            # `lost` were in flight (still counted as queued)
            self._status.dropped_full += lost + sum(lines for _, lines in self._queue)
            self._status.lines_queued = 0
            self._queue.clear()
            self._queued_bytes = 0

    def _take(self, timeout: float) -> tuple[bytes, int] | None:
        with self._wake:
            if not self._queue and not self._stop.is_set():
                self._wake.wait(timeout)
            if not self._queue:
                return None
            pieces = []
            lines = 0
            while self._queue and sum(len(p) for p in pieces) < (1 << 16):
                block, count = self._queue.popleft()
                pieces.append(block)
                lines += count
            data = b"".join(pieces)
            self._queued_bytes -= len(data)      # lines_queued keeps them until sent or lost
            return data, lines

    @staticmethod
    def _closed_by_peer(sock: socket.socket) -> bool:
        """The receiver sends nothing; a readable socket means it closed (or sent junk, which
        is read and ignored)."""
        try:
            readable, _, _ = select.select([sock], [], [], 0)
            if not readable:
                return False
            return sock.recv(4096) == b""
        except (OSError, ValueError):
            return True

    def _serve(self, sock: socket.socket) -> None:
        """Send queued lines until the connection breaks or the forwarder stops."""
        while not self._stop.is_set():
            if self._closed_by_peer(sock):
                self._disconnect(sock, "closed by the receiver")
                return
            item = self._take(0.2)
            if item is None:
                continue
            data, lines = item
            try:
                sock.sendall(data)
            except OSError as error:
                self._disconnect(sock, f"send failed: {error.strerror or error}", lost=lines)
                return
            with self._lock:
                self._status.lines_forwarded += lines
                self._status.lines_queued -= lines
                self._status.bytes_forwarded += len(data)
        self._disconnect(sock, "stopped")

    def _attempt_due(self) -> bool:
        """True when a connection attempt is due; otherwise wait a little (at most
        CLOCK_POLL_S, less when stopped) and say False."""
        due = self.next_attempt
        wait = 0.0 if due is None else due - self._clock()
        if wait <= 0.0:
            return True
        self._stop.wait(min(wait, CLOCK_POLL_S))
        return False

    def _run(self) -> None:
        while not self._stop.is_set():
            if not self._attempt_due():
                continue
            sock = self._connect()
            if sock is None:
                self.next_attempt = self._clock() + self.reconnect_s
                continue
            self.next_attempt = None
            self._serve(sock)
            self.next_attempt = self._clock() + min(self.reconnect_s, 0.2)
        with self._lock:
            self._status.state = "stopped"
