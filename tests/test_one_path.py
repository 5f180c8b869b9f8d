"""One way through the house: the offline commands run the live engine's runner; one settings
loader for every entry point; engine failures reach the user; a recording keeps our estimates."""

from __future__ import annotations

import csv
import io
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from waiting import wait_for_port, wait_for_snapshot, wait_until

import ekf
from app.cli import main
from app.engine import config
from app.engine.offline.filtering import HEADER, write_csv
from app.engine.offline.filtering import filter_log
from app.engine.live.worker import Engine
from app.stream.logfile import read_log
from app.stream.sources import LineReplaySource, LogFileSource

ROOT = Path(__file__).resolve().parents[1]


def _wait(engine: Engine, predicate, timeout: float = 40.0):
    return wait_for_snapshot(engine, predicate, timeout)


def _duplicated_log(path: Path) -> Path:
    """A turning phone whose lines include exact duplicates and several same-time samples of one
    tag with different values (two ACC lines at one time stamp), interleaved across tags."""
    lines = []
    for k in range(600):
        t = 1000 + 10 * k
        rate = 0.8 if k > 100 else 0.0
        lines.append(f"{t}\tGYR\t0.01\t-0.02\t{rate}")
        lines.append(f"{t}\tACC\t0.1\t0.0\t9.81")
        if k % 7 == 3:
            lines.append(f"{t}\tACC\t0.9\t-0.4\t9.2")          # same time, other values
        if k % 11 == 5:
            lines.append(lines[-1])                              # an exact duplicate line
        if k % 2 == 0:
            lines.append(f"{t}\tMAG\t3.0\t20.0\t-40.0")
        if k % 13 == 0:
            lines.append(f"{t}\tGYR\t0.02\t-0.01\t{rate}")       # a second GYR, same time
        lines.append(f"{t + 4}\tORI\t1.0\t0.0\t0.0\t0.0")
    path.write_text("\n".join(lines) + "\n")
    return path


def _engine_rows(path: Path, settings=None) -> tuple:
    engine = Engine(LogFileSource(path, speed=0), settings=settings, comparisons=False,
                    record_rows=True)
    with engine:
        _wait(engine, lambda s: s.health.connection_state == "finished")
    rows = [r.select(r.has_sample) for r in engine.rows_log]
    return (np.concatenate([r.t_ms for r in rows]), np.concatenate([r.quat for r in rows]),
            np.concatenate([np.stack([r.acc_rejected, r.mag_rejected, r.at_rest], 1)
                            for r in rows]))


@pytest.mark.parametrize("preset", ["default", "course"])
def test_offline_filter_equals_the_live_engine_bit_for_bit_with_duplicates(tmp_path, preset):
    log = _duplicated_log(tmp_path / "dup.txt")
    settings = ekf.PRESETS[preset]
    offline = filter_log(read_log(log), "ekf", settings)
    t_ms, quat, flags = _engine_rows(log, settings)
    assert len(offline) > 500
    assert np.array_equal(offline.t_ms, t_ms)
    assert np.array_equal(offline.quat, quat)     # bit for bit, not approximately
    assert np.array_equal(np.stack([offline.acc_rejected, offline.mag_rejected,
                                    offline.at_rest], 1), flags)
    # and the command prints exactly these rows
    out = tmp_path / "est.csv"
    assert main(["filter", str(log), "--settings", preset, "-o", str(out)]) == 0
    printed = list(csv.reader(out.open()))
    assert ",".join(printed[0]) == HEADER
    assert [int(r[0]) for r in printed[1:]] == t_ms.tolist()
    np.testing.assert_allclose([[float(x) for x in r[1:5]] for r in printed[1:]], quat,
                               atol=1e-9, rtol=0)


def test_same_time_samples_are_all_used_offline(tmp_path):
    """Both ACC samples of one time stamp reach the filter (the old array path kept only the
    last, so the estimates differed from the live path's by up to 7e-3)."""
    log = _duplicated_log(tmp_path / "dup.txt")
    rows = filter_log(read_log(log), "ekf", ekf.PRESETS["course"])
    assert len(np.unique(rows.t_ms)) == len(rows.t_ms)       # one row per distinct time
    data = read_log(log)
    acc_at = {}
    acc = data.tag == 1
    for t, values in zip(data.t_ms[acc].tolist(), data.values[acc, :3].tolist()):
        acc_at.setdefault(t, []).append(values)
    assert any(len(v) == 2 and v[0] != v[1] for v in acc_at.values())


# ---- one settings loader -------------------------------------------------------------------------

def test_settings_loader_takes_presets_files_and_sessions(tmp_path):
    assert config.load_settings("course") is ekf.PRESETS["course"]
    assert config.load_settings("default") is ekf.PRESETS["default"]
    assert config.load_settings(None) is None
    path = tmp_path / "s.json"
    ekf.PRESETS["course"].with_changes(acc_gate=2.5).save(path)
    assert config.load_settings(path).acc_gate == 2.5
    session = tmp_path / "session.json"
    session.write_text('{"settings": {"mag_gate": 7.0}, "timeline": []}')
    assert config.load_settings(session).mag_gate == 7.0
    with pytest.raises(config.ConfigError, match="settings file not found: nope.json"):
        config.load_settings("nope.json")
    (tmp_path / "bad.json").write_text('{"acc_gat": 1}')
    with pytest.raises(config.ConfigError, match="bad settings file"):
        config.load_settings(tmp_path / "bad.json")


def _sim(tmp_path: Path) -> Path:
    log = tmp_path / "sim.txt"
    assert main(["simulate", "-o", str(log), "--duration", "4", "--seed", "1"]) == 0
    return log


@pytest.mark.parametrize("command", ["filter", "evaluate"])
@pytest.mark.parametrize("settings", ["course", "file"])
def test_offline_commands_accept_a_preset_name_and_a_file(tmp_path, capsys, command, settings):
    log = _sim(tmp_path)
    if settings == "file":
        settings = str(tmp_path / "s.json")
        ekf.PRESETS["course"].save(settings)
    capsys.readouterr()
    assert main([command, str(log), "--settings", settings]) == 0
    assert capsys.readouterr().err.count("error") == 0


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _serve(args: list[str], timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "app", "serve", "--host", "127.0.0.1",
                           "--port", str(_free_port()), "--quiet", *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("settings", ["course", "file"])
def test_serve_accepts_a_preset_name_and_a_file(tmp_path, settings):
    if settings == "file":
        settings = str(tmp_path / "s.json")
        ekf.PRESETS["course"].save(settings)
    result = _serve(["--settings", settings, "--exit-after", "0.3", "--no-comparisons"])
    assert result.returncode == 0, result.stderr
    assert "final: " in result.stdout


def test_serve_bad_settings_is_one_line_exit_2(tmp_path):
    result = _serve(["--settings", str(tmp_path / "missing.json"), "--exit-after", "0"])
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"orientation-lab: error: settings file not found: {tmp_path / 'missing.json'} "
        "(or give a preset: default, course)"]


@pytest.mark.parametrize("settings", ["course", "file"])
def test_the_window_accepts_a_preset_name_and_a_file(tmp_path, settings):
    from app.ui.main import WindowOptions, build_engine
    if settings == "file":
        settings = str(tmp_path / "s.json")
        ekf.PRESETS["course"].with_changes(acc_gate=1.5).save(settings)
    engine = build_engine(WindowOptions(source=config.SourceOptions(demo=True, port=0),
                                        settings=settings))
    expected = 1.5 if settings.endswith(".json") else ekf.PRESETS["course"].acc_gate
    assert engine.runner.settings.acc_gate == expected


def test_the_window_without_a_display_says_so_in_one_line():
    env = {k: v for k, v in __import__("os").environ.items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM")}
    result = subprocess.run([sys.executable, "-m", "app", "--demo"], cwd=ROOT, env=env,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "no display" in lines[0] and "serve" in lines[0]


def test_a_display_that_does_not_answer_is_one_line_not_a_qt_abort():
    env = {k: v for k, v in __import__("os").environ.items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM")}
    env["DISPLAY"] = ":97"                 # no X server listens there
    result = subprocess.run([sys.executable, "-m", "app", "--demo"], cwd=ROOT, env=env,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "DISPLAY=:97 does not answer" in lines[0]


# ---- engine failures reach the user --------------------------------------------------------------

class _Boom(RuntimeError):
    pass


def _lines(seconds: float = 3.0) -> list[bytes]:
    out = []
    for k in range(int(seconds * 100)):
        t = 1000 + 10 * k
        out += [f"{t}\tGYR\t0.0\t0.0\t0.1\n".encode(), f"{t}\tACC\t0.0\t0.0\t9.81\n".encode()]
    return out


def test_a_failing_batch_is_reported_and_the_engine_goes_on(monkeypatch, caplog):
    # 60 s: several chunks of at most 4096 lines, the first of which fails
    engine = Engine(LineReplaySource(_lines(60.0), "synthetic", speed=0), comparisons=False)
    runner = engine.runner
    original = runner.feed_arrays
    calls = {"n": 0}

    def flaky(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 1:
            raise _Boom("injected")
        return original(*args, **kwargs)

    monkeypatch.setattr(runner, "feed_arrays", flaky)
    with caplog.at_level("ERROR", logger="orientation_lab.engine"):
        with engine:
            final = _wait(engine, lambda s: s.health.connection_state == "finished")
    assert len(final.failures) == 1
    failure = final.failures[0]
    assert failure.number == 1 and not failure.fatal
    assert failure.message.startswith("_Boom: injected (test_one_path.py, line")
    assert "Traceback (most recent call last)" in failure.details and "flaky" in failure.details
    assert any("engine failure 1" in r.getMessage() and "Traceback" in r.getMessage()
               for r in caplog.records)
    assert final.t_ms == 1000 + 10 * 5999                  # it went on to the end
    assert not engine.stopped_by_failure


def test_repeated_failures_stop_the_engine_cleanly(monkeypatch):
    engine = Engine(LineReplaySource(_lines(), "synthetic", speed=0.05), comparisons=False)

    def always(*args, **kwargs):
        raise _Boom("always")

    monkeypatch.setattr(engine.runner, "feed_arrays", always)
    with engine:
        final = _wait(engine, lambda s: s.failures and s.failures[-1].fatal, timeout=30)
        wait_until(lambda: not engine.running, 5, what="the engine to stop")
    assert engine.stopped_by_failure
    assert final.health.connection_state == "stopped"
    assert len(final.failures) == 5


def test_serve_prints_engine_failures(tmp_path):
    """A failure inside serve's engine is printed as one line and serve goes on."""
    code = f"""
import sys
from app.engine.processing import runner
original = runner.EstimatorRunner.feed_arrays
state = {{"n": 0}}
def flaky(self, *a, **k):
    state["n"] += 1
    if state["n"] == 2:
        raise ZeroDivisionError("float division by zero")
    return original(self, *a, **k)
runner.EstimatorRunner.feed_arrays = flaky
from app.cli import main
sys.exit(main(["serve", "--host", "127.0.0.1", "--port", "{_free_port()}", "--quiet",
               "--exit-when-idle", "0.5", "--no-comparisons"]))
"""
    port = int(code.split('"--port", "')[1].split('"')[0])
    server = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        _wait_port(port)
        payload = b"".join(_lines(2.0))
        with socket.create_connection(("127.0.0.1", port)) as phone:
            for start in range(0, len(payload), 4096):   # several chunks: several batches
                phone.sendall(payload[start:start + 4096])
                time.sleep(0.01)                         # apart, so they arrive apart
        out, err = server.communicate(timeout=60)
    finally:
        if server.poll() is None:
            server.kill()
            server.communicate()
    assert server.returncode == 0, err
    assert "orientation-lab: engine error (going on): ZeroDivisionError: float division by zero" \
        in err
    assert "Traceback" in err           # the log (stderr for serve) has the traceback


_wait_port = wait_for_port


# ---- a recording keeps what the user saw -----------------------------------------------------------

def test_serve_record_writes_estimates_that_filter_reproduces(tmp_path, realphone_dir):
    log = realphone_dir / "tsrt14_lab2_rotation.txt"
    port = _free_port()
    record = tmp_path / "session"
    server = subprocess.Popen(
        [sys.executable, "-m", "app", "serve", "--host", "127.0.0.1", "--port", str(port),
         "--record", str(record), "--exit-when-idle", "1", "--no-comparisons", "--quiet"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_port(port)
        sent = subprocess.run([sys.executable, "-m", "app", "send", str(log), "--port",
                               str(port), "--speed", "0"], cwd=ROOT, capture_output=True,
                              text=True, timeout=60)
        assert sent.returncode == 0, sent.stderr
        out, err = server.communicate(timeout=60)
    finally:
        if server.poll() is None:
            server.kill()
            server.communicate()
    assert server.returncode == 0, err
    recorded = (record / "estimates.csv").read_text()
    assert recorded.startswith(HEADER + "\n") and recorded.count("\n") > 1500
    replayed = tmp_path / "replayed.csv"
    assert main(["filter", str(record / "raw.txt"), "--settings", str(record / "session.json"),
                 "-o", str(replayed)]) == 0
    assert replayed.read_text() == recorded
    # the session folder itself is accepted wherever a log is
    stream = io.StringIO()
    write_csv(filter_log(config.open_log(record)), stream)
    assert stream.getvalue() == recorded


def test_serve_records_beside_a_session_never_over_it(tmp_path):
    """Was: refused (and before that, appended to the first session's raw.txt). Now a second
    recording into the same folder makes a new session folder and says so."""
    folder = tmp_path / "rec"
    folder.mkdir()
    (folder / "raw.txt").write_text("1\tACC\t0\t0\t9.8\n")
    result = _serve(["--record", str(folder), "--exit-after", "0"])
    assert result.returncode == 0, result.stderr
    assert f"{folder} already holds a recorded session: recording into {folder}-2" \
        in result.stderr
    assert (folder / "raw.txt").read_text() == "1\tACC\t0\t0\t9.8\n"
    assert (tmp_path / "rec-2" / "session.json").exists()


def test_the_window_on_a_port_in_use_names_the_port_in_one_line():
    taken = socket.socket()
    taken.bind(("0.0.0.0", 0))
    taken.listen(1)
    port = taken.getsockname()[1]
    try:
        env = dict(__import__("os").environ, QT_QPA_PLATFORM="offscreen")
        result = subprocess.run([sys.executable, "-m", "app", "--port", str(port),
                                 "--exit-after", "2"], cwd=ROOT, env=env, capture_output=True,
                                text=True, timeout=60)
    finally:
        taken.close()
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and f"0.0.0.0:{port}" in lines[0] and "--port" in lines[0]
