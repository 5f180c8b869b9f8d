"""--forward HOST:PORT: every line from the phone reaches another TCP server verbatim and in
order; a receiver that closes is reconnected; a slow or absent one never holds up the caller."""

from __future__ import annotations

import random
import socket
import threading
import time

import pytest

from waiting import wait_until

from app.engine.config import ConfigError, forward_target
from app.engine.live.worker import Engine
from app.stream.emulator import PhoneEmulator
from app.stream.forwarder import LineForwarder
from app.stream.sources import TcpSource


def _wait(predicate, timeout: float = 15.0):
    return wait_until(predicate, timeout, poll_s=0.01)


class Receiver:
    """A TCP server like the MATLAB kit's reader: accepts connections one after another and
    keeps what each sent (or, with read=False, reads nothing); `ended` counts the connections
    the sender closed."""

    def __init__(self, read: bool = True) -> None:
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(4)
        self.port = self.listener.getsockname()[1]
        self.read = read
        self.received: list[bytearray] = []
        self.client: socket.socket | None = None
        self.ended = 0
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        self.listener.settimeout(0.1)
        while not self._stop.is_set():
            try:
                client, _ = self.listener.accept()
            except (socket.timeout, OSError):
                continue
            self.client = client
            data = bytearray()
            self.received.append(data)
            client.settimeout(0.1)
            while not self._stop.is_set() and self.client is client:
                if not self.read:
                    time.sleep(0.05)                # reads nothing: the behaviour under test
                    continue
                try:
                    chunk = client.recv(65536)
                except socket.timeout:
                    continue
                except OSError:
                    break
                if not chunk:
                    self.ended += 1
                    break
                data.extend(chunk)

    def hang_up(self) -> None:
        client, self.client = self.client, None
        client.close()

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5)
        if self.client is not None:
            self.client.close()
        self.listener.close()


@pytest.fixture
def receiver():
    server = Receiver()
    yield server
    server.close()


def _lines(n: int, start: int = 0) -> list[bytes]:
    return [f"{1000 + 10 * k}\tACC\t0.1\t-0.2\t{9.8 + k % 7 / 100:.4f}\n".encode()
            for k in range(start, start + n)]


def _feed_in_random_pieces(forwarder: LineForwarder, data: bytes, connection: int = 1) -> None:
    rng = random.Random(4)
    position = 0
    while position < len(data):
        size = rng.randint(1, 300)
        forwarder.feed(data[position:position + size], connection)
        position += size


def test_every_line_arrives_byte_for_byte_in_order(receiver):
    data = b"".join(_lines(20_000)) + b"123\tGYR\t1e-3\t-0.0\t3.2043457E-4\r\n"
    with LineForwarder("127.0.0.1", receiver.port) as forwarder:
        _wait(lambda: forwarder.status().state == "connected")
        _feed_in_random_pieces(forwarder, data)         # lines cut anywhere, as TCP delivers
        _wait(lambda: receiver.received and len(receiver.received[0]) == len(data))
        status = forwarder.status()
    assert bytes(receiver.received[0]) == data
    assert status.lines_forwarded == 20_001 and status.lines_dropped == 0


def test_it_survives_the_receiver_closing_and_reconnects(receiver):
    with LineForwarder("127.0.0.1", receiver.port, reconnect_s=0.05) as forwarder:
        _wait(lambda: forwarder.status().state == "connected")
        first = b"".join(_lines(100))
        forwarder.feed(first, 1)
        _wait(lambda: receiver.received and len(receiver.received[0]) == len(first))
        receiver.hang_up()
        # lines fed while it notices and reconnects are dropped and counted, never queued up
        sent = 0

        def reconnected() -> bool:
            nonlocal sent
            if forwarder.status().connections >= 2:
                return True
            forwarder.feed(_lines(1, 100 + sent)[0], 1)
            sent += 1
            return False
        wait_until(reconnected, 15.0, what="the second connection", poll_s=0.002)
        _wait(lambda: len(receiver.received) == 2)
        later = b"".join(_lines(50, 10_000))
        forwarder.feed(later, 1)
        _wait(lambda: len(receiver.received) > 1
              and bytes(receiver.received[1]).endswith(later))
        status = forwarder.status()
    assert bytes(receiver.received[0]) == first
    second = bytes(receiver.received[1])
    assert second.endswith(later) and all(line.endswith(b"\n") for line in
                                          second.splitlines(keepends=True))
    assert status.lines_forwarded + status.lines_dropped == 100 + sent + 50
    assert status.connections == 2


def test_a_cut_line_of_a_dropped_connection_is_never_sent(receiver):
    with LineForwarder("127.0.0.1", receiver.port) as forwarder:
        _wait(lambda: forwarder.status().state == "connected")
        forwarder.feed(b"1000\tACC\t0.1\t0.2\t9.8\n1010\tACC\t0.1", connection=1)
        forwarder.feed(b"2000\tGYR\t0.0\t0.0\t0.1\n", connection=2)    # the phone reconnected
        _wait(lambda: receiver.received and receiver.received[0].count(b"\n") == 2)
    assert bytes(receiver.received[0]) == b"1000\tACC\t0.1\t0.2\t9.8\n2000\tGYR\t0.0\t0.0\t0.1\n"


def test_a_receiver_that_reads_nothing_never_blocks_the_caller():
    slow = Receiver(read=False)
    try:
        with LineForwarder("127.0.0.1", slow.port, max_queued_bytes=1 << 20) as forwarder:
            _wait(lambda: forwarder.status().state == "connected")
            block = b"".join(_lines(1000))                   # ~30 kB
            started = time.perf_counter()
            for _ in range(1000):                             # ~30 MB, far beyond the buffers
                forwarder.feed(block, 1)
            elapsed = time.perf_counter() - started
            status = forwarder.status()
    finally:
        slow.close()
    assert elapsed < 2.0
    assert status.dropped_full > 500_000
    assert status.lines_forwarded + status.lines_queued + status.lines_dropped == 1_000_000


def test_without_a_receiver_lines_are_dropped_and_counted():
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()                                            # nothing listens there
    with LineForwarder("127.0.0.1", port, reconnect_s=0.05) as forwarder:
        forwarder.feed(b"".join(_lines(10)), 1)
        _wait(lambda: forwarder.status().last_error)           # an attempt to connect failed
        status = forwarder.status()
    assert status.dropped_no_receiver == 10 and status.lines_forwarded == 0
    assert status.state == "connecting" and forwarder.status().state == "stopped"
    assert status.summary() == f"forward 127.0.0.1:{port} connecting, 0 lines sent, 10 dropped"


def test_the_engine_forwards_what_the_phone_sends(receiver):
    data = b"".join(_lines(3000)) + b"garbage line\n" + b"".join(_lines(10, 5000))
    forwarder = LineForwarder("127.0.0.1", receiver.port)
    engine = Engine(TcpSource("127.0.0.1", 0), comparisons=False, forwarder=forwarder)
    with engine:
        _wait(lambda: forwarder.status().state == "connected")
        with PhoneEmulator("127.0.0.1", engine.source.port) as phone:
            phone.send(data)
        _wait(lambda: receiver.received and len(receiver.received[0]) == len(data))
        health = _wait(lambda: engine.snapshot_now().health.forward.lines_forwarded == 3011
                       and engine.snapshot_now().health)
    assert bytes(receiver.received[0]) == data               # unknown lines too: verbatim
    assert health.forward.summary().startswith(f"forward 127.0.0.1:{receiver.port} connected")


@pytest.mark.parametrize("text, expected", [("192.168.1.5:3401", ("192.168.1.5", 3401)),
                                            (":3401", ("127.0.0.1", 3401)),
                                            ("3401", ("127.0.0.1", 3401))])
def test_forward_target(text, expected):
    assert forward_target(text) == expected


@pytest.mark.parametrize("text", ["host:", "host:70000", "host:0", "nowhere"])
def test_bad_forward_targets_are_one_line_errors(text):
    with pytest.raises(ConfigError):
        forward_target(text)


def test_a_forward_started_and_stopped_by_command_while_the_phone_streams(receiver):
    """SetForward (the connection panel's "Forward to"): started while the engine runs, every
    later line arrives verbatim; stopped, nothing more is sent and the phone link goes on."""
    from app.engine.commands import SetForward

    engine = Engine(TcpSource("127.0.0.1", 0), comparisons=False)
    with engine:
        assert engine.snapshot_now().health.forward is None
        engine.send(SetForward(f"127.0.0.1:{receiver.port}"))
        status = _wait(lambda: (f := engine.snapshot_now().health.forward) is not None
                       and f.state == "connected" and f)
        assert status.target == f"127.0.0.1:{receiver.port}"
        data = b"".join(_lines(2000))
        with PhoneEmulator("127.0.0.1", engine.source.port) as phone:
            phone.send(data)
            _wait(lambda: receiver.received and len(receiver.received[0]) == len(data))
            assert bytes(receiver.received[0]) == data
            engine.send(SetForward(None))
            _wait(lambda: engine.snapshot_now().health.forward is None)
            phone.send(b"".join(_lines(500, 9000)))
            _wait(lambda: engine.snapshot_now().health.lines_total >= 2500)
            _wait(lambda: receiver.ended == 1)        # the forward's connection is closed
        assert bytes(receiver.received[0]) == data            # nothing after the stop
        assert len(receiver.received) == 1
        engine.send(SetForward("nonsense:port"))
        note = _wait(lambda: [w for w in engine.snapshot_now().health.warnings
                              if "nonsense" in w or "'port'" in w])
        assert engine.snapshot_now().health.forward is None
    assert note[0] == "forward to 'nonsense:port': not a port number: 'port'"


def test_reconnection_waits_on_the_forwarders_clock_not_on_real_time():
    now = [100.0]
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.bind(("127.0.0.1", 0))          # bound, not listening: connections are refused
    port = listener.getsockname()[1]
    try:
        with LineForwarder("127.0.0.1", port, reconnect_s=30.0,
                           clock=lambda: now[0]) as forwarder:
            _wait(lambda: forwarder.status().last_error)           # the first attempt failed
            assert forwarder.next_attempt == 130.0
            listener.listen(1)
            now[0] = 130.0          # 30 s on the forwarder's clock: it connects at once
            _wait(lambda: forwarder.status().state == "connected", timeout=10.0)
            assert forwarder.next_attempt is None
            client, _ = listener.accept()
            client.close()                                         # the receiver hangs up
            _wait(lambda: forwarder.next_attempt is not None)
            assert forwarder.next_attempt == pytest.approx(130.2)  # a hang-up: 0.2 s
            assert forwarder.status().connections == 1
    finally:
        listener.close()
