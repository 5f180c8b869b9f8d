"""Loopback tests: the TCP server and the engine survive whatever a client does; counts are right."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from waiting import wait_until as _wait

from app.engine.live.worker import Engine
from app.stream.emulator import PhoneEmulator, send_log
from app.stream.sources import TcpSource
from app.stream.events import Chunk, SourceEvent
from app.stream.tcp_server import TcpServer


@pytest.fixture
def engine():
    source = TcpSource("127.0.0.1", 0)
    running = Engine(source, comparisons=False, record_rows=True)
    running.start()
    yield running
    running.stop()
    assert not running.running and not source.server.running


def _health(engine: Engine):
    return engine.snapshot_now().health


def _lines(n: int, t0: int = 1000, step: int = 10) -> bytes:
    out = []
    for k in range(n):
        t = t0 + step * k
        out.append(f"{t}\tGYR\t0.01\t0.0\t0.0\n{t}\tACC\t0.0\t0.0\t9.81\n{t}\tMAG\t0.0\t20.0\t-40.0\n")
    return "".join(out).encode()


def test_server_events_and_chunks_then_clean_stop():
    with TcpServer("127.0.0.1", 0) as server:
        assert server.port and server.state == "waiting"
        with socket.create_connection(("127.0.0.1", server.port)) as client:
            client.sendall(b"1\tACC\t1\t2\t3\n")
            items = []
            _wait(lambda: items.extend(server.get(0.05)) or any(
                isinstance(i, Chunk) for i in items))
        _wait(lambda: items.extend(server.get(0.05)) or any(
            isinstance(i, SourceEvent) and i.kind == "disconnected" for i in items))
        kinds = [i.kind for i in items if isinstance(i, SourceEvent)]
        assert kinds == ["listening", "connected", "disconnected"]
        assert b"".join(i.data for i in items if isinstance(i, Chunk)) == b"1\tACC\t1\t2\t3\n"
    assert not server.running and server.state == "stopped"


def test_split_lines_crlf_and_garbage(engine):
    data = _lines(50).replace(b"\n", b"\r\n") + b"\xff\xfe\x00garbage\r\n" + b"2000\tFOO\t1\n"
    with PhoneEmulator("127.0.0.1", engine.source.port) as phone:
        for index in range(0, len(data), 7):          # 7-byte pieces split every line
            phone.send(data[index:index + 7])
            if index % 700 == 0:
                time.sleep(0.001)                 # now and then apart, so pieces arrive apart
    health = _wait(lambda: (h := _health(engine)).connection_state == "disconnected" and h)
    assert health.lines_total == 152 and health.damaged == 1 and health.unknown == 1
    rows = sum(len(r) for r in engine.rows_log)
    assert rows == 50


def test_megabyte_line_without_newline_is_discarded_with_bounded_memory(engine):
    with PhoneEmulator("127.0.0.1", engine.source.port) as phone:
        phone.send(_lines(5))
        phone.send(b"1" * (1 << 20))
        phone.send(b"\n" + _lines(5, t0=1050))
    health = _wait(lambda: (h := _health(engine)).connection_state == "disconnected" and h)
    assert health.too_long == 1 and health.damaged == 0 and health.lines_total == 31
    assert len(engine.pipeline.parser._pending) == 0


def test_silent_client_then_disconnect_mid_line(engine):
    port = engine.source.port
    silent = socket.create_connection(("127.0.0.1", port))
    host, own_port = silent.getsockname()[:2]
    # a candidate, not the stream: it sent nothing
    _wait(lambda: _health(engine).waiting_peers == [f"{host}:{own_port}"])
    assert _health(engine).connection_state == "waiting"
    silent.close()
    _wait(lambda: _health(engine).waiting_peers == [])
    with PhoneEmulator("127.0.0.1", port) as phone:
        phone.send(_lines(10) + b"1100\tACC\t0.0\t0.")   # cut in the middle of a line
    health = _wait(lambda: (h := _health(engine)).connection_state == "disconnected"
                   and h.lines_total == 31 and h)
    assert health.damaged == 1                    # the cut line, not parsed as "0."


def test_two_clients_in_a_row_and_at_once(engine):
    """The phone keeps its stream: a second connection while it streams waits (it is not
    closed, and neither is the phone), then takes over when the phone hangs up and it streams
    (its held lines first)."""
    port = engine.source.port
    with PhoneEmulator("127.0.0.1", port) as first:
        first.send(_lines(10))
    _wait(lambda: _health(engine).lines_total == 30)
    old = PhoneEmulator("127.0.0.1", port).connect()
    old.send(_lines(10, t0=1100))
    _wait(lambda: _health(engine).lines_total == 60)
    new = PhoneEmulator("127.0.0.1", port).connect()
    new.send(_lines(3, t0=1200))                  # 9 lines: below a phone's rate, it waits
    _wait(lambda: _health(engine).waiting_peers == [_peer(new)])
    old.send(_lines(10, t0=1300))                 # the phone goes on streaming
    health = _wait(lambda: (h := _health(engine)).lines_total == 90 and h)
    assert health.peer == _peer(old) and health.connection_state == "connected"
    old.sock.settimeout(0.2)
    assert not _closed(old.sock)                  # nobody cut the phone off
    old.close()
    _wait(lambda: _health(engine).connection_state == "disconnected")
    new.send(_lines(10, t0=1400))
    health = _wait(lambda: (h := _health(engine)).lines_total == 129 and h)
    assert health.peer == _peer(new) and health.waiting_peers == []
    new.close()
    assert health.damaged == 0 and engine.running


def _peer(phone: PhoneEmulator) -> str:
    host, port = phone.sock.getsockname()[:2]
    return f"{host}:{port}"


def _closed(sock: socket.socket) -> bool:
    try:
        return sock.recv(1) == b""
    except socket.timeout:
        return False
    except OSError:
        return True


def test_reconnect_with_time_jump_keeps_orientation(engine):
    port = engine.source.port
    with PhoneEmulator("127.0.0.1", port) as phone:
        phone.send(_lines(200))
    _wait(lambda: _health(engine).connection_state == "disconnected")
    before = engine.snapshot_now().own_quat
    with PhoneEmulator("127.0.0.1", port) as phone:
        phone.send(_lines(200, t0=500_000))
    # the row of the last time is committed when the stream ends (the phone hangs up)
    _wait(lambda: (s := engine.snapshot_now()).t_ms is not None and s.t_ms >= 500_000 + 1990
          and s.health.connection_state == "disconnected")
    after = engine.snapshot_now()
    assert after.health.out_of_order == 0
    # 2 s at 0.01 rad/s about x between the two: the estimate continues, it is not reset
    assert abs(after.own_quat @ before) > 0.99
    times = [t for rows in engine.rows_log for t in rows.t_ms.tolist()]
    assert times == sorted(times) and len(times) == 400


def test_clock_offset_log_over_tcp(engine, realphone_dir):
    send_log(realphone_dir / "sensorLog_20221020T074342.txt", "127.0.0.1", engine.source.port, 0)
    health = _wait(lambda: (h := _health(engine)).connection_state == "disconnected"
                   and h.lines_total == 6878 and h)
    assert health.clock_quirks == ["GYR clock -131072000 ms vs ACC (aligned)",
                                   "MAG clock -131072000 ms vs ACC (aligned)"]
    assert 95 < health.rates_hz["GYR"] < 105 and health.out_of_order == 0


def test_damaged_standstill_log_over_tcp(engine, realphone_dir):
    send_log(realphone_dir / "sensorLog_20221024T182616_standstill.txt", "127.0.0.1",
             engine.source.port, 0)
    health = _wait(lambda: (h := _health(engine)).connection_state == "disconnected"
                   and h.lines_total == 9339 and h)
    assert (health.damaged, health.unknown, health.out_of_order) == (2, 0, 420)


def test_emulator_paced_send_takes_the_log_time():
    received = []
    with TcpServer("127.0.0.1", 0) as server:
        lines = [f"{1000 + 10 * k}\tACC\t0\t0\t9.8\n".encode() for k in range(31)]
        def stream() -> None:
            with PhoneEmulator("127.0.0.1", server.port) as phone:
                phone.stream_lines(lines, speed=2.0)

        thread = threading.Thread(target=stream)
        started = time.perf_counter()
        thread.start()
        thread.join()
        elapsed = time.perf_counter() - started
        _wait(lambda: received.extend(server.get(0.05)) or sum(
            len(i.data) for i in received if isinstance(i, Chunk)) == sum(map(len, lines)))
    assert 0.13 < elapsed < 2.0                   # 300 ms of log at speed 2 (loaded CI: slack)


def test_a_late_tag_a_clock_offset_and_a_late_block_over_tcp(engine):
    """Issue 10, item 6 through the server: MAG written 150 ms late, GYR on a clock 2 s ahead,
    a 0.9 s block written 2.9 s late: only the block is dropped, no new segment."""
    events = []
    for k in range(800):
        t = 1000 + 10 * k
        events += [(t, 0, f"{t + 2000}\tGYR\t0.01\t0.0\t0.0\n"), (t, 1, f"{t}\tACC\t0.0\t0.0\t9.81\n"),
                   (t + 150, 2, f"{t}\tMAG\t0.0\t20.0\t-40.0\n")]
    block = [e for e in events if 3000 <= e[0] < 3900]
    rest = sorted(e for e in events if not 3000 <= e[0] < 3900)
    at = next(i for i, e in enumerate(rest) if e[0] >= 6800)
    data = "".join(e[2] for e in rest[:at] + block + rest[at:]).encode()
    with PhoneEmulator("127.0.0.1", engine.source.port) as phone:
        phone.send(data)
    health = _wait(lambda: (h := _health(engine)).connection_state == "disconnected"
                   and h.lines_total == 2400 and h)
    # MAG shares ACC's clock: it takes ACC's offset exactly (its 150 ms are a lag, waited for)
    assert health.clock_quirks == ["ACC clock -2000 ms vs GYR (aligned)",
                                   "MAG clock -2000 ms vs GYR (aligned)"]
    # the block, and the late MAG's first 150 ms after the gap it leaves (the others resumed
    # first; MAG, 150 ms behind, was inactive by then)
    assert len(block) <= health.out_of_order <= len(block) + 15 and health.sessions == 0
    assert health.lags_ms.get("MAG", 0) >= 140 and health.reorder_window_ms >= 150
