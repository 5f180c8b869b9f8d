"""Your filter written in MATLAB, run in GNU Octave: the solved course filter in .m
(tests/octave_filters/course, and course_lean: the same written with the kit's helpers inlined)
gives the built-in `course` estimator's estimates to 1e-9 through
`filter` and `evaluate --estimator course,DIR`; the template runs as written; each kind of error
gives its message in MATLAB terms (file and line where there is one) and pauses only YOURS.

The engine's live lane: tests/test_matlab_engine.py."""

from __future__ import annotations

import csv
import io
import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

import ekf
from app import cli
from app.engine.config import ConfigError, estimator_names, open_log
from app.engine.offline.filtering import filter_log
from app.engine.offline.refilter import refilter
from app.engine.userfilter import octave
from app.engine.userfilter.code import UserFilterError
from app.engine.userfilter.filter import UserFilterEstimator
from app.engine.userfilter.matlab_template import template_files
from app.engine.userfilter.protocol import settings_to_wire
from app.engine.userfilter.remote import filter_settings
from matlab_filters import COURSE_LEAN, COURSE_M, matlab_filter, needs_octave
from ekf.simulate import simulate
from user_filters import log_lines

pytestmark = needs_octave

COURSE = ekf.PRESETS["course"]
LOGS = ["tsrt14_lab2_rotation.txt", "tsrt14_lab2_magdisturbance.txt",
        "sensorLog_20221020T074342.txt"]


@pytest.fixture
def log(tmp_path):
    path = tmp_path / "log.txt"
    path.write_bytes(b"".join(log_lines(3.0)))
    return path


def _csv(text: str) -> np.ndarray:
    rows = list(csv.reader(io.StringIO(text)))
    assert rows[0][:5] == ["t_ms", "qw", "qx", "qy", "qz"]
    return np.array([[float(v) for v in row[:5]] for row in rows[1:]])


# ---- the solved course filter is the course estimator ----------------------------------------

@pytest.mark.shared
@pytest.mark.parametrize("name", LOGS)
@pytest.mark.parametrize("solved", [COURSE_M, COURSE_LEAN], ids=["as the course", "lean"])
def test_the_solved_course_filter_in_m_gives_the_course_estimates(realphone_dir, name, solved):
    log = open_log(realphone_dir / name)
    with UserFilterEstimator(solved, COURSE) as mine:
        theirs = filter_log(log, mine, COURSE)
        assert mine.problem is None and mine.missing_steps() == [] and mine.notes == []
    ours = filter_log(log, "course")
    assert np.array_equal(theirs.t_ms, ours.t_ms)
    assert np.max(np.abs(theirs.quat - ours.quat)) < 1e-9
    assert np.array_equal(theirs.acc_rejected, ours.acc_rejected)
    assert np.array_equal(theirs.mag_rejected, ours.mag_rejected)
    assert np.array_equal(theirs.at_rest, ours.at_rest)


def _rows_on_a_grid(seconds: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A simulated session's GYR, ACC, MAG readings stamped together every 10 ms, as the Sensor
    Fusion app stamps them: times [s] (n,) and values (n, 9) (NaN: none)."""
    sim = simulate(duration_s=seconds, rates_hz={"gyr": 100.0, "acc": 100.0, "mag": 100.0},
                   seed=seed)
    rows: dict[int, np.ndarray] = {}
    for t, tag, values in sim.iter_rows():
        if tag in ("GYR", "ACC", "MAG"):
            row = rows.setdefault(int(t) - int(t) % 10, np.full(9, np.nan))
            at = ("GYR", "ACC", "MAG").index(tag) * 3
            row[at:at + 3] = values[:3]
    t_ms = sorted(rows)
    return np.array(t_ms, float) / 1000.0, np.array([rows[k] for k in t_ms])


def test_irregular_rows_give_the_course_estimates():
    """What the host works out before its loop (which readings count, the time steps, the
    gyroscope rate held, where the filter starts) is what the course estimator does row by row:
    late sensors, gaps, absurd readings, times that go back or repeat, a long pause."""
    t, values = _rows_on_a_grid(12.0, seed=3)
    values[:40, 3:6] = np.nan                 # no accelerometer at first: the start comes later
    values[:20, 6:9] = np.nan
    values[300:360, 0:3] = np.nan             # a gyroscope gap: q stays, P grows
    values[500:504, 3:6] = np.nan
    values[610, 0] = 1e7                      # absurd or empty readings are not used
    values[700, 3:6] = 0.0
    values[800, 6:9] = 0.0
    t[900] = t[899] - 0.004                   # a time that goes back, one that repeats
    t[901] = t[899]
    t[1000:] += 0.8                           # longer than max_dt
    values[1100] = np.nan                     # a row with nothing
    columns = (values[:, 0:3], values[:, 3:6], values[:, 6:9])
    theirs = ekf.make_estimator("course", COURSE).run_batch(t, *columns)
    with UserFilterEstimator(COURSE_LEAN, COURSE) as mine:
        ours = mine.run_batch(t, *columns)
        assert mine.problem is None
    assert np.max(np.abs(ours.quat - theirs.quat)) < 1e-9
    for flag in ("acc_rejected", "mag_rejected", "at_rest"):
        assert np.array_equal(getattr(ours, flag), getattr(theirs, flag)), flag


def test_a_block_reply_times_the_loop_and_the_whole_block(tmp_path):
    """seconds (the loop) and block_seconds (the whole block: the loop and the work before and
    after it) are the block's own, in seconds."""
    t, values = _rows_on_a_grid(2.0, seed=1)
    data = tmp_path / "rows.bin"
    np.concatenate([t[:, None], values], axis=1).astype("<f8").tofile(data)
    wire = tmp_path / "settings.json"
    wire.write_text(json.dumps(settings_to_wire(filter_settings(COURSE))))
    script = tmp_path / "block.m"
    script.write_text(f"""
        addpath('{octave.HOST_DIR}');
        fid = fopen('{data}', 'r'); D = fread(fid, [10, Inf], 'double'); fclose(fid);
        cd('{COURSE_LEAN}');
        ctx = ol_load(pwd, pwd, jsondecode(fileread('{wire}')));
        V = D(2:10, :)';
        t0 = tic;
        [ctx, reply] = ol_run_block(ctx, D(1, :)', ~isnan(V(:, [1, 4, 7])), V, false);
        printf('\\ntimes %.9f %.9f %.9f %d\\n', reply.seconds, reply.block_seconds, toc(t0), ...
               reply.run);
    """)
    out = subprocess.run([str(octave.find_octave()), "--no-gui", "--norc", "--quiet",
                          "--no-window-system", str(script)], capture_output=True, timeout=120)
    assert out.returncode == 0, out.stderr
    # the last line, after the progress frames
    seconds, block_seconds, wall, run = out.stdout.rsplit(b"\ntimes ", 1)[1].decode().split()
    assert int(run) == len(t)
    assert 0 < float(seconds) <= float(block_seconds) <= float(wall)


@pytest.mark.shared
def test_filter_and_evaluate_on_the_command_line(realphone_dir, capsys):
    log = str(realphone_dir / "tsrt14_lab2_magdisturbance.txt")
    assert cli.main(["filter", log, "--estimator", str(COURSE_M), "--settings", "course"]) == 0
    mine = _csv(capsys.readouterr().out)
    assert cli.main(["filter", log, "--estimator", "course"]) == 0
    ours = _csv(capsys.readouterr().out)
    assert np.array_equal(mine[:, 0], ours[:, 0])
    assert np.max(np.abs(mine[:, 1:] - ours[:, 1:])) <= 1.0001e-9     # printed to 9 decimals
    assert cli.main(["evaluate", log, "--estimator", f"course,{COURSE_M}",
                     "--settings", "course"]) == 0
    out = capsys.readouterr().out
    lines = [line.split() for line in out.splitlines()
             if line.startswith(("course", "course "))]
    assert len(lines) == 2 and lines[0][1:] == lines[1][1:], out       # the same errors


@pytest.mark.shared
def test_the_re_filter_that_tune_runs_takes_the_m_filter(realphone_dir):
    prepared = open_log(realphone_dir / "tsrt14_lab2_rotation.txt")
    mine = refilter(prepared, COURSE, str(COURSE_M))
    ours = refilter(prepared, COURSE, "course")
    assert np.max(np.abs(mine.rows.quat - ours.rows.quat)) < 1e-9
    assert mine.errors.summary.total_rmse_deg == pytest.approx(
        ours.errors.summary.total_rmse_deg, abs=1e-9)


def test_an_m_file_names_its_folder_and_folders_are_estimator_names(tmp_path):
    assert estimator_names(f"course,{COURSE_M}") == ["course", str(COURSE_M)]
    assert estimator_names(str(COURSE_M / "tu_qw.m")) == [str(COURSE_M / "tu_qw.m")]
    assert octave.filter_folder(COURSE_M / "mu_g.m") == COURSE_M
    with pytest.raises(ConfigError, match="no such MATLAB filter"):
        estimator_names(str(tmp_path / "nothing" / "mu_g.m"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="this folder has none"):
        estimator_names(str(tmp_path / "empty"))


# ---- the template ----------------------------------------------------------------------------

def test_the_template_runs_as_written_and_says_what_is_not_written(tmp_path, log, capsys):
    folder = tmp_path / "mine"
    assert cli.main(["new-filter", "--matlab", str(folder)]) == 0
    assert "README.md" in capsys.readouterr().out
    assert sorted(p.name for p in folder.iterdir()) == sorted(p.name for p in template_files())
    somega = (folder / "Somega.m").read_text()
    assert "wy  -wz    0   wx;" in somega                       # eq. 2d, not the listing's typo
    with UserFilterEstimator(folder, COURSE) as mine:
        rows = filter_log(open_log(log), mine, COURSE)
        assert mine.problem is None
        assert [s.split(" ")[0] for s in mine.missing_steps()] == [
            "tu_qw", "mu_g", "mu_m", "mu_normalizeQ"]
        assert mine.missing_steps()[0] == "tu_qw (tu_qw.m:17)"
        assert "acc_outlier is not written yet: the course's test is used" in mine.notes
        assert "q is normalised for display: mu_normalizeQ is not written yet" in mine.notes
    # nothing written: the phone stays as it started (flat, heading from the first reading)
    assert np.all(np.isfinite(rows.quat))
    assert np.max(np.abs(rows.quat - rows.quat[0])) == 0.0
    # never overwritten
    (folder / "tu_qw.m").write_text("% mine")
    assert cli.main(["new-filter", "--matlab", str(folder)]) == 2
    assert "already; not overwritten" in capsys.readouterr().err
    assert (folder / "tu_qw.m").read_text() == "% mine"


def test_written_functions_run_and_the_rest_are_skipped(tmp_path, log):
    folder = tmp_path / "mine"
    cli.main(["new-filter", "--matlab", str(folder)])
    for name in ("tu_qw", "mu_normalizeQ"):
        (folder / f"{name}.m").write_bytes((COURSE_M / f"{name}.m").read_bytes())
    with UserFilterEstimator(folder, COURSE) as mine:
        rows = filter_log(open_log(log), mine, COURSE)
        assert [s.split(" ")[0] for s in mine.missing_steps()] == ["mu_g", "mu_m"]
    # the log turns about up at 0.5 rad/s after 1 s: with tu_qw written, so does YOURS
    heading = np.degrees(ekf.quaternion.to_euler(rows.quat))[:, 0]
    turned = (heading[-1] - heading[0] + 180) % 360 - 180
    assert turned == pytest.approx(math.degrees(0.5 * 1.99), abs=2.0)


def test_a_snapshot_restores_the_state_bit_for_bit_and_prints_reach_the_output(tmp_path, log):
    lines = []
    folder = matlab_filter(tmp_path, filter_settings="""
        function s = filter_settings(s)
          printf('hello from filter_settings\\n');
        end
    """)
    rows = open_log(log).to_arrays()
    t, gyr, acc, mag = rows.t_ms / 1000.0, rows.gyr, rows.acc, rows.mag
    half = len(t) // 2
    with UserFilterEstimator(folder, COURSE, on_output=lines.append) as mine:
        mine.run_batch(t[:half], gyr[:half], acc[:half], mag[:half])
        saved = mine.snapshot()
        first = mine.run_batch(t[half:], gyr[half:], acc[half:], mag[half:]).quat
        mine.restore(saved)
        again = mine.run_batch(t[half:], gyr[half:], acc[half:], mag[half:]).quat
        assert mine.problem is None
    assert np.array_equal(first, again)
    assert lines == ["hello from filter_settings"]


# ---- your settings and your outlier tests ---------------------------------------------------

def test_filter_settings_and_your_own_outlier_tests_are_used(tmp_path, log):
    folder = matlab_filter(tmp_path, filter_settings="""
        function s = filter_settings(s)
          s.m0 = [0; 10; -40];
          s.Ra = 2 * s.Ra;
        end
    """, acc_outlier="""
        function outlier = acc_outlier(yacc, g0, s)
          outlier = true;
        end
    """, mag_outlier="""
        function [outlier, L] = mag_outlier(mag, L, s)
          outlier = L > 0;
          L = L + 1;
        end
    """)
    with UserFilterEstimator(folder, COURSE) as mine:
        rows = filter_log(open_log(log), mine, COURSE)
        assert mine.problem is None and mine.notes == []
    started = slice(1, None)
    assert rows.acc_rejected[started].all() and rows.mag_rejected[started][1:].all()
    # every update skipped: only the time update moves q, from the start's orientation
    with UserFilterEstimator(matlab_filter(tmp_path / "plain"), COURSE) as plain:
        ours = filter_log(open_log(log), plain, COURSE)
    assert not ours.acc_rejected.any()
    assert not np.allclose(rows.quat, ours.quat)


def test_an_error_in_filter_settings_names_its_line(tmp_path, log):
    folder = matlab_filter(tmp_path, filter_settings="""
        function s = filter_settings(s)
          s.Ra = eye(2);
        end
    """)
    with UserFilterEstimator(folder, COURSE) as mine:
        filter_log(open_log(log), mine, COURSE)
        problem = mine.problem
    assert problem.message == ("filter_settings.m in filter_settings: filter_settings: s.Ra must "
                               "be a finite 3x3 matrix (got 2x2 double)")


# ---- errors in MATLAB terms ------------------------------------------------------------------

@pytest.mark.parametrize("broken, message, line", [
    ("syntax", "mu_g.m:3: parse error: syntax error", 3),
    ("runtime", "mu_g.m:4 in mu_g: operator *: nonconformant arguments (op1 is 4x4, op2 is 3x4)",
     4),
    ("wrong_size", "tu_qw.m: tu_qw returned x of size 1x4 and P of size 4x4, expected x 4x1 and "
                   "P 4x4 at t = ", None),
    ("not_finite", "mu_m.m: mu_m returned a non-finite x = [NaN NaN NaN NaN] at t = ", None),
    ("keyboard", "mu_m.m:2 in mu_m: input(): a filter has no keyboard", 2),
])
def test_each_error_says_where_in_matlab_terms(tmp_path, log, broken, message, line):
    folder = matlab_filter(tmp_path, broken)
    try:
        mine = UserFilterEstimator(folder, COURSE)
    except UserFilterError as error:       # a syntax error: the folder does not load
        problem = error.problem
        assert broken == "syntax" and problem.kind == "load"
    else:
        with mine:
            rows = filter_log(open_log(log), mine, COURSE)
            problem = mine.problem
        assert np.isfinite(rows.quat).all()                # the rows after it keep the last one
    assert problem.message.startswith(message), problem.message
    assert problem.line == line
    assert Path(problem.file).parent == folder             # the user's folder, not the copy


def test_an_endless_loop_is_stopped_by_the_deadline(tmp_path, log):
    with UserFilterEstimator(matlab_filter(tmp_path, "endless"), COURSE,
                             deadline_s=1.0) as mine:
        filter_log(open_log(log), mine, COURSE)
        problem = mine.problem
    assert problem.kind == "stuck"
    assert problem.message == ("course: Octave has not come back from your functions for 1 s "
                               "(an endless loop?): paused; save a .m file to restart it")


def test_octave_ending_pauses_your_filter_with_the_reason(tmp_path, log):
    with UserFilterEstimator(matlab_filter(tmp_path, "crash"), COURSE) as mine:
        rows = filter_log(open_log(log), mine, COURSE)
        problem = mine.problem
    assert problem.kind == "ended"
    assert problem.message == ("course: Octave ended (exit status 7): paused; save a .m file to "
                               "restart it")
    assert np.isfinite(rows.quat[:10]).all()


def test_octave_not_installed_says_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setattr(octave, "_chosen", None)
    octave.use_octave(tmp_path / "no-octave-here")
    try:
        with pytest.raises(UserFilterError) as caught:
            UserFilterEstimator(COURSE_M, COURSE)
    finally:
        octave.use_octave(None)
    message = caught.value.problem.message
    assert message.startswith(f"course: Octave not found at {tmp_path / 'no-octave-here'}: "
                              "install GNU Octave")
    assert "\n" not in message
    for platform, words in (("linux", "apt-get install octave"), ("darwin", "brew install octave"),
                            ("win32", "octave.org/download")):
        assert words in octave.install_hint(platform)
