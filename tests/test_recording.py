"""Recording in the engine: through the real TCP server with the emulator (raw.txt byte for
byte), started and stopped by commands (also mid-stream), the recorded timeline and markers in
session.json, and determinism: replaying a recording gives exactly the estimates recorded."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pytest

from waiting import wait_until

from ekf.simulate import simulate
from app.cli import main
from app.engine.commands import (AddMarker, ReplayControl, SetEstimator, SetMarkerLabel,
                                 SetSensorEnabled, StartRecording, StopRecording)
from app.engine.offline.filtering import csv_lines
from app.engine.processing.runner import Rows
from app.engine.sessions.session import read_session, write_markers
from app.engine.live.worker import Engine
from app.stream.emulator import PhoneEmulator
from app.stream.protocol import Sample, format_line
from app.stream.recorder import FLUSH_INTERVAL_S, JSON_INTERVAL_S, Recorder
from app.stream.sources import LogFileSource, TcpSource


@pytest.fixture(scope="module")
def lines() -> list[bytes]:
    session = simulate(duration_s=24.0, rates_hz={"gyr": 100.0, "acc": 100.0, "mag": 50.0,
                                                  "ori": 100.0}, seed=11)
    return [(format_line(Sample(t, tag, values)) + "\n").encode()
            for t, tag, values in session.iter_rows()]


wait_for = wait_until


def send_in_pieces(phone: PhoneEmulator, lines: list[bytes], size: int = 613) -> None:
    for start in range(0, len(lines), size):           # chunks cut anywhere, lines too
        block = b"".join(lines[start:start + size])
        phone.send(block[:-5])
        phone.send(block[-5:])


def replayed_rows(folder: Path) -> list[str]:
    """Replay a recorded session (its timeline followed) as fast as possible: the estimate
    rows as estimates.csv lines."""
    engine = Engine(LogFileSource(folder / "raw.txt", speed=0), record_rows=True, index=False)
    with engine:
        wait_for(lambda: engine.snapshot_now().health.connection_state == "finished",
                 what="the replay's end")
    return csv_lines(Rows.concatenate(engine.rows_log))


def recorded_rows(folder: Path) -> list[str]:
    return (folder / "estimates.csv").read_text().splitlines()[1:]


def test_record_from_the_start_through_tcp_and_replay_gives_the_same_estimates(lines, tmp_path):
    folder = tmp_path / "rec"
    engine = Engine(TcpSource("127.0.0.1", 0), comparisons=True)
    with engine:
        engine.send(StartRecording(str(folder)))
        assert engine.wait_idle()
        with PhoneEmulator("127.0.0.1", engine.source.port) as phone:
            send_in_pieces(phone, lines[:3000])
            wait_for(lambda: engine.snapshot_now().health.lines_total >= 3000, what="lines")
            engine.send(SetSensorEnabled("mag", False))       # at whatever sample it lands
            engine.send(AddMarker("turn"))
            send_in_pieces(phone, lines[3000:5500])
            wait_for(lambda: engine.snapshot_now().health.lines_total >= 5500, what="lines")
            engine.send(SetEstimator("course"))
            engine.send(SetSensorEnabled("mag", True))
            send_in_pieces(phone, lines[5500:])
        wait_for(lambda: engine.snapshot_now().health.connection_state == "disconnected",
                 what="the disconnect")
        wait_for(lambda: engine.snapshot_now().health.lines_total == len(lines), what="lines")
        engine.send(SetMarkerLabel(1, "first turn"))
        engine.send(StopRecording())
        assert engine.wait_idle()
    assert (folder / "raw.txt").read_bytes() == b"".join(lines)         # byte for byte
    session = read_session(folder / "session.json")
    kinds = [e["kind"] for e in session.timeline]
    assert kinds.count("sensor") == 2 and "estimator" in kinds and "connected" in kinds
    assert [m.label for m in session.markers] == ["first turn"]
    assert session.start_state is None and session.estimator == "ekf"
    assert session.data["host"]["name"] and session.data["phone"].startswith("127.0.0.1:")
    assert session.data["calibration"]["g"] == 9.81 and session.data["stopped_utc"]
    positions = [e["sample"] for e in session.filter_events]
    assert positions == sorted(positions) and 0 < positions[0] < positions[-1]
    recorded = recorded_rows(folder)
    assert len(recorded) > 2000
    assert replayed_rows(folder) == recorded                             # bit for bit


def test_record_mid_stream_keeps_the_engine_state_and_replays_exactly(lines, tmp_path):
    folder = tmp_path / "mid"
    engine = Engine(TcpSource("127.0.0.1", 0), comparisons=True)
    first, toggle, stop = 3000, 5000, 7000                 # of 8400 lines
    with engine:
        with PhoneEmulator("127.0.0.1", engine.source.port) as phone:
            send_in_pieces(phone, lines[:first])
            wait_for(lambda: engine.snapshot_now().health.lines_total >= first, what="lines")
            engine.send(StartRecording(str(folder)))
            send_in_pieces(phone, lines[first:toggle])
            engine.send(SetSensorEnabled("acc", False))
            send_in_pieces(phone, lines[toggle:stop])
            wait_for(lambda: engine.snapshot_now().health.lines_total >= stop, what="lines")
            engine.send(StopRecording())
            assert engine.wait_idle()
            send_in_pieces(phone, lines[stop:])
        wait_for(lambda: engine.snapshot_now().recording["active"] is False, what="the stop")
    raw = (folder / "raw.txt").read_bytes()
    assert b"".join(lines).find(raw) > 0 and raw.endswith(b"\n")   # a stretch of the stream
    session = read_session(folder / "session.json")
    assert session.start_state is not None                         # the engine's state then
    recorded = recorded_rows(folder)
    replayed = replayed_rows(folder)
    assert len(recorded) > 1000
    # the replay also releases the samples held when the recording stopped: a few rows more
    assert replayed[:len(recorded)] == recorded and len(replayed) - len(recorded) < 100


def test_markers_added_while_replaying_a_session_are_saved_in_its_session_json(lines, tmp_path):
    folder = tmp_path / "rec"
    folder.mkdir()
    (folder / "raw.txt").write_bytes(b"".join(lines[:2000]))
    (folder / "session.json").write_text(json.dumps({"format": 2, "timeline": []}))
    engine = Engine(LogFileSource(folder / "raw.txt", speed=0, paused=True), index=False)
    with engine:
        assert engine.wait_idle()
        engine.send(AddMarker())
        engine.send(SetMarkerLabel(1, "start"))
        engine.send(AddMarker("second"))
        assert engine.wait_idle()
        assert [m.title for m in engine.snapshot_now().markers] == ["1: start", "2: second"]
    markers = read_session(folder / "session.json").markers
    assert [(m.id, m.label) for m in markers] == [(1, "start"), (2, "second")]
    assert not (folder / "session.json.tmp").exists()
    write_markers(folder / "session.json", markers[:1])               # round trip
    assert [m.label for m in read_session(folder / "session.json").markers] == ["start"]


def test_a_folder_that_cannot_be_made_is_one_message_and_the_stream_goes_on(lines, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    engine = Engine(LogFileSource(_write(tmp_path / "log.txt", lines[:800]), speed=0),
                    index=False)
    with engine:
        engine.send(StartRecording(str(blocker / "rec")))
        wait_for(lambda: engine.snapshot_now().health.connection_state == "finished",
                 what="the end")
        snapshot = engine.snapshot_now()
    assert any(w.startswith("cannot record") and str(blocker) in w
               for w in snapshot.health.warnings)
    assert snapshot.health.lines_total == 800
    assert snapshot.recording["active"] is False and str(blocker) in snapshot.recording["error"]


def _write(path: Path, lines: list[bytes]) -> Path:
    path.write_bytes(b"".join(lines))
    return path


def test_the_window_records_from_the_start_with_record_dir(lines, tmp_path):
    """`orientation-lab --replay LOG --record DIR`: a real window process (offscreen) records
    what it plays, verbatim."""
    import os
    import subprocess
    import sys
    log = _write(tmp_path / "log.txt", lines[:1500])
    folder = tmp_path / "rec"
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen", ORIENTATION_LAB_DATA=str(tmp_path))
    result = subprocess.run([sys.executable, "-m", "app", "--replay", str(log), "--speed", "0",
                             "--record", str(folder), "--port", "0", "--exit-after", "4"],
                            cwd=Path(__file__).resolve().parents[1], env=env,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert (folder / "raw.txt").read_bytes() == log.read_bytes()
    session = read_session(folder / "session.json")
    assert session.data["stopped_utc"] and session.start_state is None
    assert len(recorded_rows(folder)) > 400


def test_a_marker_added_in_a_recording_started_mid_stream_is_at_its_replayed_time(lines,
                                                                                  tmp_path):
    folder = tmp_path / "mid"
    engine = Engine(TcpSource("127.0.0.1", 0), comparisons=True)
    first, marked = 3000, 4200                                   # of 8400 lines
    with engine:
        with PhoneEmulator("127.0.0.1", engine.source.port) as phone:
            send_in_pieces(phone, lines[:first])
            wait_for(lambda: engine.snapshot_now().health.lines_total >= first, what="lines")
            engine.send(StartRecording(str(folder)))
            send_in_pieces(phone, lines[first:marked])
            wait_for(lambda: engine.snapshot_now().health.lines_total >= marked, what="lines")
            engine.send(AddMarker("here"))
            assert engine.wait_idle()
            live = engine.snapshot_now().markers[0]
            send_in_pieces(phone, lines[marked:6000])
            wait_for(lambda: engine.snapshot_now().health.lines_total >= 6000, what="lines")
            engine.send(StopRecording())
            assert engine.wait_idle()
    saved = read_session(folder / "session.json").markers[0]
    assert saved.t_ms == live.t_ms and saved.sample is not None
    # the live plots count from the stream's start, the session from the recording's
    stream_s = live.t_s
    assert 4200 / 350 - 1.5 < stream_s < 4200 / 350 + 1.5          # ~12 s into the stream
    replay = Engine(LogFileSource(folder / "raw.txt", speed=0, paused=True), index=False)
    with replay:
        replay.send(ReplayControl(paused=False))
        wait_for(lambda: replay.snapshot_now().health.connection_state == "finished",
                 what="the replay's end")
        t0_ms = replay.snapshot_now().t0_ms
        assert saved.t_s == pytest.approx((saved.t_ms - t0_ms) / 1000.0, abs=1e-9)
        assert 0.0 < saved.t_s < stream_s - 5.0                      # ~3.4 s into the session
        replay.send(AddMarker("in the replay"))
        assert replay.wait_idle()
    markers = read_session(folder / "session.json").markers
    assert [m.label for m in markers] == ["here", "in the replay"]
    assert markers[0].sample == saved.sample                         # kept on the rewrite
    exported = tmp_path / "from_marker.csv"
    assert main(["export", str(folder), "--format", "csv", "--from-marker", "1",
                 "-o", str(exported)]) == 0
    assert len(exported.read_text().splitlines()) > 100


def test_recording_a_replay_mid_way_with_a_switch_replays_exactly(lines, tmp_path):
    """A replay (the demo, a log) recorded mid-way: a sensor switched off and on applies from
    then on, as on a live stream (not to the whole replay), so the recording replays to the
    rows that were shown."""
    log = tmp_path / "log.txt"
    log.write_bytes(b"".join(lines))
    folder = tmp_path / "rec"
    engine = Engine(LogFileSource(log, speed=6.0), comparisons=True)
    with engine:
        wait_for(lambda: engine.snapshot_now().health.lines_total >= 2000, what="lines")
        engine.send(StartRecording(str(folder)))
        wait_for(lambda: engine.snapshot_now().health.lines_total >= 3500, what="lines")
        engine.send(SetSensorEnabled("gyr", False))
        wait_for(lambda: engine.snapshot_now().health.lines_total >= 4500, what="lines")
        engine.send(SetSensorEnabled("gyr", True))
        wait_for(lambda: engine.snapshot_now().health.lines_total >= 6500, what="lines")
        engine.send(StopRecording())
        assert engine.wait_idle()
    session = read_session(folder / "session.json")
    assert [e["kind"] for e in session.filter_events] == ["sensor", "sensor"]
    recorded = recorded_rows(folder)
    replayed = replayed_rows(folder)
    assert len(recorded) > 1500
    assert replayed[:len(recorded)] == recorded and len(replayed) - len(recorded) < 100


def test_raw_txt_and_session_json_are_written_on_the_recorders_clock(tmp_path):
    now = [50.0]
    recorder = Recorder(tmp_path, min_free_bytes=0, clock=lambda: now[0])
    line = b"1000\tACC\t0.1\t0.2\t9.8\n"
    recorder.write_line(line)
    recorder.add_event("marker", 1000)
    recorder.tick()
    raw, session = tmp_path / "raw.txt", tmp_path / "session.json"
    assert raw.read_bytes() == b"" and json.loads(session.read_text())["timeline"] == []
    now[0] = 50.0 + FLUSH_INTERVAL_S + 0.01
    recorder.tick()
    assert raw.read_bytes() == line                                   # flushed once due
    assert json.loads(session.read_text())["timeline"] == []          # not due yet
    now[0] = 50.0 + JSON_INTERVAL_S + 0.01
    recorder.tick()
    assert [e["kind"] for e in json.loads(session.read_text())["timeline"]] == ["marker"]
    assert recorder.elapsed_s == pytest.approx(JSON_INTERVAL_S + 0.01)
    recorder.close()


def _taken_port() -> socket.socket:
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen(1)
    return taken


@pytest.mark.parametrize("refusal", ["free space", "port in use"])
def test_serve_refused_at_its_start_leaves_no_session(tmp_path, capsys, refusal):
    """Was: `serve --record DIR` refused at its start (too little free space, the port in use)
    left a stub session (empty raw.txt, session.json, estimates.csv): the next recording went
    to DIR-2 and `filter DIR` said "empty file". Now nothing is made: one line, exit 2, and
    the next recording goes into DIR."""
    folder = tmp_path / "sessions" / "rec"
    taken = _taken_port()
    try:
        port = str(taken.getsockname()[1])
        extra = ["--record-min-free-mb", "1e9"] if refusal == "free space" else []
        if refusal == "free space":
            taken.close()
        capsys.readouterr()
        assert main(["serve", "--host", "127.0.0.1", "--port", port, "--quiet",
                     "--record", str(folder), *extra]) == 2
    finally:
        taken.close()
    error = capsys.readouterr().err.strip().splitlines()
    wanted = "less than" if refusal == "free space" else "cannot listen on"
    assert len(error) == 1 and wanted in error[0]
    assert list(tmp_path.iterdir()) == []
    assert main(["serve", "--host", "127.0.0.1", "--port", "0", "--quiet", "--exit-after", "0",
                 "--no-comparisons", "--record", str(folder)]) == 0
    assert "already holds" not in capsys.readouterr().err
    assert sorted(p.name for p in folder.iterdir()) == ["estimates.csv", "raw.txt",
                                                         "session.json"]


def test_a_recording_the_window_starts_without_free_space_leaves_no_folder(lines, tmp_path):
    engine = Engine(LogFileSource(_write(tmp_path / "log.txt", lines[:800]), speed=0),
                    index=False)
    folder = tmp_path / "new" / "rec"
    with engine:
        engine.send(StartRecording(str(folder), min_free_mb=1e9))
        wait_for(lambda: engine.snapshot_now().health.connection_state == "finished",
                 what="the end")
        snapshot = engine.snapshot_now()
    assert any(w.startswith("cannot record") and "less than" in w
               for w in snapshot.health.warnings)
    assert snapshot.recording["active"] is False and "less than" in snapshot.recording["error"]
    assert not (tmp_path / "new").exists()
