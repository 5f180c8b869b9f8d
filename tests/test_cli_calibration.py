"""calibrate, calibrate-mag and tune on the command line: tables, files, profiles, PNG figures,
and bad input as one line with exit status 2; headless with Qt blocked (except --plots)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import ekf
from ekf.simulate import simulate
from app import cli
from app.stream.demo import write_session
from test_architecture import QT, run_blocked

ROOT = Path(__file__).resolve().parents[1]

OFFSET = (30.0, -25.0, 200.0)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cli")
    rest = folder / "rest.txt"
    write_session(simulate(duration_s=12, script="rest", seed=4, gyro_bias=(0.01, 0, 0)), rest)
    turning = simulate(duration_s=40, seed=5)
    turning.mag.values = turning.mag.values + np.array(OFFSET)
    mag = folder / "turning.txt"
    write_session(turning, mag)
    motion = folder / "motion.txt"
    write_session(simulate(duration_s=30, seed=6), motion)
    return {"rest": rest, "mag": mag, "motion": motion, "folder": folder}


def test_calibrate_prints_the_table_the_checks_and_the_allan_figures(logs, capsys, tmp_path,
                                                                     monkeypatch):
    monkeypatch.setenv("ORIENTATION_LAB_DATA", str(tmp_path))
    out = tmp_path / "s.json"
    assert cli.main(["calibrate", str(logs["rest"]), "-o", str(out), "--profile", "sim"]) == 0
    text = capsys.readouterr().out
    assert "Covariance gyr" in text and "K² p" in text and "ARW" in text
    assert "verdict: Gaussian: neither test rejects normality at the 1 % level" in text
    saved = json.loads(out.read_text())
    assert saved["settings"]["gyr_bias"][0] == pytest.approx(0.01, abs=1e-3)
    assert saved["calibration"]["allan"]["axes"][0]["arw_rad_per_sqrt_s"] > 0
    profile = json.loads((tmp_path / "profiles" / "sim.json").read_text())
    assert profile["rest"]["gyr"]["mean"][0] == pytest.approx(0.01, abs=1e-3)


def test_calibrate_a_chosen_range_of_a_moving_log_warns(logs, capsys):
    assert cli.main(["calibrate", str(logs["motion"]), "--range", "0:12"]) == 0
    assert "warning: the phone moved" in capsys.readouterr().out


def test_calibrate_plots_writes_pngs(logs, tmp_path, capsys):
    plots = tmp_path / "plots"
    assert cli.main(["calibrate", str(logs["rest"]), "--plots", str(plots)]) == 0
    assert sorted(p.name for p in plots.iterdir()) == [
        "gyro_allan.png", "rest_autocorrelation.png", "rest_histograms.png",
        "rest_timeseries.png"]
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in plots.iterdir())
    assert cli.main(["calibrate-mag", str(logs["mag"]), "--plots", str(plots)]) == 0
    assert (plots / "mag_cloud.png").stat().st_size > 10_000


@pytest.mark.parametrize("command", ["calibrate", "calibrate-mag"])
@pytest.mark.parametrize("where", ["a file", "below a file"])
def test_plots_into_a_place_that_takes_no_files_is_one_line(logs, tmp_path, command, where):
    a_file = tmp_path / "taken.png"
    a_file.write_bytes(b"mine")
    target = a_file if where == "a file" else a_file / "plots"
    log = logs["rest"] if command == "calibrate" else logs["mag"]
    result = subprocess.run([sys.executable, "-m", "app", command, str(log), "--plots",
                             str(target)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and f"--plots {target}" in lines[0], lines
    assert a_file.read_bytes() == b"mine"


def test_calibrate_mag_prints_offset_matrix_coverage_and_spread(logs, capsys, tmp_path):
    out = tmp_path / "mag.json"
    assert cli.main(["calibrate-mag", str(logs["mag"]), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    for needle in ("hard-iron offset", "soft-iron matrix", "coverage", "|m| before"):
        assert needle in text
    saved = json.loads(out.read_text())
    np.testing.assert_allclose(saved["settings"]["mag_hard_iron"], OFFSET, atol=1.0)
    # the written settings correct the readings for `filter` and `evaluate`
    assert cli.main(["evaluate", str(logs["mag"]), "--settings", str(out)]) == 0
    fixed = float(capsys.readouterr().out.splitlines()[-1].split()[2])
    assert cli.main(["evaluate", str(logs["mag"])]) == 0
    wrong = float(capsys.readouterr().out.splitlines()[-1].split()[2])
    assert fixed < wrong


def test_calibrate_mag_on_calibrated_readings_finds_nothing_to_correct(logs, capsys):
    assert cli.main(["calibrate-mag", str(logs["motion"])]) == 0
    assert "nothing to correct" in capsys.readouterr().out


def test_tune_prints_before_after_and_the_time_and_writes_settings(logs, capsys, tmp_path):
    out = tmp_path / "tuned.json"
    assert cli.main(["tune", str(logs["motion"]), "--params", "gyr_noise_cov,acc_gate=0.5:5",
                     "--max-evals", "8", "--skip", "2", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "tune  first half before" in text and "check second half after" in text
    assert "evaluations in" in text and "acc_gate" in text
    saved = json.loads(out.read_text())
    assert ekf.EKFSettings.from_dict(saved["settings"])
    assert saved["tuning"]["evaluations"] <= 8
    assert cli.main(["filter", str(logs["motion"]), "--settings", str(out),
                     "-o", str(tmp_path / "e.csv")]) == 0


def test_tune_on_intervals_checked_on_another_log(logs, capsys, tmp_path):
    intervals = tmp_path / "i.json"
    intervals.write_text(json.dumps({"score_intervals_ms": [[1_003_000, 1_020_000]]}))
    assert cli.main(["tune", str(logs["motion"]), "--intervals", str(intervals),
                     "--check-log", str(logs["mag"]), "--max-evals", "4",
                     "--settings", "course"]) == 0
    assert "check turning.txt" in capsys.readouterr().out


def test_tune_names_a_long_check_log_whole_and_warns_of_a_bound(logs, capsys, tmp_path):
    long_name = tmp_path / "a_check_log_with_a_rather_long_name.txt"
    long_name.write_bytes(logs["mag"].read_bytes())
    assert cli.main(["tune", str(logs["motion"]), "--check-log", str(long_name),
                     "--params", "acc_lowpass_s=0.001:0.002", "--max-evals", "4"]) == 0
    text = capsys.readouterr().out
    assert f"check {long_name.name} before" in text and f"check {long_name.name} after" in text
    assert "acc_lowpass_s ended at its search bound" in text


@pytest.mark.parametrize("argv,needle", [
    (["calibrate-mag", "{rest}", "--range", "5:1"], "time range"),
    (["calibrate", "{rest}", "--range", "100:200"], "nothing in the range"),
    (["tune", "{rest}", "--params", "nonsense"], "unknown setting"),
    (["tune", "{rest}", "--estimator", "gyro"], "one EKF"),
    (["tune", "{rest}", "--check-intervals", "/no/such.json"], "not found"),
    (["tune", "{rest}", "--objective", "speed"], "invalid choice"),
    (["calibrate", "/no/such/log.txt"], "no such file"),
])
def test_bad_input_gives_one_line_and_exit_2(logs, capsys, argv, needle):
    argv = [a.format(**logs) for a in argv]
    capsys.readouterr()
    try:
        code = cli.main(argv)
    except SystemExit as error:
        code = error.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    errors = [line for line in err if "error" in line]     # the log's summary may come first
    assert len(errors) == 1 and errors == err[-1:] and needle in err[-1], err
    assert "Traceback" not in "\n".join(err)


def test_the_new_commands_run_with_qt_blocked_and_plots_say_what_they_need(logs, tmp_path):
    r = run_blocked(QT, f"""
        import app.cli
        assert app.cli.main(["calibrate", {str(logs['rest'])!r}]) == 0
        assert app.cli.main(["calibrate-mag", {str(logs['mag'])!r}]) == 0
        assert app.cli.main(["tune", {str(logs['motion'])!r}, "--max-evals", "3"]) == 0
        code = app.cli.main(["calibrate", {str(logs['rest'])!r}, "--plots",
                             {str(tmp_path / 'p')!r}])
        assert code == 2, code
        print("ok")
    """)
    assert r.returncode == 0, r.stderr
    assert "ok" in r.stdout
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("orientation-lab: error: --plots needs Qt")


def test_a_log_without_a_gyroscope_is_said_once_and_tune_leaves_its_settings_alone(
        logs, capsys, tmp_path):
    """Issue 51: evaluate on a log without a gyroscope gave its figure without a word, and tune
    searched gyr_noise_cov, which has no effect there."""
    no_gyro = tmp_path / "no_gyro.txt"
    no_gyro.write_bytes(b"".join(line for line in logs["motion"].read_bytes().splitlines(True)
                                 if b"\tGYR\t" not in line))
    assert cli.main(["evaluate", str(no_gyro)]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert warnings == ["orientation-lab: warning: no_gyro.txt has no gyroscope samples: the "
                        "estimate runs without it (--sensors acc,mag says so and silences this)"]
    assert cli.main(["evaluate", str(no_gyro), "--sensors", "acc,mag"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert cli.main(["evaluate", str(logs["motion"])]) == 0
    assert "warning" not in capsys.readouterr().err
    out = tmp_path / "tuned.json"
    assert cli.main(["tune", str(no_gyro), "--params", "gyr_noise_cov,acc_noise_cov",
                     "--max-evals", "4", "-o", str(out)]) == 0
    captured = capsys.readouterr()
    assert "not tuning gyr_noise_cov: the filter runs without its sensor" in captured.err
    assert "tuning acc_noise_cov on" in captured.out
    saved = json.loads(out.read_text())
    assert saved["settings"]["gyr_noise_cov"] == ekf.PRESETS["default"].gyr_noise_cov
    assert [p["name"] for p in saved["tuning"]["parameters"]] == ["acc_noise_cov"]
    assert cli.main(["tune", str(no_gyro), "--params", "gyr_noise_cov"]) == 2
    assert "nothing to tune" in capsys.readouterr().err
