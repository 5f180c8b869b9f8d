"""phyphox's remote interface: the client (PhyphoxSource) against the phone emulator on
loopback, with the documented edge cases (phyphox-docs docs/remote-interface/openapi.yaml):
thresholds with a percent-encoded `|`, null values, a changed session, a stopped or cleared
measurement, an experiment without the needed buffers, a phone that goes away."""

from __future__ import annotations

import json
import urllib.parse
import urllib.request

import pytest

from phone_logs import Collected, by_tag, log_samples, simulated_lines
from waiting import wait_until

from app.stream.phyphox import (PhyphoxSensor, PhyphoxSource, get_query, parse_address,
                                read_config, sensor_batch)
from app.stream.emulator import PhyphoxPhone
from app.stream.phyphox_experiment import SENSORS, experiment_xml

ACC_ONLY = """<phyphox version="1.14" locale="en">
<title>Acceleration with g</title>
<category>Raw Sensors</category>
<data-containers>
<container size="0">accX</container><container size="0">accY</container>
<container size="0">accZ</container><container size="0">acc_time</container>
</data-containers>
<input><sensor type="accelerometer">
<output component="x">accX</output><output component="y">accY</output>
<output component="z">accZ</output><output component="t">acc_time</output>
</sensor></input>
<views><view label="Graph"><info label="acc"/></view></views>
</phyphox>
"""


@pytest.fixture(scope="module")
def lines() -> list[bytes]:
    return simulated_lines(4.0)


def _source(phone: PhyphoxPhone, **options) -> PhyphoxSource:
    options.setdefault("retry_max_s", 0.2)
    source = PhyphoxSource(f"http://127.0.0.1:{phone.port}", timeout_s=2.0, **options)
    source.start()
    return source


def _collect_until(source: PhyphoxSource, got: Collected, condition, what: str,
                   timeout: float = 20.0) -> None:
    def done():
        got.take(source.read(0.02))
        return condition()
    wait_until(done, timeout, what)


def _all_of(lines: list[bytes], got: Collected, phone: PhyphoxPhone, less: int = 0):
    """A condition: the log served to its end and its samples (less some) handed over."""
    return lambda: phone.served_to_end and got.line_count() >= len(lines) - less


def _same_samples(got: Collected, lines: list[bytes], offset_ms: int) -> None:
    expected = by_tag(log_samples(lines))
    received = by_tag(got.samples(), -offset_ms)
    assert received.keys() == expected.keys()
    for tag in expected:
        assert received[tag] == expected[tag], tag


# ---- the pieces ---------------------------------------------------------------------------------

def test_address_forms():
    assert parse_address("http://192.168.1.5:8080").url == "http://192.168.1.5:8080"
    assert parse_address("192.168.1.5:8081").port == 8081
    assert parse_address("192.168.1.5").port == 80          # iOS's default port
    for bad in ("", "https://192.168.1.5", "http://:80", "http://x:99999"):
        with pytest.raises(ValueError):
            parse_address(bad)


def test_query_percent_encodes_the_threshold_bar():
    """The docs' incremental example {t: "3", accX: "3|t"}: the `|` goes out as %7C."""
    sensor = PhyphoxSensor("accelerometer", "ACC", ("t", "accX"))
    query = get_query((sensor,), {"accelerometer": 3.0})
    assert query == "/get?t=3.0&accX=3.0%7Ct"
    assert "|" not in query
    assert dict(urllib.parse.parse_qsl(query.split("?")[1])) == {"t": "3.0", "accX": "3.0|t"}
    assert get_query((sensor,), {"accelerometer": None}) == "/get?t=full&accX=full"


def test_config_names_what_is_missing():
    config = read_config({"title": "Acceleration with g", "localTitle": "Acceleration with g",
                          "inputs": [{"source": "accelerometer",
                                      "outputs": [{"x": "accX"}, {"y": "accY"}, {"z": "accZ"},
                                                  {"t": "acc_time"}]},
                                     {"source": "gyroscope", "outputs": [{"x": "gx"}]}]})
    assert [s.buffers for s in config.sensors] == [("acc_time", "accX", "accY", "accZ")]
    assert config.missing == ("magnetometer", "attitude (the phone's orientation)",
                              "gyroscope t, y, z")


def test_nulls_and_uneven_buffers():
    """null (NaN on the phone) is skipped and counted; buffers read up to the shortest."""
    sensor = PhyphoxSensor("gyroscope", "GYR", ("t", "x", "y", "z"))
    reply = {"t": {"buffer": [0.01, 0.02, None, 0.04, 0.05]},
             "x": {"buffer": [1.0, None, 1.0, 1.0, 1.0]},
             "y": {"buffer": [0.0, 0.0, 0.0, 0.0]},
             "z": {"buffer": [0.5, 0.5, 0.5, 0.5, 0.5]}}
    batch = sensor_batch(sensor, reply)
    assert [(s.t_ms, s.values) for s in batch.samples] == [(10, (1.0, 0.0, 0.5)),
                                                           (40, (1.0, 0.0, 0.5))]
    assert batch.nulls == 2 and batch.last_time == 0.04 and not batch.missing
    assert sensor_batch(sensor, {"t": {"buffer": []}}).missing


def test_emulator_answers_the_get_forms_of_the_docs(lines):
    """/get?abc&def=full&ghi=42&jkl=23|mno, on the emulator's buffers: the last value, the
    whole buffer, what follows a threshold, a threshold on another buffer; an unknown buffer is
    skipped, a threshold that is no number is a 400."""
    with PhyphoxPhone(lines, speed=0, measuring=True) as phone:
        base = f"http://127.0.0.1:{phone.port}/get?"

        def get(query):
            with urllib.request.urlopen(base + query, timeout=5) as reply:
                return json.loads(reply.read())

        whole = get("acc_time=full&accX=full")["buffer"]
        times = whole["acc_time"]["buffer"]
        assert whole["acc_time"]["updateMode"] == "full" and len(times) > 100
        last = get("accX=")["buffer"]["accX"]
        assert last["updateMode"] == "single" and last["buffer"] == whole["accX"]["buffer"][-1:]
        threshold = times[49]
        after = get(f"acc_time={threshold}&accX={threshold}%7Cacc_time&nothing=full")
        assert "nothing" not in after["buffer"]
        assert after["buffer"]["acc_time"]["buffer"] == times[50:]
        assert after["buffer"]["accX"]["buffer"] == whole["accX"]["buffer"][50:]
        assert after["status"]["measuring"] is True and after["status"]["session"]
        with pytest.raises(urllib.error.HTTPError) as error:
            get("accX=abc")
        assert error.value.code == 400


# ---- end to end on loopback ---------------------------------------------------------------------

def test_every_sample_arrives_one_request_at_a_time(lines):
    """The source starts the measurement, takes every sample in its time order, and never has
    two requests open at once (the phone's server is single-threaded)."""
    phone = PhyphoxPhone(lines, speed=4.0).start()
    source = _source(phone)
    got = Collected()
    try:
        _collect_until(source, got, _all_of(lines, got, phone), "the whole log")
    finally:
        source.stop()
        phone.stop()
    assert got.kinds()[0] == "connected"
    assert phone.requests_by_path["/control"] == 1 and phone.measuring
    _same_samples(got, lines, phone.t0_ms)
    info = source.info()["phyphox"]
    assert info["requests_in_flight_max"] == 1 and phone.overlapping_requests == 0
    assert info["null_values"] == 0 and info["missing"] == []


def test_null_values_are_skipped_and_counted(lines):
    phone = PhyphoxPhone(lines, speed=0, measuring=True,
                         nan_samples={"GYR": {5, 6}, "MAG": {0}}).start()
    source = _source(phone)
    got = Collected()
    try:
        _collect_until(source, got, _all_of(lines, got, phone, less=3), "the whole log")
    finally:
        source.stop()
        phone.stop()
    expected = by_tag(log_samples(lines))
    received = by_tag(got.samples(), -phone.t0_ms)
    assert received["GYR"] == expected["GYR"][:5] + expected["GYR"][7:]
    assert received["MAG"] == expected["MAG"][1:]
    assert received["ACC"] == expected["ACC"]
    assert source.info()["phyphox"]["null_values"] == 3


def test_missing_buffers_are_one_line_and_the_rest_streams(lines):
    phone = PhyphoxPhone(lines, speed=0, measuring=True, xml=ACC_ONLY).start()
    source = _source(phone)
    got = Collected()
    try:
        acc = sum(b"\tACC\t" in line for line in lines)
        _collect_until(source, got, lambda: got.line_count() >= acc, "the accelerometer")
    finally:
        source.stop()
        phone.stop()
    problems = got.details("error")
    assert len(problems) == 1
    assert problems[0].startswith('the phyphox experiment "Acceleration with g" has no '
                                  "gyroscope, magnetometer, attitude")
    assert "QR code" in problems[0] and "\n" not in problems[0]
    assert set(by_tag(got.samples())) == {"ACC"}
    assert source.info()["phyphox"]["missing"] == ["gyroscope", "magnetometer",
                                                   "attitude (the phone's orientation)"]


def test_a_changed_session_starts_afresh(lines):
    """The user loads another experiment: a new connection, its data from its own start."""
    phone = PhyphoxPhone(lines, speed=2.0).start()
    source = _source(phone)
    got = Collected()
    try:
        _collect_until(source, got, lambda: len(got.samples()) > 200, "some samples")
        phone.switch_session()
        _collect_until(source, got, lambda: got.kinds().count("connected") == 2,
                       "the new session")
        before = len(got.data)
        _collect_until(source, got, lambda: len(got.data) > before + 2, "the new session's data")
    finally:
        source.stop()
        phone.stop()
    assert "session" in got.details("connected")[1]
    assert got.connections[-1] == 2
    first_new = next(s for s, c in zip(got.data, got.connections) if c == 2)
    assert first_new.startswith(b"0\t") or int(first_new.split(b"\t")[0]) < 1000
    assert source.info()["phyphox"]["sessions"] == 2


def test_a_stopped_measurement_is_said_and_nothing_is_lost(lines):
    phone = PhyphoxPhone(lines, speed=3.0).start()
    source = _source(phone)
    got = Collected()
    try:
        _collect_until(source, got, lambda: len(got.samples()) > 100, "some samples")
        phone.stop_measurement()
        _collect_until(source, got, lambda: any("stopped on the phone" in d
                                                for d in got.details("error")), "the notice")
        assert source.info()["phyphox"]["measuring"] is False
        phone.start_measurement()
        _collect_until(source, got, _all_of(lines, got, phone), "the rest of the log")
    finally:
        source.stop()
        phone.stop()
    assert got.kinds().count("connected") == 1          # the same stream goes on
    _same_samples(got, lines, phone.t0_ms)


def test_a_phone_that_goes_away_loses_nothing_it_held(lines):
    phone = PhyphoxPhone(lines, speed=2.0).start()
    source = _source(phone)
    got = Collected()
    try:
        _collect_until(source, got, lambda: len(got.samples()) > 100, "some samples")
        phone.vanish(1.0)
        _collect_until(source, got, lambda: "disconnected" in got.kinds(), "the notice")
        assert source.info()["connection_state"] == "disconnected"
        _collect_until(source, got, _all_of(lines, got, phone), "the rest of the log")
    finally:
        source.stop()
        phone.stop()
    assert got.kinds().count("connected") == 2
    assert "answers again" in got.details("connected")[1]
    assert "not answering" in got.details("disconnected")[0]
    _same_samples(got, lines, phone.t0_ms)


def test_cleared_data_starts_a_new_stream(lines):
    """Cleared on the phone and started again: its time restarts at 0, which the source
    notices (nothing newer than its threshold while measuring) and starts afresh."""
    phone = PhyphoxPhone(lines, speed=2.0).start()
    source = _source(phone, stall_s=0.3)
    got = Collected()
    try:
        _collect_until(source, got, lambda: len(got.samples()) > 300, "some samples")
        phone.clear()
        phone.start_measurement()
        _collect_until(source, got, lambda: got.kinds().count("connected") == 2, "the restart")
    finally:
        source.stop()
        phone.stop()
    assert "cleared" in got.details("connected")[1]
    assert source.info()["phyphox"]["clears"] == 1


def test_no_phone_is_said_and_waited_for():
    source = PhyphoxSource("http://127.0.0.1:9", timeout_s=0.5, retry_max_s=0.2)
    source.start()
    got = Collected()
    try:
        _collect_until(source, got, lambda: got.details("error"), "the notice", timeout=10)
    finally:
        source.stop()
    assert "no answer from phyphox at http://127.0.0.1:9" in got.details("error")[0]
    assert source.info()["connection_state"] == "waiting"


def test_experiment_matches_what_the_source_reads():
    """Our experiment's /config gives the source all four sensors, nothing missing."""
    phone = PhyphoxPhone([], xml=experiment_xml())
    config = read_config(phone.config())
    assert [s.tag for s in config.sensors] == [s.tag for s in SENSORS] == ["ACC", "GYR", "MAG",
                                                                        "ORI"]
    assert config.missing == ()
