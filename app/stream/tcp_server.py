"""The TCP server the phone connects to (the PC is the server; see ../shared/PROTOCOL.md).

A background thread (plain ``threading`` + ``selectors``, no Qt) accepts one phone at a time:
a new connection wins and the old one is closed (a phone that stopped and started again may
leave a half-open socket). Received bytes and connection events go into a bounded queue that
the engine drains with :meth:`TcpServer.get`. When the queue is full the thread stops reading,
so TCP flow control slows the phone down instead of memory growing or data being lost.
"""

from __future__ import annotations

import queue
import selectors
import socket
import threading
import time

from app.stream.events import Chunk, SourceEvent

DEFAULT_PORT = 3400
RECV_BYTES = 65536


def _peer_text(address) -> str:
    try:
        return f"{address[0]}:{address[1]}"
    except (TypeError, IndexError):
        return str(address)


class TcpServer:
    """Listen on host:port in a background thread; one client at a time, newest wins.

    port 0 picks a free port (read :attr:`port` after :meth:`start`). ``max_queued`` bounds the
    chunks waiting for the consumer (at most max_queued x RECV_BYTES bytes).
    """

    def __init__(self, host: str = "0.0.0.0", port: int = DEFAULT_PORT,
                 max_queued: int = 256) -> None:
        self.host = host
        self.requested_port = port
        self.port: int | None = None
        self.state = "stopped"           # "waiting" | "connected" | "disconnected" | "stopped"
        self.peer: str | None = None
        self.connections = 0             # connections accepted so far
        self.bytes_received = 0
        self._queue: queue.Queue = queue.Queue(maxsize=max_queued)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._listener: socket.socket | None = None
        self._client: socket.socket | None = None
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
            listener.listen(4)
            listener.setblocking(False)
        except OSError:
            listener.close()
            raise
        self._listener = listener
        self.port = listener.getsockname()[1]
        self._wake_reader, self._wake_writer = socket.socketpair()
        self._wake_reader.setblocking(False)
        self._selector = selectors.DefaultSelector()
        self._selector.register(listener, selectors.EVENT_READ, "listen")
        self._selector.register(self._wake_reader, selectors.EVENT_READ, "wake")
        self.state = "waiting"
        self._put(SourceEvent("listening", detail=f"{self.host}:{self.port}",
                              t_host=time.perf_counter()))
        self._thread = threading.Thread(target=self._run, name="tcp-server", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Close every socket and join the thread. Idempotent."""
        self._stop.set()
        if self._wake_writer is not None:
            try:
                self._wake_writer.send(b"x")
            except OSError:
                pass
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        for sock in (self._client, self._listener, self._wake_reader, self._wake_writer):
            if sock is not None:
                try:
                    sock.close()
                except OSError:
                    pass
        self._client = self._listener = self._wake_reader = self._wake_writer = None
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
        try:
            items.append(self._queue.get(timeout=timeout) if timeout > 0
                         else self._queue.get_nowait())
            while len(items) < max_items:
                items.append(self._queue.get_nowait())
        except queue.Empty:
            pass
        return items

    # -- server thread ----------------------------------------------------------------------------

    def _put(self, item) -> bool:
        # Block (TCP back-pressure) rather than drop; give up only when stopping.
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _close_client(self, reason: str) -> None:
        client = self._client
        if client is None:
            return
        self._client = None
        try:
            self._selector.unregister(client)
        except (KeyError, ValueError):
            pass
        try:
            client.close()
        except OSError:
            pass
        self.state = "disconnected"
        self._put(SourceEvent("disconnected", self.connections, self.peer, reason,
                              time.perf_counter()))

    def _accept(self) -> None:
        try:
            client, address = self._listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        except OSError as error:
            self._put(SourceEvent("error", detail=f"accept failed: {error}",
                                  t_host=time.perf_counter()))
            return
        if self._client is not None:
            self._close_client("replaced by a new connection")
        client.setblocking(False)
        try:
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError:
            pass
        self._client = client
        self.connections += 1
        self.peer = _peer_text(address)
        self.state = "connected"
        self._selector.register(client, selectors.EVENT_READ, "client")
        self._put(SourceEvent("connected", self.connections, self.peer, "",
                              time.perf_counter()))

    def _receive(self) -> None:
        client = self._client
        try:
            data = client.recv(RECV_BYTES)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as error:
            self._close_client(f"connection error: {error}")
            return
        if not data:
            self._close_client("closed by the phone")
            return
        self.bytes_received += len(data)
        self._put(Chunk(self.connections, data, time.perf_counter()))

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                for key, _ in self._selector.select(timeout=0.5):
                    if self._stop.is_set():
                        break
                    if key.data == "listen":
                        self._accept()
                    elif key.data == "client":
                        if key.fileobj is self._client:
                            self._receive()
                    else:
                        try:
                            self._wake_reader.recv(64)
                        except OSError:
                            pass
        except Exception as error:   # never die silently: report, the consumer shows it
            self._put(SourceEvent("error", detail=f"server thread failed: {error!r}",
                                  t_host=time.perf_counter()))
        finally:
            if self._client is not None:
                try:
                    self._client.close()
                except OSError:
                    pass
                self._client = None
