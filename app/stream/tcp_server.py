"""The TCP server the phone connects to (the PC is the server; see ../shared/PROTOCOL.md).

It listens on every interface (the phone needs that), so whatever any machine on the LAN sends
is input. A background thread (plain ``threading`` + ``selectors``, no Qt) keeps the phone's
stream whatever else connects:

- **One stream, for the phone.** A phone sends hundreds of valid lines a second; a stranger's
  trickle does not keep the stream from it. A new connection is a *candidate*: its first
  ``PROBE_BYTES`` are read and held (not streamed, not recorded) and judged by their rate: it
  *shows a phone's rate* when it sent at least ``PHONE_LINES`` lines that parse within the
  latest ``RATE_WINDOW_S`` (a candidate whose held bytes are full is judged on how fast they
  came). While no one streams, the stream goes at once to a candidate at a phone's rate (the
  first of them); a slower one gets it when it has been the only kind for
  ``slow_stream_after_s`` since the stream was free, or when it hangs up (its lines then go
  out). The connection that streams keeps it against candidates (up to ``max_waiting``; they
  wait, they are not closed) until its own rate falls below a phone's while a candidate shows
  one, it has been silent (no valid line) for ``takeover_after_s`` while a candidate has sent a
  valid line, it never sent a valid line (after a short grace), it closes, or the user accepts
  a candidate (:class:`~app.stream.events.AcceptConnection`: the rate rule no longer applies
  to it; :class:`~app.stream.events.IgnoreConnection` closes one). The consumer sees
  "connected" / "disconnected" for the stream only.
- **Who may connect**: ``allow`` (addresses or networks, :class:`SetAllowedNetworks` changes
  it); others are closed at once and counted.
- **Junk is closed**: a connection that sends nothing valid within ``junk_bytes`` bytes or
  ``junk_after_s`` seconds is closed and counted (a newline flood costs its first 64 KiB).
  When ``max_waiting`` candidates wait, the longest-waiting one that sent nothing valid makes
  room for a newcomer (else the newcomer is closed).
- **Bounded buffers, per connection**: the stream's chunks wait for the consumer in a queue of
  at most ``max_buffered_bytes``; when it is full the server stops reading that socket (TCP
  flow control slows the phone, nothing is lost). A waiting connection holds at most
  ``PROBE_BYTES``. No other connection can fill what the phone's data goes through, and
  accepting never waits for the consumer (listen backlog 128).

Counts of the connections closed, by reason, and the waiting peers are in :meth:`info`; a
"closed" or "waiting" event (at most one a second per kind) tells the consumer something
happened.

The PC's own LAN addresses (:func:`lan_ipv4_addresses`), so the user knows what to type into
the phone's app, are at the end of this module.
"""

from __future__ import annotations

import collections
import ipaddress
import selectors
import shutil
import socket
import subprocess
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from app.stream.events import (AcceptConnection, Chunk, IgnoreConnection, SetAllowedNetworks,
                               SourceEvent)
from app.stream.fastparse import count_good_lines
from app.stream.protocol import DEFAULT_LIMITS, MAX_LINE_BYTES, Limits

DEFAULT_PORT = 3400
RECV_BYTES = 65536
PROBE_BYTES = 65536          # what a waiting connection may send before the server stops reading
LISTEN_BACKLOG = 128
HOUSEKEEPING_S = 0.1
NEVER_VALID_GRACE_S = 0.5    # a stream that never sent a valid line yields after this long
NOTE_INTERVAL_S = 1.0
PHONE_LINES = 10             # valid lines within RATE_WINDOW_S: a phone's rate (phones: 100-300/s)
RATE_WINDOW_S = 2.0
SLOW_STREAM_AFTER_S = 10.0   # a slower candidate streams once the stream has been free this long


def _peer_text(address) -> str:
    try:
        return f"{address[0]}:{address[1]}"
    except (TypeError, IndexError):
        return str(address)


def parse_networks(texts) -> list[ipaddress.IPv4Network | ipaddress.IPv6Network]:
    """"192.168.1.42", "192.168.1.0/24" -> networks; ValueError for a bad one."""
    return [ipaddress.ip_network(str(text).strip(), strict=False) for text in texts
            if str(text).strip()]


@dataclass(eq=False)
class _Connection:
    number: int
    sock: socket.socket
    peer: str
    address: str
    since: float                      # monotonic
    received: int = 0
    valid: bool = False               # has sent a line that parses
    last_valid: float = 0.0           # monotonic time of the latest chunk holding one
    tail: bytes = b""                 # the unfinished line at the end of what arrived
    held: list[bytes] = field(default_factory=list)   # a waiting connection's first bytes
    held_bytes: int = 0
    reading: bool = True              # registered with the selector
    reading_since: float = 0.0        # monotonic: read since then (set when reading resumes)
    # (monotonic time, valid lines) of its chunks within the latest RATE_WINDOW_S, and their sum
    good: collections.deque = field(default_factory=collections.deque)
    good_in_window: int = 0
    judged_at: float | None = None    # a candidate no longer read (its held bytes are full)
    accepted: bool = False            # the user chose it: the rate rule does not apply


class TcpServer:
    """Listen on host:port in a background thread; one stream at a time (see the module
    docstring for the policy).

    port 0 picks a free port (read :attr:`port` after :meth:`start`). ``max_queued`` x
    RECV_BYTES bounds the bytes waiting for the consumer.
    """

    def __init__(self, host: str = "0.0.0.0", port: int = DEFAULT_PORT,
                 max_queued: int = 256, allow=(), takeover_after_s: float = 3.0,
                 junk_bytes: int = 65536, junk_after_s: float = 10.0, max_waiting: int = 8,
                 limits: Limits = DEFAULT_LIMITS,
                 slow_stream_after_s: float = SLOW_STREAM_AFTER_S) -> None:
        self.host = host
        self.requested_port = port
        self.port: int | None = None
        self.state = "stopped"           # "waiting" | "connected" | "disconnected" | "stopped"
        self.peer: str | None = None
        self.connections = 0             # connections accepted so far (allowed ones)
        self.bytes_received = 0          # bytes of the stream (the connection that streams)
        self.max_buffered_bytes = max(1, int(max_queued)) * RECV_BYTES
        self.takeover_after_s = float(takeover_after_s)
        self.junk_bytes = int(junk_bytes)
        self.junk_after_s = float(junk_after_s)
        self.max_waiting = int(max_waiting)
        self.slow_stream_after_s = float(slow_stream_after_s)
        self.limits = limits
        self._allowed = parse_networks(allow)
        self._cond = threading.Condition()
        self._items: collections.deque = collections.deque()   # Chunk | SourceEvent
        self._items_bytes = 0
        self._commands: collections.deque = collections.deque()
        self._closed_counts: dict[str, int] = {}
        self._waiting_peers: list[str] = []
        self._note_times: dict[str, float] = {}
        self._active: _Connection | None = None
        self._waiting: list[_Connection] = []      # the candidates, oldest first
        self._free_since = 0.0                     # monotonic: since when no one streams
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._listener: socket.socket | None = None
        self._selector: selectors.BaseSelector | None = None
        self._wake_reader: socket.socket | None = None
        self._wake_writer: socket.socket | None = None

    # -- lifecycle ------------------------------------------------------------------------------

    def start(self) -> None:
        """Bind and listen (OSError if the port is taken), then serve in a daemon thread."""
        if self._thread is not None:
            return
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            listener.bind((self.host, self.requested_port))
            listener.listen(LISTEN_BACKLOG)
            listener.setblocking(False)
        except OSError:
            listener.close()
            raise
        self._listener = listener
        self.port = listener.getsockname()[1]
        self._wake_reader, self._wake_writer = socket.socketpair()
        self._wake_reader.setblocking(False)
        self._wake_writer.setblocking(False)
        self._selector = selectors.DefaultSelector()
        self._selector.register(listener, selectors.EVENT_READ, "listen")
        self._selector.register(self._wake_reader, selectors.EVENT_READ, "wake")
        self.state = "waiting"
        self._free_since = time.monotonic()
        self._put(SourceEvent("listening", detail=f"{self.host}:{self.port}",
                              t_host=time.perf_counter()))
        self._thread = threading.Thread(target=self._run, name="tcp-server", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Close every socket and join the thread. Idempotent."""
        self._stop.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        for connection in [self._active] + self._waiting:
            if connection is not None:
                _close(connection.sock)
        self._active = None
        self._waiting = []
        for sock in (self._listener, self._wake_reader, self._wake_writer):
            if sock is not None:
                _close(sock)
        self._listener = self._wake_reader = self._wake_writer = None
        if self._selector is not None:
            self._selector.close()
            self._selector = None
        self.state = "stopped"

    def __enter__(self) -> TcpServer:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # -- consumer side --------------------------------------------------------------------------

    def get(self, timeout: float = 0.05, max_items: int = 256) -> list[Chunk | SourceEvent]:
        """Wait up to `timeout` s for the first item, then drain without waiting."""
        items: list[Chunk | SourceEvent] = []
        with self._cond:
            if not self._items and timeout > 0:
                self._cond.wait(timeout)
            while self._items and len(items) < max_items:
                item = self._items.popleft()
                if isinstance(item, Chunk):
                    self._items_bytes -= len(item.data)
                items.append(item)
            resume = self._items_bytes <= self.max_buffered_bytes // 2
        active = self._active
        if resume and active is not None and not active.reading:
            self._wake()            # the server thread reads the stream's socket again
        return items

    def control(self, command: Any) -> None:
        """AcceptConnection / IgnoreConnection / SetAllowedNetworks (applied by the server
        thread, in order). A bad address in SetAllowedNetworks changes nothing: an "error"
        event says why (app.engine.config.allowed_networks checks the user's text first)."""
        if isinstance(command, SetAllowedNetworks):
            try:
                parse_networks(command.networks)
            except ValueError as error:
                self._put(SourceEvent("error", detail=f"allowed addresses unchanged: {error}",
                                      t_host=time.perf_counter()))
                return
        self._commands.append(command)
        self._wake()

    def info(self) -> dict[str, Any]:
        """waiting_peers, connections_closed (reason -> count), allowed (texts)."""
        with self._cond:
            return {"waiting_peers": list(self._waiting_peers),
                    "connections_closed": dict(self._closed_counts),
                    "allowed": [str(network) for network in self._allowed]}

    # -- server thread ----------------------------------------------------------------------------

    def _wake(self) -> None:
        writer = self._wake_writer
        if writer is not None:
            try:
                writer.send(b"x")
            except OSError:          # full (a wake-up is pending anyway) or closed
                pass

    def _put(self, item) -> None:
        with self._cond:
            self._items.append(item)
            if isinstance(item, Chunk):
                self._items_bytes += len(item.data)
            self._cond.notify_all()

    def _note(self, kind: str, detail: str, peer: str | None = None) -> None:
        """A "closed"/"waiting" event, at most one a second per kind."""
        now = time.monotonic()
        if now - self._note_times.get(kind, -1e9) >= NOTE_INTERVAL_S:
            self._note_times[kind] = now
            self._put(SourceEvent(kind, 0, peer, detail, time.perf_counter()))

    def _count_closed(self, reason: str, peer: str) -> None:
        with self._cond:
            count = self._closed_counts[reason] = self._closed_counts.get(reason, 0) + 1
        self._note("closed", f"closed the connection from {peer}: {reason} ({count} so far)",
                   peer)

    def _publish_waiting(self) -> None:
        with self._cond:
            self._waiting_peers = [connection.peer for connection in self._waiting]

    def _allowed_address(self, address: str) -> bool:
        if not self._allowed:
            return True
        try:
            ip = ipaddress.ip_address(address)
        except ValueError:
            return False
        return any(ip in network for network in self._allowed)

    def _accept(self) -> None:
        for _ in range(64):                         # drain the backlog
            try:
                sock, address = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as error:
                self._put(SourceEvent("error", detail=f"accept failed: {error}",
                                      t_host=time.perf_counter()))
                return
            peer = _peer_text(address)
            if not self._allowed_address(str(address[0])):
                _close(sock)
                self._count_closed("not allowed", peer)
                continue
            if len(self._waiting) >= self.max_waiting and not self._make_room():
                _close(sock)
                self._count_closed("too many waiting", peer)
                continue
            sock.setblocking(False)
            try:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            except OSError:
                pass
            self.connections += 1
            now = time.monotonic()
            connection = _Connection(self.connections, sock, peer, str(address[0]), now,
                                     reading_since=now)
            self._selector.register(sock, selectors.EVENT_READ, connection)
            self._waiting.append(connection)
            self._publish_waiting()
            if self._active is not None:
                self._note("waiting", f"a new device at {connection.address} wants to stream "
                                      "(waiting)", peer)

    def _make_room(self) -> bool:
        """Close the longest-waiting candidate that sent nothing valid (a slow-loris): True when
        there was one."""
        idle = next((c for c in self._waiting if not c.valid), None)
        if idle is None:
            return False
        self._drop(idle, "made room for a new connection", "too many waiting")
        return True

    def _receive(self, connection: _Connection) -> None:
        active = connection is self._active
        limit = RECV_BYTES if active else PROBE_BYTES - connection.held_bytes
        if limit <= 0:
            self._pause(connection)
            return
        try:
            data = connection.sock.recv(limit)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as error:
            self._drop(connection, f"connection error: {error}")
            return
        if not data:
            if not active and self._active is None and connection.valid \
                    and not self._at_phone_rate_other(connection):
                # it hung up before it was chosen and no one else streams: its lines go out
                self._activate(connection, "sent its lines and closed")
                active = True
            self._drop(connection, "closed by the phone" if active else "closed while waiting")
            return
        connection.received += len(data)
        self._check_valid(connection, data)
        if active:
            self.bytes_received += len(data)
            self._put(Chunk(connection.number, data, time.perf_counter()))
            if self._items_bytes >= self.max_buffered_bytes:
                self._pause(connection)
        else:
            connection.held.append(data)
            connection.held_bytes += len(data)
            if connection.held_bytes >= PROBE_BYTES:
                self._pause(connection)
                connection.judged_at = time.monotonic()
        if not connection.valid and connection.received >= self.junk_bytes:
            self._drop(connection, f"sent nothing valid in its first {self.junk_bytes} bytes",
                       "nothing valid")

    def _check_valid(self, connection: _Connection, data: bytes) -> None:
        probe = connection.tail + data if connection.tail else data
        good = count_good_lines(probe, self.limits, PHONE_LINES)
        if good:
            now = time.monotonic()
            connection.valid = True
            connection.last_valid = now
            connection.good.append((now, good))
            connection.good_in_window += good
            self._rate_lines(connection, now)         # forget what left the window
        newline = probe.rfind(b"\n")
        tail = probe[newline + 1:] if newline >= 0 else probe
        connection.tail = tail if len(tail) <= MAX_LINE_BYTES else b""

    def _pause(self, connection: _Connection) -> None:
        if connection.reading:
            self._selector.unregister(connection.sock)
            connection.reading = False

    def _resume(self, connection: _Connection) -> None:
        if not connection.reading:
            self._selector.register(connection.sock, selectors.EVENT_READ, connection)
            connection.reading = True
            connection.reading_since = time.monotonic()

    def _rate_lines(self, connection: _Connection, now: float) -> int:
        """Valid lines the connection sent within the latest RATE_WINDOW_S (up to when it was
        no longer read, for a candidate whose held bytes are full); at most PHONE_LINES are
        counted a chunk."""
        until = connection.judged_at if connection.judged_at is not None else now
        good = connection.good
        while good and good[0][0] <= until - RATE_WINDOW_S:
            connection.good_in_window -= good.popleft()[1]
        return connection.good_in_window

    def _at_phone_rate(self, now: float) -> _Connection | None:
        """The first candidate that shows a phone's rate."""
        return next((c for c in self._waiting if self._rate_lines(c, now) >= PHONE_LINES), None)

    def _at_phone_rate_other(self, connection: _Connection) -> bool:
        now = time.monotonic()
        return any(c is not connection and self._rate_lines(c, now) >= PHONE_LINES
                   for c in self._waiting)

    def _activate(self, connection: _Connection, detail: str) -> None:
        if connection in self._waiting:
            self._waiting.remove(connection)
        connection.judged_at = None
        self._active = connection
        self.peer = connection.peer
        self.state = "connected"
        now = time.perf_counter()
        self._put(SourceEvent("connected", connection.number, connection.peer, detail, now))
        for data in connection.held:
            self.bytes_received += len(data)
            self._put(Chunk(connection.number, data, now))
        connection.held = []
        connection.held_bytes = 0
        self._resume(connection)
        self._publish_waiting()

    def _drop(self, connection: _Connection, reason: str, counted_as: str | None = None,
              promote: bool = True) -> None:
        """Close a connection; when it was the stream, say so and let a waiting one take
        over (promote)."""
        self._pause(connection)
        _close(connection.sock)
        if connection is self._active:
            self._active = None
            self._free_since = time.monotonic()
            self.state = "disconnected"
            self._put(SourceEvent("disconnected", connection.number, connection.peer, reason,
                                  time.perf_counter()))
            if promote:
                self._fill(self._free_since)
        elif connection in self._waiting:
            self._waiting.remove(connection)
        if counted_as is not None:
            self._count_closed(counted_as, connection.peer)
        self._publish_waiting()

    def _fill(self, now: float) -> None:
        """No one streams: a candidate at a phone's rate streams now; a slower one that sent a
        valid line once the stream has been free for slow_stream_after_s (and it has waited
        that long)."""
        if self._active is not None or not self._waiting:
            return
        chosen = self._at_phone_rate(now)
        if chosen is not None:
            self._activate(chosen, "streams at a phone's rate")
            return
        patience = self.slow_stream_after_s
        if now - self._free_since < patience:
            return
        chosen = next((c for c in self._waiting if c.valid and now - c.since >= patience), None)
        if chosen is not None:
            self._activate(chosen, f"no phone streamed for {patience:g} s")

    def _housekeeping(self) -> None:
        now = time.monotonic()
        for connection in [self._active] + list(self._waiting):
            if connection is not None and not connection.valid \
                    and now - connection.since >= self.junk_after_s:
                self._drop(connection, f"sent nothing valid in {self.junk_after_s:g} s",
                           "nothing valid")
        active = self._active
        if active is None:
            self._fill(now)
            return
        candidate = next((c for c in self._waiting if c.valid), None)
        if candidate is None:
            return
        if not active.valid and now - active.since >= NEVER_VALID_GRACE_S:
            why = "it sent nothing valid"
        elif active.valid and now - active.last_valid >= self.takeover_after_s:
            why = f"it sent nothing valid for {self.takeover_after_s:g} s"
        elif not active.accepted and active.reading \
                and now - active.reading_since >= RATE_WINDOW_S \
                and (lines := self._rate_lines(active, now)) < PHONE_LINES \
                and (phone := self._at_phone_rate(now)) is not None:
            # a stranger's trickle: a phone streams at its rate beside it
            candidate = phone
            why = f"{lines} valid lines in {RATE_WINDOW_S:g} s, below a phone's rate"
        else:
            return
        self._drop(active, f"replaced by {candidate.peer}: {why}", "replaced", promote=False)
        self._activate(candidate, f"took over from {active.peer}: {why}")

    def _apply(self, command: Any) -> None:
        if isinstance(command, AcceptConnection):
            chosen = next((c for c in self._waiting
                           if command.peer is None or c.peer == command.peer), None)
            if chosen is None:
                return
            self._waiting.remove(chosen)
            if self._active is not None:
                self._drop(self._active, f"replaced by {chosen.peer}: accepted by the user",
                           "replaced", promote=False)
            chosen.accepted = True
            self._activate(chosen, "accepted by the user")
        elif isinstance(command, IgnoreConnection):
            for connection in list(self._waiting):
                if command.peer is None or connection.peer == command.peer:
                    self._drop(connection, "ignored by the user", "ignored")
        elif isinstance(command, SetAllowedNetworks):
            networks = parse_networks(command.networks)
            with self._cond:
                self._allowed = networks
            for connection in list(self._waiting) + [self._active]:
                if connection is not None and not self._allowed_address(connection.address):
                    self._drop(connection, "not in the allowed addresses", "not allowed")

    def _step(self) -> None:
        for key, _ in self._selector.select(timeout=HOUSEKEEPING_S):
            if self._stop.is_set():
                return
            if key.data == "listen":
                self._accept()
            elif key.data == "wake":
                try:
                    self._wake_reader.recv(4096)
                except OSError:
                    pass
            elif key.data is self._active or key.data in self._waiting:
                self._receive(key.data)
        while self._commands:
            self._apply(self._commands.popleft())
        active = self._active
        if active is not None and not active.reading \
                and self._items_bytes <= self.max_buffered_bytes // 2:
            self._resume(active)
        self._housekeeping()

    def _run(self) -> None:
        failures = 0
        while not self._stop.is_set():
            try:
                self._step()
                failures = 0
            except Exception as error:   # never die silently: report, the consumer shows it
                failures += 1
                self._put(SourceEvent("error", detail=f"server thread failed: {error!r}",
                                      t_host=time.perf_counter()))
                if failures >= 20:
                    return
                time.sleep(0.05)


def _close(sock: socket.socket) -> None:
    try:
        sock.close()
    except OSError:
        pass


# -- the PC's LAN addresses --------------------------------------------------------------------
#
# The PC's own LAN IPv4 addresses, so the user knows what to type into the phone's app.
#
# Only local interface queries: ``ip -4 -o addr`` where it exists (Linux), the address the system
# would send from (a UDP socket "connected" to a private address: no packet is sent; Windows and
# macOS) and the host name's addresses.


def _from_hostname() -> list[str]:
    try:
        infos = socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET)
    except OSError:
        return []
    return [info[4][0] for info in infos]


def parse_ip_addr_output(text: str) -> list[str]:
    """Addresses from ``ip -4 -o addr`` output lines like
    ``2: eth0    inet 192.168.1.23/24 brd 192.168.1.255 scope global eth0``."""
    out = []
    for line in text.splitlines():
        fields = line.split()
        if "inet" in fields:
            index = fields.index("inet")
            if index + 1 < len(fields):
                out.append(fields[index + 1].split("/")[0])
    return out


def _from_ip_command() -> list[str]:
    ip = shutil.which("ip")
    if ip is None:
        return []
    try:
        done = subprocess.run([ip, "-4", "-o", "addr", "show"], capture_output=True, text=True,
                              timeout=2.0, check=False)
    except (OSError, subprocess.SubprocessError):
        return []
    return parse_ip_addr_output(done.stdout)


def _from_route() -> list[str]:
    """The address of the interface the system routes LAN traffic through (connect() on a UDP
    socket picks it without sending anything)."""
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.connect(("10.255.255.255", 1))
        return [probe.getsockname()[0]]
    except OSError:
        return []
    finally:
        probe.close()


def lan_ipv4_addresses() -> list[str]:
    """LAN IPv4 addresses of this machine, private ones first, loopback last.

    Always returns at least one address ("127.0.0.1" when nothing else is found).
    """
    found: list[str] = []
    for address in _from_ip_command() + _from_route() + _from_hostname():
        try:
            parsed = ipaddress.IPv4Address(address)
        except ValueError:
            continue
        if parsed.is_unspecified or parsed.is_multicast or parsed.is_link_local:
            continue
        if address not in found:
            found.append(address)

    def rank(address: str) -> tuple[int, str]:
        parsed = ipaddress.IPv4Address(address)
        return (2 if parsed.is_loopback else 0 if parsed.is_private else 1, address)

    found.sort(key=rank)
    return found or ["127.0.0.1"]
