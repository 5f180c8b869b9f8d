"""The headless commands, end to end, and their error handling."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import ekf
from app import cli
from app.engine.offline.filtering import evaluate_log


def test_simulate_filter_evaluate_round_trip(tmp_path, capsys):
    log = tmp_path / "sim.txt"
    assert cli.main(["simulate", "-o", str(log), "--duration", "20", "--seed", "2"]) == 0
    out = tmp_path / "est.csv"
    assert cli.main(["filter", str(log), "-o", str(out), "--estimator", "ekf"]) == 0
    rows = list(csv.reader(out.open()))
    assert rows[0] == ["t_ms", "qw", "qx", "qy", "qz", "acc_rejected", "mag_rejected", "at_rest"]
    q = np.array([[float(x) for x in r[1:5]] for r in rows[1:]])
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-8)
    assert (q[:, 0] >= 0).all()
    t = [int(r[0]) for r in rows[1:]]
    assert t == sorted(set(t))   # one row per distinct time
    capsys.readouterr()
    assert cli.main(["evaluate", str(log), "--estimator", "ekf,course,complementary,gyro,accmag"]) == 0
    table = capsys.readouterr().out
    ekf_total = float(next(line for line in table.splitlines() if line.startswith("ekf ")).split()[2])
    assert ekf_total < 3.0


@pytest.mark.parametrize("argv,needle", [
    (["filter", "/no/such/log.txt"], "no such file"),
    (["filter", "{log}", "--sensors", "gyr,foo"], "--sensors"),
    (["filter", "{log}", "--estimator", "kalman"], "unknown"),
    (["filter", "{log}", "--settings", "{bad_settings}"], "bad settings"),
    (["evaluate", "{log}", "--intervals", "/no/such.json"], "not found"),
    (["calibrate", "{empty}"], "empty"),
    (["simulate", "-o", "x.txt", "--duration", "-1"], "--duration"),
    (["filter"], "required"),
    (["nonsense"], "invalid choice"),
])
def test_bad_input_gives_one_line_and_exit_2(tmp_path, capsys, argv, needle):
    log = tmp_path / "sim.txt"
    cli.main(["simulate", "-o", str(log), "--duration", "3"])
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"acc_gat": 1}))
    empty = tmp_path / "empty.txt"
    empty.write_text("")
    argv = [a.format(log=log, bad_settings=bad, empty=empty) for a in argv]
    capsys.readouterr()
    try:
        code = cli.main(argv)
    except SystemExit as e:     # argparse's own errors
        code = e.code
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert needle in err
    assert "Traceback" not in err


def test_calibrate_writes_settings_the_filter_accepts(tmp_path, capsys):
    from ekf.simulate import simulate
    from app.stream.demo import write_session
    log = tmp_path / "rest.txt"
    write_session(simulate(duration_s=8, script="rest", seed=4, gyro_bias=(0.01, 0, 0)), log)
    settings = tmp_path / "s.json"
    assert cli.main(["calibrate", str(log), "-o", str(settings)]) == 0
    saved = json.loads(settings.read_text())["settings"]
    assert saved["g"] == pytest.approx(9.81, abs=0.01)
    assert saved["gyr_bias"][0] == pytest.approx(0.01, abs=1e-3)
    assert cli.main(["filter", str(log), "--settings", str(settings), "-o", str(tmp_path / "o.csv")]) == 0
    # onto the plain course model the measured noise goes too (task 2)
    course_file = tmp_path / "c.json"
    assert cli.main(["calibrate", str(log), "--settings", "course", "-o", str(course_file)]) == 0
    course = json.loads(course_file.read_text())["settings"]
    assert course["acc_lowpass_s"] == 0 and course["acc_noise_cov"][0][0] < 0.01
    assert saved["acc_noise_cov"] == ekf_default_acc_cov()


def ekf_default_acc_cov():
    import ekf
    return ekf.PRESETS["default"].acc_noise_cov


def test_real_rotation_log_within_10_degrees_of_the_phone(realphone_dir):
    from app.stream.logfile import read_log
    import ekf
    log = read_log(realphone_dir / "tsrt14_lab2_rotation.txt")
    s = evaluate_log(log, "ekf", None, ("gyr", "acc", "mag"), None, 3.0)
    assert s.samples > 1500
    assert s.total_rmse_deg < 10.0
    course = evaluate_log(log, "ekf", ekf.PRESETS["course"], ("gyr", "acc", "mag"), None, 3.0)
    assert course.total_rmse_deg < 10.0


def _log_and_truth(tmp_path, seconds=20):
    """A simulated log whose ORI is turned by 5 deg (a phone's own, imperfect estimate) and a
    sibling NAME.truth.txt holding the true orientation (ORI lines only)."""
    import ekf.quaternion as Q
    log = tmp_path / "walk.txt"
    assert cli.main(["simulate", "-o", str(log), "--duration", str(seconds), "--seed", "4"]) == 0
    lines = log.read_text().splitlines()
    truth = [line for line in lines if "\tORI\t" in line]
    (tmp_path / "walk.truth.txt").write_text("\n".join(truth) + "\n")
    off = Q.from_axis_angle([0, 0, 1], np.radians(5.0))
    phone = []
    for line in lines:
        if "\tORI\t" in line:
            t, tag, *q = line.split("\t")
            q = Q.multiply(off, np.array(q, float))
            line = "\t".join([t, tag, *(f"{v:.7f}" for v in q)])
        phone.append(line)
    log.write_text("\n".join(phone) + "\n")
    return log


def _rows(table: str) -> dict[str, list[float]]:
    out = {}
    for line in table.splitlines()[2:]:
        name, _, rest = line.rpartition("  ")
        parts = line.split()
        if len(parts) >= 5:
            out[" ".join(parts[:-4])] = [float(x) for x in parts[-3:]]
    return out


def test_evaluate_scores_against_the_sibling_truth_with_the_phone_as_a_row(tmp_path, capsys):
    log = _log_and_truth(tmp_path)
    capsys.readouterr()
    assert cli.main(["evaluate", str(log), "--estimator", "ekf,course"]) == 0
    out = capsys.readouterr().out
    assert "walk.truth.txt" in out.splitlines()[0]
    rows = _rows(out)
    assert set(rows) == {"ekf", "course", "phone (ORI)"}
    assert rows["ekf"][0] < 3.0
    assert abs(rows["phone (ORI)"][0] - 5.0) < 0.1 and abs(rows["phone (ORI)"][1] - 5.0) < 0.1
    # an explicit --truth gives the same; without a truth file the reference is the log's ORI
    capsys.readouterr()
    assert cli.main(["evaluate", str(log), "--truth", str(tmp_path / "walk.truth.txt")]) == 0
    assert _rows(capsys.readouterr().out)["ekf"] == rows["ekf"]
    (tmp_path / "walk.truth.txt").unlink()
    assert cli.main(["evaluate", str(log)]) == 0
    alone = _rows(capsys.readouterr().out)
    assert set(alone) == {"ekf"} and alone["ekf"][1] > 3.0     # 5 deg off in heading


def test_evaluate_and_filter_smooth(tmp_path, capsys):
    log = _log_and_truth(tmp_path, seconds=30)
    capsys.readouterr()
    assert cli.main(["evaluate", str(log), "--estimator", "ekf,course"]) == 0
    forward = _rows(capsys.readouterr().out)
    assert cli.main(["evaluate", str(log), "--estimator", "ekf,course", "--smooth"]) == 0
    smoothed = _rows(capsys.readouterr().out)
    assert smoothed["ekf smoothed"][0] <= forward["ekf"][0]
    assert "course smoothed" in smoothed
    out = tmp_path / "s.csv"
    assert cli.main(["filter", str(log), "--smooth", "-o", str(out)]) == 0
    plain = tmp_path / "f.csv"
    assert cli.main(["filter", str(log), "-o", str(plain)]) == 0
    a, b = list(csv.reader(out.open())), list(csv.reader(plain.open()))
    assert len(a) == len(b) and [r[0] for r in a] == [r[0] for r in b]
    assert [r[5:] for r in a] == [r[5:] for r in b]      # the lights are the filter's
    # the smoother combines the filter as set with what the rows after each row add: its last
    # row (nothing after it) is the filter's, earlier rows are not
    assert a[-1][:5] == b[-1][:5] and any(x[:5] != y[:5] for x, y in zip(a, b))


def test_smooth_needs_the_ekf(tmp_path, capsys):
    log = tmp_path / "sim.txt"
    cli.main(["simulate", "-o", str(log), "--duration", "3"])
    capsys.readouterr()
    assert cli.main(["filter", str(log), "--smooth", "--estimator", "complementary"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--smooth" in err[0]


def test_filter_into_a_pipe_closed_early_ends_quietly(tmp_path):
    # `orientation-lab filter LOG | head -1`: the reader stops; no error message, status 0
    import subprocess
    import sys
    log = tmp_path / "long.txt"
    assert cli.main(["simulate", "-o", str(log), "--duration", "120", "--seed", "3"]) == 0
    process = subprocess.Popen([sys.executable, "-c", "import sys; from app import cli; sys.exit(cli.main())", "filter",
                                str(log)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert process.stdout.readline().startswith(b"t_ms,")
    process.stdout.close()                     # the reader had enough
    _, err = process.communicate(timeout=120)
    assert process.returncode == 0, err
    assert b"error" not in err and b"Traceback" not in err

