"""The command line of the other phone apps: `serve --phyphox` / `--sensor-logger` with `send
--as phyphox` / `--as sensor-logger` end to end, and their bad arguments as one line."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from phone_logs import by_tag, log_samples, simulated_lines

from app.cli import main

ROOT = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "app"]


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cli") / "log.txt"
    path.write_bytes(b"".join(simulated_lines(3.0, seed=2)))
    return path


def _finish(process: subprocess.Popen, timeout: float = 90) -> tuple[str, str]:
    try:
        return process.communicate(timeout=timeout)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()


def test_serve_records_what_send_as_phyphox_serves(tmp_path, log):
    port = _free_port()
    phone = subprocess.Popen(CLI + ["send", str(log), "--as", "phyphox", "--port", str(port),
                                    "--speed", "0", "--start-ms", "0"],
                             cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert "serving" in phone.stderr.readline()
    server = subprocess.Popen(CLI + ["serve", "--phyphox", f"127.0.0.1:{port}", "--record",
                                     str(tmp_path / "rec"), "--exit-when-idle", "2",
                                     "--no-comparisons"],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = _finish(server)
    _, said = _finish(phone)
    assert server.returncode == 0 and "Traceback" not in err
    assert out.startswith(f"polling phyphox at http://127.0.0.1:{port}")
    assert "served the log to its end" in said and "0 overlapping" in said
    recorded = (tmp_path / "rec" / "raw.txt").read_bytes().splitlines(keepends=True)
    assert by_tag(log_samples(recorded)) == by_tag(log_samples(log.read_bytes().splitlines()))
    session = json.loads((tmp_path / "rec" / "session.json").read_text())
    assert session["source"] == "phyphox"


def test_serve_records_what_send_as_sensor_logger_pushes(tmp_path, log):
    server = subprocess.Popen(CLI + ["serve", "--sensor-logger", "127.0.0.1:0", "--record",
                                     str(tmp_path / "rec"), "--exit-when-idle", "2",
                                     "--no-comparisons"],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = server.stdout.readline()
    assert first.startswith("listening on port") and "Sensor Logger" in first
    url = first.rsplit(": ", 1)[1].split(",")[0].strip()
    pushed = subprocess.run(CLI + ["send", str(log), "--as", "sensor-logger", "--url", url,
                                   "--speed", "0", "--period", "0.5", "--platform", "ios"],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    out, err = _finish(server)
    assert pushed.returncode == 0 and "x 200" in pushed.stderr, pushed.stderr
    assert server.returncode == 0 and "Traceback" not in err
    recorded = log_samples((tmp_path / "rec" / "raw.txt").read_bytes().splitlines())
    expected = log_samples(log.read_bytes().splitlines())
    assert {tag: len(v) for tag, v in by_tag(recorded).items()} == \
        {tag: len(v) for tag, v in by_tag(expected).items()}


@pytest.mark.parametrize("arguments, message", [
    (["serve", "--phyphox", "https://10.0.0.2"], "--phyphox: phyphox speaks plain http"),
    (["serve", "--phyphox", "10.0.0.2", "--sensor-logger", "8000"],
     "--phyphox and --sensor-logger: give one source at a time"),
    (["serve", "--sensor-logger", "99999"], "port out of range"),
    (["serve", "--sensor-logger-frames", "sideways"], "--sensor-logger-frames"),
    (["send", "LOG", "--as", "sensor-logger"], "--as sensor-logger needs --url"),
    (["send", "LOG", "--as", "sensor-logger", "--url", "ftp://x"], "--url:"),
    (["send", "LOG", "--gone", "1:2"], "--gone: only with --as phyphox or --as sensor-logger"),
    (["send", "LOG", "--as", "phyphox", "--loop"], "--loop: not with --as phyphox"),
    (["send", "LOG", "--as", "phyphox", "--gone", "soon"], "expected AT:SECONDS"),
])
def test_bad_arguments_are_one_line(capsys, log, arguments, message):
    arguments = [str(log) if a == "LOG" else a for a in arguments]
    try:
        status = main(arguments)
    except SystemExit as exit_:          # argparse's own checks
        status = exit_.code
    assert status == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
