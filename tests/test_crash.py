"""Crash safety: a recording killed with SIGKILL (in a subprocess) holds every line received up
to at most 0.5 s before the kill, and the session opens for replay, a torn last line left out
and counted; SIGTERM and SIGHUP (the terminal closed) finish the recording of `serve` and of the
window's process (session.json with its stop time and counts)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from waiting import wait_for_snapshot, wait_until

from ekf.simulate import simulate
from app.engine.config import open_replay
from app.engine.live.worker import Engine
from app.stream.emulator import PhoneEmulator
from app.stream.protocol import Sample, format_line

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(sys.platform == "win32", reason="SIGKILL is POSIX")
def test_sigkill_while_recording_loses_at_most_half_a_second(tmp_path):
    session = simulate(duration_s=8.0, rates_hz={"gyr": 100.0, "acc": 100.0, "mag": 50.0,
                                                 "ori": 100.0}, seed=5)
    lines = [(format_line(Sample(t, tag, values)) + "\n").encode()
             for t, tag, values in session.iter_rows()]
    folder = tmp_path / "rec"
    env = dict(os.environ, ORIENTATION_LAB_DATA=str(tmp_path / "data"))
    process = subprocess.Popen(
        [sys.executable, "-m", "app", "serve", "--host", "127.0.0.1", "--port", "0",
         "--record", str(folder), "--quiet", "--no-comparisons"],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = int(re.search(r"port (\d+)", process.stdout.readline()).group(1))
        sent = 0
        marks: list[tuple[float, int]] = []          # (when, bytes sent by then)
        with PhoneEmulator("127.0.0.1", port) as phone:
            started = time.monotonic()
            for first in range(0, len(lines), 4):    # ~100 lines/s ... in 10 ms steps
                block = b"".join(lines[first:first + 4])
                phone.send(block)
                sent += len(block)
                marks.append((time.monotonic(), sent))
                time.sleep(0.01)                     # the phone's pace: the behaviour under test
                if time.monotonic() - started > 3.0:
                    break
            killed_at = time.monotonic()
            os.kill(process.pid, signal.SIGKILL)
            process.wait(timeout=10)
    finally:
        if process.poll() is None:
            process.kill()
        process.communicate(timeout=10)
    assert process.returncode == -signal.SIGKILL
    data = b"".join(lines)
    raw = (folder / "raw.txt").read_bytes()
    due = max(count for when, count in marks if when <= killed_at - 0.5)
    assert data.startswith(raw) and len(raw) >= due        # nothing older than 0.5 s lost
    assert (folder / "session.json").is_file()
    # it opens for replay; a torn last line is left out and counted
    torn = 0 if raw.endswith(b"\n") else 1
    source = open_replay(folder, speed=0)
    assert source.torn_lines == torn and source.line_count == raw.count(b"\n")
    with Engine(source, comparisons=False, index=False) as engine:
        health = wait_for_snapshot(engine, lambda s: s.health.connection_state == "finished",
                                   20, "the replay to finish").health
    assert health.connection_state == "finished" and health.damaged == torn
    assert health.lines_total == raw.count(b"\n") + torn


def test_a_torn_last_line_of_a_recording_is_left_out_and_counted(tmp_path):
    folder = tmp_path / "rec"
    folder.mkdir()
    (folder / "session.json").write_text("{}")
    (folder / "raw.txt").write_bytes(b"1000\tACC\t0.1\t0.2\t9.8\n1010\tACC\t0.1\t0.2\t9.")
    source = open_replay(folder)
    assert source.line_count == 1 and source.torn_lines == 1
    # a phone's own log may end without a newline: its last line counts
    log = tmp_path / "sensorLog.txt"
    log.write_bytes(b"1000\tACC\t0.1\t0.2\t9.8\n1010\tACC\t0.1\t0.2\t9.8")
    assert open_replay(log).line_count == 2


def _phone_lines(seconds: float, seed: int = 5) -> list[bytes]:
    session = simulate(duration_s=seconds, rates_hz={"gyr": 100.0, "acc": 100.0, "mag": 50.0,
                                                     "ori": 100.0}, seed=seed)
    return [(format_line(Sample(t, tag, values)) + "\n").encode()
            for t, tag, values in session.iter_rows()]


def _finished(folder: Path) -> dict:
    """session.json of a finished recording, checked against its raw.txt."""
    session = json.loads((folder / "session.json").read_text())
    raw = (folder / "raw.txt").read_bytes()
    assert session["stopped_utc"] is not None
    assert (session["raw_lines"], session["raw_bytes"]) == (raw.count(b"\n"), len(raw))
    assert not (folder / "session.json.tmp").exists()
    return session


@pytest.mark.skipif(not hasattr(signal, "SIGHUP"), reason="SIGHUP is POSIX")
@pytest.mark.parametrize("name", ["SIGHUP", "SIGTERM"])
def test_sighup_and_sigterm_finish_the_recording_of_serve(tmp_path, name):
    """Was: SIGHUP (closing the terminal) ended serve as SIGKILL does: session.json never
    finalised. Now it stops serve like SIGTERM: exit 0, every received line in raw.txt,
    session.json with its stop time and counts, estimates.csv to the last sample."""
    lines = _phone_lines(4.0)
    data = b"".join(lines)
    folder = tmp_path / "rec"
    env = dict(os.environ, ORIENTATION_LAB_DATA=str(tmp_path / "data"))
    process = subprocess.Popen(
        [sys.executable, "-m", "app", "serve", "--host", "127.0.0.1", "--port", "0",
         "--record", str(folder), "--quiet", "--no-comparisons"],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = int(re.search(r"port (\d+)", process.stdout.readline()).group(1))
        with PhoneEmulator("127.0.0.1", port) as phone:
            phone.send(data)
            raw = folder / "raw.txt"
            wait_until(lambda: raw.stat().st_size == len(data), what="raw.txt to hold the lines")
            process.send_signal(getattr(signal, name))
            process.wait(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
        out, err = process.communicate(timeout=10)
    assert process.returncode == 0, err
    assert "Traceback" not in err and out.splitlines()[-1].startswith("final: ")
    assert (folder / "raw.txt").read_bytes() == data
    session = _finished(folder)
    assert session["raw_lines"] == len(lines)
    rows = (folder / "estimates.csv").read_text().splitlines()[1:]
    last_t = max(int(line.split(b"\t")[0]) for line in lines)
    assert rows and int(float(rows[-1].split(",")[0])) == last_t


@pytest.mark.skipif(not hasattr(signal, "SIGHUP"), reason="SIGHUP is POSIX")
def test_sighup_finishes_the_recording_of_the_window(tmp_path):
    """The window's process (offscreen, `--replay LOG --record DIR`): SIGHUP closes the window
    as Ctrl-C does; the recording it made is finished."""
    lines = _phone_lines(30.0)
    log = tmp_path / "log.txt"
    log.write_bytes(b"".join(lines))
    folder = tmp_path / "rec"
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen", ORIENTATION_LAB_DATA=str(tmp_path))
    process = subprocess.Popen(
        [sys.executable, "-m", "app", "--replay", str(log), "--record", str(folder),
         "--port", "0"], cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True)
    try:
        raw = folder / "raw.txt"
        wait_until(lambda: raw.exists() and raw.stat().st_size > 0, 60,
                   "the window to record")
        process.send_signal(signal.SIGHUP)
        process.wait(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
        _, err = process.communicate(timeout=10)
    assert process.returncode == 0, err
    recorded = (folder / "raw.txt").read_bytes()
    assert log.read_bytes().startswith(recorded) and recorded.endswith(b"\n")
    _finished(folder)
