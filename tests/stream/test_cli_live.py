"""`send` and `serve` end to end: a log through the socket is recorded verbatim."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from app.cli import main

ROOT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _wait_port(port: int, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return
        except OSError:
            time.sleep(0.05)
    raise AssertionError("serve never listened")


def test_send_to_serve_records_raw_verbatim(tmp_path, realphone_dir):
    log = realphone_dir / "sensorLog_20221024T182616_standstill.txt"
    port = _free_port()
    record = tmp_path / "session"
    server = subprocess.Popen(
        [sys.executable, "-m", "app", "serve", "--host", "127.0.0.1", "--port", str(port),
         "--record", str(record), "--exit-when-idle", "1", "--no-comparisons"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_port(port)     # this probe connection counts as a (silent) phone
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
    assert "final: disconnected" in out and "9339 lines" in out and "2 damaged" in out
    assert (record / "raw.txt").read_bytes() == log.read_bytes()
    assert '"stopped_utc": "20' in (record / "session.json").read_text()


@pytest.mark.parametrize("argv, message", [
    (["send", "/no/such/log.txt"], "no such file"),
    (["send", "--port", "70000", "x"], "port out of range"),
    (["serve", "--estimator", "nope", "--exit-after", "0"], "unknown 'nope'"),
    (["serve", "--speed", "1"], "unrecognized arguments"),
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
