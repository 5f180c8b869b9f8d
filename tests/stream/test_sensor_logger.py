"""Sensor Logger's HTTP Push: the endpoint (SensorLoggerSource) against the phone emulator on
loopback and against hostile requests, and the documented conversions
(awesome-sensor-logger PUSHING.md, UNITS.md, COORDINATES.md, CROSSPLATFORM.md)."""

from __future__ import annotations

import http.client
import json
import math
import socket
from http.server import BaseHTTPRequestHandler

import numpy as np
import pytest

from ekf import quaternion as quat
from phone_logs import Collected, by_tag, log_samples, simulated_lines
from waiting import wait_until

from app.stream.phone_apps import ENU_FROM_NWU
from app.stream.sensor_logger import PushServer, SensorLoggerConverter, SensorLoggerSource
from app.stream.emulator import SensorLoggerPhone

#: The push documented in PUSHING.md, with values filled in.
DOC_PUSH = {"messageId": 0, "sessionId": "identifier", "deviceId": "identifier",
            "payload": [{"name": "accelerometer", "time": 1698501144401773000,
                         "values": {"x": 0.1, "y": 0.2, "z": 0.3}},
                        {"name": "location", "time": 1698501145514000000,
                         "values": {"latitude": 58.4, "longitude": 15.6}}]}


@pytest.fixture(scope="module")
def lines() -> list[bytes]:
    return simulated_lines(3.0, seed=5)


@pytest.fixture
def source():
    running = SensorLoggerSource("127.0.0.1", 0, takeover_after_s=3.0)
    running.start()
    yield running
    running.stop()


def _post(port: int, body: bytes, path: str = "/data", headers: dict | None = None):
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        connection.request("POST", path, body=body,
                           headers={"Content-Type": "application/json", **(headers or {})})
        reply = connection.getresponse()
        return reply.status, reply.read().decode()
    finally:
        connection.close()


def _drain(source: SensorLoggerSource, got: Collected) -> Collected:
    got.take(source.read(0.0))
    return got


def _samples(source, phone, lines) -> Collected:
    got = Collected()
    phone.stream_lines(lines, speed=0)
    wanted = sum(line.split(b"\t")[1] in (b"ACC", b"GYR", b"MAG", b"ORI") for line in lines)
    wait_until(lambda: _drain(source, got).line_count() >= wanted, 20, "every sample")
    return got


def _close(a: dict, b: dict, tolerance: float = 1e-12) -> None:
    assert a.keys() == b.keys()
    for tag in a:
        assert [t for t, _ in a[tag]] == [t for t, _ in b[tag]], tag
        np.testing.assert_allclose(np.array([v for _, v in a[tag]]),
                                   np.array([v for _, v in b[tag]]), atol=tolerance,
                                   err_msg=tag)


# ---- the documented conversions ----------------------------------------------------------------

def test_documented_push_time_and_names():
    """PUSHING.md's example: time in UTC epoch ns -> ms; location is not used (counted)."""
    converter = SensorLoggerConverter("standardised")
    samples = converter.convert(DOC_PUSH["payload"] + [
        {"name": "gravity", "time": 1698501144401773000, "values": {"x": 0, "y": 0, "z": 9.8}}])
    assert [(s.t_ms, s.tag) for s in samples] == [(1698501144401, "ACC")]
    assert samples[0].values == pytest.approx((0.1, 0.2, 10.1))
    assert converter.ignored == {"location": 1}


def test_ios_flat_screen_up_gives_gravity_up():
    """COORDINATES.md: flat on a table, gravity points -z on iOS (+z on Android); iOS's
    orientation is in x-north-z-vertical. A flat iPhone with x north: its quaternion is the
    identity; ours points x north in East-North-Up, and ACC is +g on z."""
    converter = SensorLoggerConverter("auto")
    t = 1_700_000_000_000_000_000
    batch = [{"name": "accelerometer", "time": t, "values": {"x": 0.0, "y": 0.0, "z": 0.0}},
             {"name": "gravity", "time": t, "values": {"x": 0.0, "y": 0.0, "z": -9.80665}},
             {"name": "orientation", "time": t,
              "values": {"qw": 1.0, "qx": 0.0, "qy": 0.0, "qz": 0.0, "roll": 0.0,
                         "pitch": 0.0, "yaw": 0.0}}]
    samples = {s.tag: s.values for s in converter.convert(batch)}
    assert samples["ACC"] == pytest.approx((0.0, 0.0, 9.80665))
    assert converter.decision.startswith("not-standardised")
    q = np.array(samples["ORI"])
    np.testing.assert_allclose(quat.rotate(q, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(q, ENU_FROM_NWU)


def test_standardised_ios_is_taken_as_android():
    converter = SensorLoggerConverter("auto")
    t = 1_700_000_000_000_000_000
    q = quat.from_axis_angle([1.0, 0.0, 0.0], 0.6)        # tilted: up is not z in the device
    up = quat.to_matrix(q)[2, :] * 9.80665
    batch = [{"name": "accelerometer", "time": t, "values": dict(zip("xyz", (0.5, 0.0, 0.0)))},
             {"name": "gravity", "time": t, "values": dict(zip("xyz", up))},
             {"name": "orientation", "time": t,
              "values": {"qw": q[0], "qx": q[1], "qy": q[2], "qz": q[3]}}]
    samples = {s.tag: s.values for s in converter.convert(batch)}
    assert converter.decision.startswith("standardised")
    assert samples["ACC"] == pytest.approx(tuple(up + [0.5, 0.0, 0.0]))
    assert samples["ORI"] == pytest.approx(tuple(q))


def test_accelerometer_without_gravity_is_said():
    converter = SensorLoggerConverter("not-standardised")
    converter.convert([{"name": "accelerometer", "time": 10**18, "values": {"x": 0, "y": 0,
                                                                          "z": 0}}])
    assert converter.without_gravity == 1 and "Gravity" in converter.problems[0]


# ---- end to end through the emulator --------------------------------------------------------------

@pytest.mark.parametrize("platform, standardised", [("android", False), ("ios", False),
                                                    ("ios", True)])
def test_every_sample_arrives(source, lines, platform, standardised):
    """Android (totalacceleration) and iOS (accelerometer without gravity + gravity, frames
    standardised or not): the same samples as the log; Android's exactly."""
    phone = SensorLoggerPhone(f"http://127.0.0.1:{source.port}/", period_s=0.5,
                              platform=platform, standardised=standardised, time_offset_ms=0)
    got = _samples(source, phone, lines)
    expected = by_tag(log_samples(lines))
    received = by_tag(got.samples())
    if platform == "android":
        assert received == expected
    else:
        _close(received, expected)
    info = source.info()["sensor_logger"]
    assert info["counts"]["batches"] == phone.message_id and phone.statuses == {200:
                                                                                 phone.message_id}
    assert got.kinds()[:2] == ["listening", "connected"]
    if platform == "ios":
        assert info["frames"].startswith("standardised" if standardised else "not-standardised")


def test_frames_set_by_hand(lines):
    phone = SensorLoggerPhone("http://127.0.0.1:1/", platform="ios", standardised=False,
                              time_offset_ms=0)
    entries, _ = phone.entries(lines)
    payload = [entry for group in entries for entry in group]
    converted = by_tag(SensorLoggerConverter("not-standardised").convert(payload))
    _close({tag: converted[tag] for tag in ("ACC", "ORI")},
           {tag: by_tag(log_samples(lines))[tag] for tag in ("ACC", "ORI")})
    wrong = by_tag(SensorLoggerConverter("standardised").convert(payload))
    assert wrong["ACC"][0][1][2] < 0                   # believed: gravity points down


def test_bad_requests_are_answered_and_counted(source, lines):
    port = source.port
    assert _post(port, b"{not json")[0] == 400
    assert _post(port, b'{"payload": 3}')[0] == 400
    assert _post(port, b"[1, 2]")[0] == 400
    status, text = _post(port, b"x" * (9 << 20))
    assert status == 413 and "MiB" in text
    with socket.create_connection(("127.0.0.1", port), timeout=5) as raw:
        raw.sendall(b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 99999999999\r\n\r\n")
        assert raw.recv(100).startswith(b"HTTP/1.1 413")
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    connection.request("GET", "/")
    reply = connection.getresponse()
    assert reply.status == 200 and b"Sensor Logger" in reply.read()
    connection.close()
    unknown = dict(DOC_PUSH, payload=[{"name": "tricorder", "time": 1, "values": {"x": 1}},
                                      {"name": "gyroscope", "time": 2, "values": {"x": None,
                                                                                 "y": 0, "z": 0}},
                                      {"nothing": True}])
    assert _post(port, json.dumps(unknown).encode())[0] == 200
    info = source.info()["sensor_logger"]
    assert info["counts"]["bad JSON"] == 1 and info["counts"]["not a push"] == 2
    assert info["counts"]["too large"] == 2
    assert info["unknown_sensors"] == {"tricorder": 1}
    assert info["null_values"] == 1 and info["malformed_entries"] == 1
    # and the endpoint still takes the phone (the same device, a new recording)
    phone = SensorLoggerPhone(f"http://127.0.0.1:{port}/", period_s=0.5, time_offset_ms=0,
                              device_id="identifier")
    got = _samples(source, phone, lines)
    assert by_tag(got.samples()) == by_tag(log_samples(lines))


def test_chunked_body_is_taken(source):
    body = json.dumps(dict(DOC_PUSH, payload=[{"name": "gyroscope", "time": 10**18,
                                               "values": {"x": 0.1, "y": 0, "z": 0}}])).encode()
    chunked = b"%x\r\n%s\r\n0\r\n\r\n" % (len(body), body)
    with socket.create_connection(("127.0.0.1", source.port), timeout=5) as raw:
        raw.sendall(b"POST /data HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n"
                    + chunked)
        assert raw.recv(100).startswith(b"HTTP/1.1 200")
    got = Collected()
    wait_until(lambda: _drain(source, got).line_count() == 1, 10, "the sample")
    assert got.samples()[0].tag == "GYR"


def test_a_second_device_is_refused_while_the_first_streams(source, lines):
    first = SensorLoggerPhone(f"http://127.0.0.1:{source.port}/", device_id="first",
                              time_offset_ms=0)
    second = SensorLoggerPhone(f"http://127.0.0.1:{source.port}/", device_id="second",
                               time_offset_ms=5000)
    first_entries, _ = first.entries(lines[:200])
    second_entries, _ = second.entries(lines[:200])
    body = json.dumps(first.message([e for g in first_entries for e in g])).encode()
    assert first.post(body)[0] == 200
    status, text = second.post(json.dumps(second.message([e for g in second_entries
                                                          for e in g])).encode())
    assert status == 499 and "another phone" in text
    assert second.messages_shown == [text.strip()]
    assert first.post(body)[0] == 200
    info = source.info()
    assert info["sensor_logger"]["counts"]["second device"] == 1
    assert info["sensor_logger"]["device"] == "first"
    got = _drain(source, Collected())
    assert got.kinds().count("connected") == 1 and "closed" in got.kinds()


def test_a_second_device_takes_over_a_silent_one(lines):
    clock = [0.0]
    source = SensorLoggerSource("127.0.0.1", 0, takeover_after_s=3.0)
    source.endpoint.clock = lambda: clock[0]
    source.start()
    try:
        first = SensorLoggerPhone(f"http://127.0.0.1:{source.port}/", device_id="first")
        second = SensorLoggerPhone(f"http://127.0.0.1:{source.port}/", device_id="second")
        assert first.post(json.dumps(first.message([])).encode())[0] == 200
        clock[0] = 3.5
        assert second.post(json.dumps(second.message([])).encode())[0] == 200
        got = _drain(source, Collected())
    finally:
        source.stop()
    assert got.kinds().count("connected") == 2
    assert "took over" in got.details("connected")[1]
    assert source.info()["sensor_logger"]["device"] == "second"


def test_silence_is_a_disconnect_and_a_new_recording_a_new_stream(lines):
    source = SensorLoggerSource("127.0.0.1", 0, idle_after_s=0.3)
    source.start()
    got = Collected()
    try:
        phone = SensorLoggerPhone(f"http://127.0.0.1:{source.port}/", session_id="one")
        assert phone.post(json.dumps(phone.message([])).encode())[0] == 200
        wait_until(lambda: "disconnected" in _drain(source, got).kinds(), 10, "the silence")
        phone.session_id = "two"
        assert phone.post(json.dumps(phone.message([])).encode())[0] == 200
        wait_until(lambda: _drain(source, got).kinds().count("connected") == 2, 10, "two")
    finally:
        source.stop()
    assert "stopped pushing" in got.details("disconnected")[0]
    assert "new recording" in got.details("connected")[1]


def test_urls_to_type(source):
    assert source.urls()[0] == f"http://127.0.0.1:{source.port}/"
    assert math.isfinite(source.port)


@pytest.mark.parametrize("error, counted", [(ConnectionResetError(104, "reset by peer"),
                                             "closed early"),
                                            (BrokenPipeError(32, "broken pipe"), "closed early"),
                                            (ValueError("a handler's bug"), "failed requests")])
def test_a_request_that_fails_is_counted_not_printed(source, capsys, error, counted):
    """A client gone before its answer (or any request that fails) prints no traceback on the
    user's terminal: it is counted, and the endpoint goes on taking the phone's batches."""
    server = PushServer(("127.0.0.1", 0), BaseHTTPRequestHandler, source.endpoint, 4)
    try:
        raise error
    except type(error):
        server.handle_error(None, ("127.0.0.1", 1))
    finally:
        server.server_close()
    assert capsys.readouterr().err == ""
    assert source.endpoint.counts[counted] == 1
