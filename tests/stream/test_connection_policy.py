"""Issues 10 and 46, through the real TCP server: nothing a client sends takes the phone away.

The phone keeps its stream (newcomers wait; they take over on silence, close or the user's
accept), a stranger's trickle never holds the stream against a phone (before it, or when the
phone reconnects) and none of its lines are recorded, --allow restricts who may connect, junk
connections are closed and counted, a newline flood costs the phone nothing, and an earlier
stranger's samples never carry over.
"""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from waiting import wait_until as _wait

from app.engine.commands import AcceptConnection, IgnoreConnection, SetAllowedNetworks
from app.engine.offline.filtering import filter_log
from app.engine.live.worker import Engine
from app.stream.emulator import PhoneEmulator
from app.stream.fastparse import count_good_lines
from app.stream.logfile import read_log
from app.stream.protocol import LineParser, Limits, java_float_text
from app.stream.recorder import Recorder
from app.stream.sources import TcpSource

STRANGER_T0 = 999_999_000_000_000_000     # ~1e18 ms: 18 digits, the most a time may have


def _engine(recorder: Recorder | None = None, **options) -> Engine:
    engine = Engine(TcpSource("127.0.0.1", 0, **options), comparisons=False, record_rows=True,
                    recorder=recorder)
    engine.start()
    return engine


@pytest.fixture
def make_engine():
    engines: list[Engine] = []

    def make(recorder: Recorder | None = None, **options) -> Engine:
        engines.append(_engine(recorder, **options))
        return engines[-1]

    yield make
    for engine in engines:
        engine.stop()
        assert not engine.running


def _health(engine: Engine):
    return engine.snapshot_now().health


def _lines(n: int, t0: int = 1000, step: int = 10) -> bytes:
    out = []
    for k in range(n):
        t = t0 + step * k
        out.append(f"{t}\tGYR\t0.01\t0.0\t0.0\n{t}\tACC\t0.0\t0.0\t9.81\n"
                   f"{t}\tMAG\t0.0\t20.0\t-40.0\n")
    return "".join(out).encode()


class _Client(PhoneEmulator):
    """A phone emulator connected at once (from a chosen address); `with` keeps that one
    connection instead of making another."""

    def __enter__(self) -> _Client:
        return self


def _phone(port: int, source: str = "127.0.0.1") -> PhoneEmulator:
    phone = _Client("127.0.0.1", port)
    phone.sock = socket.create_connection(("127.0.0.1", port), timeout=5.0,
                                          source_address=(source, 0))
    return phone


def _peer(phone: PhoneEmulator) -> str:
    host, port = phone.sock.getsockname()[:2]
    return f"{host}:{port}"


def _closed_by_server(sock: socket.socket, timeout: float = 5.0) -> bool:
    sock.settimeout(timeout)
    try:
        return sock.recv(1) == b""
    except socket.timeout:
        return False
    except OSError:
        return True


def test_a_stream_silent_for_takeover_after_s_is_taken_over(make_engine):
    engine = make_engine(takeover_after_s=0.5)
    port = engine.source.port
    phone = _phone(port)
    phone.send(_lines(20))
    _wait(lambda: _health(engine).lines_total == 60)
    second = _phone(port)
    second.send(_lines(20, t0=5000))
    # the phone goes silent (a half-open socket after it stopped): the newcomer takes over
    health = _wait(lambda: (h := _health(engine)).lines_total == 120 and h)
    assert health.peer == _peer(second) and health.connections_closed == {"replaced": 1}
    assert _closed_by_server(phone.sock)
    phone.close()
    second.close()


def test_the_user_accepts_or_ignores_a_waiting_device(make_engine):
    engine = make_engine(takeover_after_s=60)
    port = engine.source.port
    phone = _phone(port)
    phone.send(_lines(20))
    _wait(lambda: _health(engine).lines_total == 60)
    stranger = _phone(port)
    stranger.send(_lines(3, t0=10**6))        # 9 lines: below a phone's rate, it waits
    _wait(lambda: _health(engine).waiting_peers == [_peer(stranger)])
    engine.send(IgnoreConnection(_peer(stranger)))
    assert _closed_by_server(stranger.sock)
    health = _wait(lambda: (h := _health(engine)).connections_closed.get("ignored") == 1 and h)
    assert health.waiting_peers == [] and health.peer == _peer(phone)
    second = _phone(port)
    second.send(_lines(3, t0=3000))
    _wait(lambda: _health(engine).waiting_peers == [_peer(second)])
    engine.send(AcceptConnection(_peer(second)))
    health = _wait(lambda: (h := _health(engine)).lines_total == 69 and h)
    assert health.peer == _peer(second) and _closed_by_server(phone.sock)
    for client in (phone, stranger, second):
        client.close()


def test_allow_restricts_who_may_connect(make_engine):
    engine = make_engine(allow=["127.0.0.1"])
    port = engine.source.port
    outsider = _phone(port, source="127.0.0.2")
    assert _closed_by_server(outsider.sock)
    phone = _phone(port)
    phone.send(_lines(10))
    health = _wait(lambda: (h := _health(engine)).lines_total == 30 and h)
    assert health.connections_closed == {"not allowed": 1} and health.allowed == ["127.0.0.1/32"]
    # from the connection panel: only 127.0.0.2 from now on, the current stream included
    engine.send(SetAllowedNetworks(("127.0.0.2/32",)))
    assert _closed_by_server(phone.sock)
    other = _phone(port, source="127.0.0.2")
    other.send(_lines(10, t0=5000))
    health = _wait(lambda: (h := _health(engine)).lines_total == 60 and h)
    assert health.connections_closed == {"not allowed": 2} and health.peer == _peer(other)
    engine.send(SetAllowedNetworks(("10.0.0.300",)))          # a bad one changes nothing
    health = _wait(lambda: (h := _health(engine)) and any(
        "allowed addresses unchanged" in warning for warning in h.warnings) and h)
    assert health.allowed == ["127.0.0.2/32"] and engine.running and not engine.failures
    for client in (outsider, phone, other):
        client.close()


def test_connections_sending_nothing_valid_are_closed_and_counted(make_engine):
    engine = make_engine(junk_after_s=0.5)
    port = engine.source.port
    silent = _phone(port)                       # slow-loris: connects, sends nothing
    junk = _phone(port)
    junk.send(b"\x00\xff garbage \n" * 10_000)  # 130 KB of junk: beyond the 64 KiB budget
    assert _closed_by_server(junk.sock) and _closed_by_server(silent.sock)
    phone = _phone(port)
    phone.send(_lines(10))
    health = _wait(lambda: (h := _health(engine)).lines_total >= 30 and h.peer == _peer(phone)
                   and h)
    assert health.connections_closed == {"nothing valid": 2}
    for client in (silent, junk, phone):
        client.close()


def test_a_16_mib_newline_flood_before_the_phone_costs_its_first_64_kib_only(make_engine):
    """Was: 16 MiB of newlines before the phone delayed its data by 45 s (all of them went
    through the slow per-line path, and the shared queue blocked accepting). Now the flooder is
    closed after 64 KiB without a valid line and the phone streams at once (the delay itself is
    measured by benchmarks/chaos.py)."""
    engine = make_engine()
    port = engine.source.port
    flood = _phone(port)
    flood.sock.setblocking(False)
    sent = 0
    block = b"\n" * 65536

    def flooded() -> bool:                        # as much as the server takes
        nonlocal sent
        try:
            sent += flood.sock.send(block)
        except BlockingIOError:
            return False
        except OSError:
            return True                           # closed by the server: junk
        return sent >= 16 << 20
    _wait(flooded, 5.0, what="the server to close the flooder (or take 16 MiB)", poll_s=0.001)
    phone = _phone(port)
    phone.send(_lines(50))
    health = _wait(lambda: (h := _health(engine)).peer == _peer(phone)
                   and h.rates_hz and engine.rows_log and h)
    assert health.connections_closed == {"nothing valid": 1}
    # what reached the engine of the flood: its first 64 KiB and what was in flight
    assert health.lines_total - 150 <= 2 * 65536
    flood.sock.close()
    phone.close()


@pytest.mark.parametrize("paced", [False, True])
def test_an_earlier_strangers_clock_never_shifts_the_phone(make_engine, tmp_path, paced):
    """Was: a stranger's samples at t ~ 1e18 ms shifted the phone's time axis and left its
    estimate 12.6 deg off. Now the phone's session is its own: its times, its estimate. Paced:
    the new session starts while its first samples are still held (released chunks later)."""
    engine = make_engine()
    port = engine.source.port
    with _phone(port) as stranger:
        stranger.send(_lines(100, t0=STRANGER_T0).replace(b"ACC\t0.0\t0.0\t9.81",
                                                          b"ACC\t0.0\t9.81\t0.0")
                      + _lines(100, t0=STRANGER_T0 + 2000).replace(b"MAG\t0.0\t20.0",
                                                                   b"MAG\t30.0\t-5.0"))
    _wait(lambda: _health(engine).connection_state == "disconnected")
    phone_lines = _lines(300, t0=50_000)
    with _phone(port) as phone:
        if paced:
            for start in range(0, len(phone_lines), 400):
                phone.send(phone_lines[start:start + 400])
                time.sleep(0.01)                   # paced: the behaviour under test
        else:
            phone.send(phone_lines)
    _wait(lambda: (s := engine.snapshot_now()).t_ms == 50_000 + 2990
          and s.health.connection_state == "disconnected")
    rows = [r for r in engine.rows_log if len(r) and r.t_ms[0] < STRANGER_T0]
    t_ms = np.concatenate([r.t_ms for r in rows])
    quat = np.concatenate([r.quat for r in rows])
    log = tmp_path / "phone.txt"
    log.write_bytes(phone_lines)
    alone = filter_log(read_log(log), "ekf")
    assert np.array_equal(t_ms, alone.t_ms)              # the phone's own clock
    assert np.array_equal(quat, alone.quat)              # nothing of the stranger carried over
    assert _health(engine).sessions == 1


def test_absurd_values_over_tcp_are_counted_and_never_reach_the_filter(make_engine):
    engine = make_engine()
    bad = (b"1500\tACC\t1e160\t0\t0\n1510\tGYR\t1.0E20\t0\t0\n1520\tMAG\t1e100\t0\t0\n"
           b"1530\tORI\t2\t0\t0\t0\n1540\tORI\t0.9\t0.9\t0.9\n")
    with _phone(engine.source.port) as phone:
        phone.send(_lines(50) + bad + _lines(50, t0=1550))
    health = _wait(lambda: (h := _health(engine)).connection_state == "disconnected"
                   and h.lines_total == 305 and h)
    assert health.damaged_reasons == {"ACC out of range": 1, "GYR out of range": 1,
                                      "MAG out of range": 1, "ORI out of range": 2}
    quat = np.concatenate([r.quat for r in engine.rows_log])
    assert np.isfinite(quat).all() and engine.running and not engine.failures


class _Trickle(threading.Thread):
    """A stranger that connects and sends one valid line every `every_s` seconds (its own
    clock), as long as it likes: it never goes silent, it never streams like a phone."""

    def __init__(self, port: int, every_s: float = 0.25) -> None:
        super().__init__(daemon=True)
        self.client = _phone(port)
        self.every_s = every_s
        self.sent = 0
        self.stop = threading.Event()

    def run(self) -> None:
        while True:
            t = STRANGER_T0 + 2000 * self.sent
            try:
                self.client.send(f"{t}\tACC\t0.0\t9.81\t0.0\n".encode())
            except OSError:
                return                            # closed by the server
            self.sent += 1
            if self.stop.wait(self.every_s):       # its pace: the behaviour under test
                return

    def close(self) -> None:
        self.stop.set()
        self.join()
        self.client.close()


@pytest.fixture
def trickles():
    started: list[_Trickle] = []

    def start(port: int) -> _Trickle:
        started.append(_Trickle(port))
        started[-1].start()
        return started[-1]

    yield start
    for trickle in started:
        trickle.close()


def _raw(engine: Engine, folder) -> bytes:
    engine.stop()
    return (folder / "raw.txt").read_bytes()


def test_a_strangers_trickle_before_the_phone_never_holds_the_stream(make_engine, trickles,
                                                                      tmp_path):
    """Was: the first connection streamed; one that sent a valid line every 2 s kept the stream
    in `serve` for as long as it liked and its lines were recorded. Now the phone, streaming at
    its rate, gets the stream at once; the trickle waits and none of its lines are recorded."""
    folder = tmp_path / "rec"
    engine = make_engine(Recorder(folder))
    port = engine.source.port
    squatter = trickles(port)
    _wait(lambda: _health(engine).waiting_peers == [_peer(squatter.client)]
          and squatter.sent >= 2, what="the trickle to wait")
    phone_lines = _lines(300)
    with _phone(port) as phone:
        for start in range(0, len(phone_lines), 997):      # lines cut anywhere
            phone.send(phone_lines[start:start + 997])
        health = _wait(lambda: (h := _health(engine)).lines_total == 900 and h,
                       what="the phone's lines")
        assert health.peer == _peer(phone) and health.waiting_peers == [_peer(squatter.client)]
    _wait(lambda: _health(engine).connection_state == "disconnected")
    assert squatter.is_alive()                             # still trickling, still waiting
    assert _raw(engine, folder) == phone_lines             # the phone's, none of the trickle's


def test_when_the_phone_reconnects_it_streams_before_a_waiting_trickle(make_engine, trickles,
                                                                       tmp_path):
    """Was: when the phone hung up and connected again, the waiting trickle took the stream
    before it (and kept it). Now waiting clients are judged on what they send: the phone's
    second connection streams at its rate and gets the stream; the trickle's lines are never
    recorded."""
    folder = tmp_path / "rec"
    engine = make_engine(Recorder(folder))
    port = engine.source.port
    first, second = _lines(200), _lines(200, t0=1000 + 10 * 200)
    with _phone(port) as phone:
        phone.send(first)
        _wait(lambda: _health(engine).lines_total == 600)
        squatter = trickles(port)
        _wait(lambda: _health(engine).waiting_peers == [_peer(squatter.client)]
              and squatter.sent >= 2, what="the trickle to wait")
    _wait(lambda: _health(engine).connection_state == "disconnected")
    with _phone(port) as phone:
        phone.send(second)
        health = _wait(lambda: (h := _health(engine)).lines_total == 1200 and h,
                       what="the phone's second connection")
        assert health.peer == _peer(phone)
    assert squatter.is_alive() and _health(engine).connections_closed == {}
    assert _raw(engine, folder) == first + second


def test_a_slow_client_alone_streams_after_slow_stream_after_s_and_yields_to_a_phone(
        make_engine, trickles):
    """A client slower than a phone streams when no one else does for slow_stream_after_s;
    a phone that comes then takes the stream from it at once (its trickle is far below the
    phone's rate, though it never went silent)."""
    engine = make_engine(slow_stream_after_s=0.5)
    port = engine.source.port
    slow = trickles(port)
    health = _wait(lambda: (h := _health(engine)).connection_state == "connected" and h,
                   what="the slow client to stream")
    assert health.peer == _peer(slow.client) and health.waiting_peers == []
    with _phone(port) as phone:
        phone.send(_lines(100, t0=5000))
        health = _wait(lambda: (h := _health(engine)).peer == _peer(phone)
                       and h.lines_total >= 300 and h, what="the phone to take over")
    assert health.connections_closed == {"replaced": 1}
    assert _closed_by_server(slow.client.sock)


def test_a_client_that_hangs_up_before_it_was_chosen_has_its_lines_streamed(make_engine):
    """A short log sent and closed (fewer lines than a phone's rate shows): nothing is lost
    when no one else streams."""
    engine = make_engine()
    with _phone(engine.source.port) as client:
        client.send(_lines(2))
    health = _wait(lambda: (h := _health(engine)).lines_total == 6
                   and h.connection_state == "disconnected" and h)
    assert health.connections_closed == {} and sum(len(r) for r in engine.rows_log) == 2


def test_slow_loris_candidates_make_room_for_the_phone(make_engine):
    """max_waiting candidates that send nothing: the longest-waiting one is closed for a
    newcomer, so the phone is never refused for them."""
    engine = make_engine(max_waiting=3)
    port = engine.source.port
    silent = [_phone(port) for _ in range(3)]
    _wait(lambda: len(_health(engine).waiting_peers) == 3)
    with _phone(port) as phone:
        phone.send(_lines(20))
        health = _wait(lambda: (h := _health(engine)).lines_total == 60 and h)
        assert health.peer == _peer(phone)
    assert health.connections_closed == {"too many waiting": 1}
    assert _closed_by_server(silent[0].sock)
    for client in silent:
        client.close()


_PIECES = st.one_of(
    st.sampled_from([b"\n", b"\r\n", b"\t", b"1000\tACC\t0.0\t0.0\t9.81\n",
                     b"5\tORI\t0.5\t0.5\t0.5\t0.5\n", b"6\tORI\t0.9\t0.9\t0.9\n",
                     b"7\tACC\t1e160\t0\t0\n", b"8\tGPS\t58.4\t15.6\t80\n",
                     b"9\tFOO\t1\n", b"\xff\n", b"NaN", b"12345678901234567", b"\x00"]),
    st.builds(lambda t, tag, values: (f"{t}\t{tag}\t" + "\t".join(values) + "\n").encode(),
              st.integers(0, 10**13), st.sampled_from(["GYR", "ACC", "MAG", "ORI", "PRX"]),
              st.lists(st.floats(allow_nan=True, allow_infinity=True).map(java_float_text),
                       min_size=1, max_size=5)),
    st.binary(max_size=5))


@settings(max_examples=200, deadline=None)
@given(parts=st.lists(_PIECES, max_size=40), at_most=st.integers(1, 12),
       tight=st.booleans())
def test_the_rate_measure_counts_the_lines_the_parser_takes(parts, at_most, tight):
    """count_good_lines (what a connection's rate is made of) counts exactly the complete
    lines LineParser turns into samples, up to at_most."""
    data = b"".join(parts)
    limits = Limits(acc=10.0, gyr=1.0, mag=12.0, ori_tolerance=1e-7, floor=0.5) if tight \
        else Limits()
    samples = len(LineParser(limits=limits).feed(data))
    assert count_good_lines(data, limits, at_most, max_candidates=data.count(b"\n") + 1) \
        == min(at_most, samples)
