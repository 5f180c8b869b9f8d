"""`send` and `serve` end to end: a log through the socket is recorded verbatim."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from line_helpers import parses as _parses
from waiting import wait_for_port

from app.cli import main

ROOT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


_wait_port = wait_for_port


def _serve_and_send(log: Path, record: Path, *extra: str) -> tuple[str, str]:
    port = _free_port()
    server = subprocess.Popen(
        [sys.executable, "-m", "app", "serve", "--host", "127.0.0.1", "--port", str(port),
         "--record", str(record), "--exit-when-idle", "1", "--no-comparisons", *extra],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_port(port)     # a probe that sends nothing: the idle timer waits for `send`
        result = subprocess.run(
            [sys.executable, "-m", "app", "send", str(log), "--port", str(port), "--speed", "0"],
            cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert result.returncode == 0, result.stderr
        out, err = server.communicate(timeout=60)
    finally:
        if server.poll() is None:
            server.kill()
            server.communicate()
    assert server.returncode == 0, err
    assert "Traceback" not in err
    return out, err


def test_send_to_serve_records_the_lines_that_parse_verbatim(tmp_path, realphone_dir):
    log = realphone_dir / "sensorLog_20221024T182616_standstill.txt"
    record = tmp_path / "session"
    out, _ = _serve_and_send(log, record)
    assert "final: disconnected" in out and "9339 lines" in out
    assert "2 damaged (2 value count)" in out
    lines = log.read_bytes().splitlines(keepends=True)
    raw = (record / "raw.txt").read_bytes()
    assert raw == b"".join(line for line in lines if _parses(line))   # all but the 2 damaged
    assert '"stopped_utc": "20' in (record / "session.json").read_text()
    # a second recording into the same folder leaves the first alone: DIR-2
    out, err = _serve_and_send(log, record)
    assert f"{record} already holds a recorded session: recording into {record}-2" in err
    assert (record / "raw.txt").read_bytes() == raw
    assert (tmp_path / "session-2" / "raw.txt").read_bytes() == raw


def test_serve_with_nul_bytes_and_absurd_values_records_a_file_our_tools_read(tmp_path):
    """A NUL byte makes a line damaged, not a recording: `filter` reads what serve recorded,
    and gets the estimates of the clean log."""
    clean = b"".join(f"{1000 + 10 * k}\tGYR\t0.01\t0.0\t0.0\n{1000 + 10 * k}\tACC\t0.0\t0.0\t"
                     f"9.81\n{1000 + 10 * k}\tMAG\t0.0\t20.0\t-40.0\n".encode()
                     for k in range(300))
    lines = clean.splitlines(keepends=True)
    dirty = b"".join(lines[:300] + [b"1990\tACC\t0.0\x00\t0.0\t9.81\n", b"\x00" * 500 + b"\n",
                                    b"1995\tACC\t1e160\t0\t0\n"] + lines[300:])
    log = tmp_path / "dirty.txt"
    log.write_bytes(dirty)
    record = tmp_path / "session"
    out, _ = _serve_and_send(log, record)
    assert "3 damaged" in out and "binary data" in out and "ACC out of range" in out
    assert (record / "raw.txt").read_bytes() == clean
    (tmp_path / "clean.txt").write_bytes(clean)
    estimates = []
    for path in (record, tmp_path / "clean.txt", log):
        result = subprocess.run([sys.executable, "-m", "app", "filter", str(path)], cwd=ROOT,
                                capture_output=True, text=True, timeout=60)
        assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
        estimates.append(result.stdout)
    assert estimates[0] == estimates[1] == estimates[2]
    assert (record / "estimates.csv").read_text() == estimates[0]



@pytest.mark.parametrize("argv, message", [
    (["send", "/no/such/log.txt"], "no such file"),
    (["send", "--port", "70000", "x"], "port out of range"),
    (["serve", "--estimator", "nope", "--exit-after", "0"], "unknown 'nope'"),
    (["serve", "--speed", "1"], "unrecognized arguments"),
    (["serve", "--allow", "10.0.0.300"], "not an address or network"),
    (["serve", "--limits", "acc=-1"], "--limits: expected NAME=VALUE"),
    (["serve", "--record-max-mb", "x"], "not a size in MB"),
    (["filter", "x.txt", "--limits", "speed=3"], "--limits: expected NAME=VALUE"),
])
def test_bad_arguments_exit_2_with_one_line(argv, message):
    result = subprocess.run([sys.executable, "-m", "app", *argv], cwd=ROOT,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_send_to_nobody_is_a_clean_error(tmp_path, capsys):
    log = tmp_path / "log.txt"
    log.write_text("1\tACC\t0\t0\t9.8\n")
    assert main(["send", str(log), "--host", "127.0.0.1", "--port", str(_free_port()),
                 "--speed", "0"]) == 2
    err = capsys.readouterr().err
    assert "cannot send to 127.0.0.1" in err and len(err.strip().splitlines()) == 1


def test_exit_when_idle_waits_for_lines_not_for_a_connection(monkeypatch):
    """serve --exit-when-idle: a connection that sends nothing (a port probe, a stranger) does
    not start the idle timer; once lines have arrived, S seconds without any end the run."""
    import argparse
    from types import SimpleNamespace

    from app.cli import live

    clock = [100.0]
    monkeypatch.setattr(live.time, "monotonic", lambda: clock[0])
    watch = live._Watch(argparse.Namespace(exit_after=None, exit_when_idle=1.0))
    engine = SimpleNamespace(waiting_since=100.0, running=True)

    def snapshot(state: str, lines: int):
        health = SimpleNamespace(lines_total=lines, connection_state=state, recording="")
        return SimpleNamespace(health=health, failures=[], user=None)

    assert not watch.done(engine, snapshot("disconnected", 0))     # the probe came and went
    clock[0] = 105.0
    assert not watch.done(engine, snapshot("disconnected", 0))     # 5 s later: still waiting
    assert not watch.done(engine, snapshot("connected", 500))      # the phone streams
    clock[0] = 105.5
    engine.waiting_since = 105.5                                   # and hangs up
    assert not watch.done(engine, snapshot("disconnected", 500))
    clock[0] = 106.6
    assert watch.done(engine, snapshot("disconnected", 500))       # 1.1 s without a line
