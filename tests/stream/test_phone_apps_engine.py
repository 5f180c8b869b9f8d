"""phyphox and Sensor Logger through the engine: everything downstream works unchanged (the same
estimates as `filter` on the log, the connection shown, the recording in the Sensor Fusion
format), --forward hands their streams on as Sensor Fusion lines, and the engine asks a source
what it can do, never its kind."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from phone_logs import by_tag, log_samples, simulated_lines
from test_forwarder import Receiver
from waiting import wait_for_snapshot, wait_until

from app.engine.offline.filtering import filter_log
from app.engine.live.worker import Engine
from app.stream.forwarder import LineForwarder
from app.stream.logfile import read_log
from app.stream.emulator import PhyphoxPhone, SensorLoggerPhone
from app.stream.phyphox import PhyphoxSource
from app.stream.protocol import parse_line
from app.stream.sensor_logger import SensorLoggerSource
from app.stream.sources import LIVE_PHONE, REPLAY, LogFileSource, SimulatorSource, TcpSource

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("phones") / "turns.txt"
    path.write_bytes(b"".join(simulated_lines(5.0, seed=8)))
    return path


@pytest.fixture
def receiver():
    server = Receiver()
    yield server
    server.close()


def _rows(engine: Engine) -> tuple[np.ndarray, np.ndarray]:
    rows = [r.select(r.has_sample) for r in engine.rows_log]
    return np.concatenate([r.t_ms for r in rows]), np.concatenate([r.quat for r in rows])


def _same_estimates(t_ms, quat, offline, exact: bool = True) -> None:
    """The live rows are `filter`'s rows; the last few may still wait in the orderer's window
    for samples that a live stream has not sent yet."""
    count = len(t_ms)
    assert len(offline) - 10 <= count <= len(offline)
    assert np.array_equal(t_ms, offline.t_ms[:count])
    if exact:
        assert np.array_equal(quat, offline.quat[:count])
    else:
        np.testing.assert_allclose(quat, offline.quat[:count], atol=1e-9)


def _stream(engine: Engine, count: int) -> None:
    wait_for_snapshot(engine, lambda s: s.health.lines_total >= count, 30, "every line")
    wait_until(lambda: engine.snapshot_now().health.lines_total >= count, 5)


def _forwarded(receiver: Receiver, count: int) -> list:
    wait_until(lambda: receiver.received and receiver.received[0].count(b"\n") >= count, 20,
               "the forwarded lines")
    return [parse_line(line.decode("ascii")) for line in bytes(receiver.received[0]).splitlines()]


def test_phyphox_through_the_engine(log, receiver):
    lines = log.read_bytes().splitlines(keepends=True)
    offline = filter_log(read_log(log), "ekf")
    forwarder = LineForwarder("127.0.0.1", receiver.port)
    with PhyphoxPhone(lines, speed=8.0, start_ms=0) as phone:     # the log's own times
        engine = Engine(PhyphoxSource(f"127.0.0.1:{phone.port}"), comparisons=False,
                        record_rows=True, forwarder=forwarder)
        with engine:
            wait_until(lambda: forwarder.status().state == "connected", 10)
            _stream(engine, len(lines))
            health = engine.snapshot_now().health
            forwarded = _forwarded(receiver, len(lines))
        t_ms, quat = _rows(engine)
    assert health.connection_state == "connected" and health.peer == f"127.0.0.1:{phone.port}"
    assert health.damaged == 0 and health.out_of_order == 0
    _same_estimates(t_ms, quat, offline)
    # the MATLAB kit would read the same samples, as Sensor Fusion lines
    assert by_tag(forwarded) == by_tag(log_samples(lines))


@pytest.mark.parametrize("platform", ["android", "ios"])
def test_sensor_logger_through_the_engine(log, receiver, platform):
    lines = log.read_bytes().splitlines(keepends=True)
    offline = filter_log(read_log(log), "ekf")
    forwarder = LineForwarder("127.0.0.1", receiver.port)
    source = SensorLoggerSource("127.0.0.1", 0)
    engine = Engine(source, comparisons=False, record_rows=True, forwarder=forwarder)
    with engine:
        wait_until(lambda: forwarder.status().state == "connected", 10)
        phone = SensorLoggerPhone(f"http://127.0.0.1:{source.port}/", period_s=0.2,
                                  platform=platform, time_offset_ms=0)
        phone.stream_lines(lines, speed=8.0)
        _stream(engine, len(lines))
        health = engine.snapshot_now().health
        forwarded = _forwarded(receiver, len(lines))
    t_ms, quat = _rows(engine)
    assert health.connection_state == "connected" and health.damaged == 0
    _same_estimates(t_ms, quat, offline, exact=platform == "android")
    if platform == "android":
        assert by_tag(forwarded) == by_tag(log_samples(lines))
    else:   # ACC is made of accelerometer + gravity: equal to rounding
        assert {tag: len(v) for tag, v in by_tag(forwarded).items()} == \
            {tag: len(v) for tag, v in by_tag(log_samples(lines)).items()}


def test_each_source_says_what_it_can_do(log):
    assert TcpSource().capabilities == LIVE_PHONE
    assert PhyphoxSource("127.0.0.1:1").capabilities == LIVE_PHONE
    assert SensorLoggerSource("127.0.0.1", 0).capabilities == LIVE_PHONE
    assert LogFileSource(log).capabilities == REPLAY
    assert SimulatorSource(duration_s=1.0).capabilities == REPLAY
    replay = LogFileSource(log)
    assert replay.played() is replay and PhyphoxSource("127.0.0.1:1").played() is None


def test_the_engine_never_asks_a_source_its_kind_or_class():
    """No `source.kind == ...` and no isinstance of a source class in the engine or the
    window: they ask the source's capabilities (and `played()` for the replay it plays)."""
    classes = {"Source", "TcpSource", "LineReplaySource", "LogFileSource", "SimulatorSource",
               "DemoOrPhoneSource", "PhyphoxSource", "SensorLoggerSource"}
    found = []
    for path in sorted((ROOT / "app").glob("engine/**/*.py")) + sorted((ROOT / "app").glob(
            "ui/*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Compare) and isinstance(node.left, ast.Attribute) \
                    and node.left.attr == "kind" and "source" in ast.unparse(node.left):
                found.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
            if isinstance(node, ast.Call) and ast.unparse(node.func) == "isinstance" \
                    and len(node.args) == 2 and any(name in classes for name in
                                                    ast.unparse(node.args[1]).replace(
                                                        "(", " ").replace(")", " ").replace(
                                                        ",", " ").split()):
                found.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
    assert found == []
