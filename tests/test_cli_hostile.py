"""Hostile offline inputs (issue 46 items 5, 6, 11): one line on stderr and exit status 2,
never a traceback, never exit 0 with nothing usable; and a property test over the command
line's numeric options."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import ekf.simulate
from app import cli
from app.cli import build_parser
from app.stream.demo import write_session
from app.stream.logfile import read_log
from ekf.simulate import simulate


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hostile")
    log = folder / "walk.txt"
    write_session(simulate(duration_s=22, seed=3), log)
    rest = folder / "rest.txt"
    write_session(simulate(duration_s=6, script="rest", seed=4), rest)
    lines = rest.read_text().splitlines()

    def rewrite(name: str, change) -> None:
        out = []
        for line in lines:
            fields = line.split("\t")
            change(fields)
            out.append("\t".join(fields))
        (folder / name).write_text("\n".join(out) + "\n")

    def gyr_z_zero(fields: list[str]) -> None:
        if fields[1] == "GYR":
            fields[4] = "0.0"

    def constant(fields: list[str]) -> None:
        fixed = {"GYR": ["0.001", "0.002", "0.003"], "ACC": ["0.1", "0.2", "9.8"],
                 "MAG": ["10.0", "20.0", "-30.0"]}
        if fields[1] in fixed:
            fields[2:5] = fixed[fields[1]]

    rewrite("rest_gyr_z.txt", gyr_z_zero)
    rewrite("constant.txt", constant)
    (folder / "brackets.json").write_text("[" * 100_000)
    session = folder / "session"
    session.mkdir()
    (session / "raw.txt").write_bytes(log.read_bytes())
    (session / "session.json").write_text("[" * 100_000)
    for name, intervals in (("letters", ["ab", "cd"]), ("reversed", [[5000, 1000]]),
                            ("empty", []), ("outside", [[1, 2]])):
        (folder / f"{name}.json").write_text(json.dumps({"score_intervals_ms": intervals}))
    (folder / "nan.json").write_text('{"score_intervals_ms": [[NaN, 1000]]}')
    return folder


def _one_line(capsys, argv: list[str]) -> str:
    capsys.readouterr()
    try:
        code = cli.main(argv)
    except SystemExit as error:              # argparse's own errors
        code = error.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert len(err) >= 1 and err[-1].startswith("orientation-lab")
    assert not any("Traceback" in line for line in err)
    # what comes before the error line is the log's summary, never more
    assert all(re.match(r"\S+\.txt: \d+ lines|\S+: settings: ", line) for line in err[:-1]), err
    return err[-1]


@pytest.mark.parametrize("argv, needle", [
    # item 5: tracebacks
    (["filter", "{walk}", "--settings", "{brackets}"], "nested too deeply"),
    (["filter", "{session}"], "nested too deeply"),
    (["export", "{session}", "--format", "csv", "-o", "{out}"], "nested too deeply"),
    (["evaluate", "{walk}", "--intervals", "{letters}"], 'interval 1 is "ab"'),
    (["calibrate", "{rest_gyr_z}", "--settings", "course", "-o", "{out}"],
     "gyr z is constant"),
    (["simulate", "-o", "{out}", "--seed", "-1"], "--seed: expected a whole number >= 0"),
    (["simulate", "-o", "{out}", "--duration", "1e9"], "20,000,000 a session may have"),
    (["simulate", "-o", "{out}", "--rate", "1e9"], "at most 1000 Hz"),
    # item 6: exit 0 with nothing usable
    (["evaluate", "{walk}", "--intervals", "{reversed}"], "ends before it starts"),
    (["evaluate", "{walk}", "--intervals", "{nan}"], "interval 1 is [NaN, 1000]"),
    (["evaluate", "{walk}", "--intervals", "{empty}"], "non-empty list"),
    (["evaluate", "{walk}", "--intervals", "{outside}"], "no reference sample to score"),
    (["evaluate", "{walk}", "--skip", "1e308"], "no reference sample to score"),
    (["tune", "{walk}", "--range", "500:600"], "starts after the log's end (22.0 s)"),
    (["tune", "{walk}", "--range", "0:10", "--check-range", "30:"], "--check-range 30:"),
    (["tune", "{walk}", "--params", "acc_noise_cov=0:1", "-o", "{out}"], "0 is not allowed"),
    (["tune", "{walk}", "--params", "acc_noise_cov=1e300:1e308", "-o", "{out}"],
     "1e+308 is not allowed"),
    (["simulate", "-o", "{out}", "--rate", "0.001"], "fewer than 2 samples"),
    (["simulate", "-o", "{out}", "--gyro-bias", "nan", "0", "0"], "expected a finite number"),
    (["calibrate", "{constant}"], "acc x, acc y, acc z, gyr x, gyr y, gyr z, mag x, mag y, "
                                  "mag z are constant"),
    # item 11: readable messages
    (["export", "{walk}", "--format", "csv", "-o", "{out}", "--from", "1e308"],
     "the range ends (21.995 s) before it starts (1e+308 s)"),
    (["export", "{walk}", "--format", "csv", "-o", "{out}", "--from", "1e308", "--to", "1e308"],
     "no samples from 1e+308 s to 1e+308 s: the session runs from 0.000 s to 21.995 s"),
    (["serve", "--allow", "10.0.0.0/99"], "argument --allow: not an address or network"),
    (["serve", "--record-max-mb", "1e308"], "expected a size in MB from 0"),
])
def test_hostile_input_is_one_line_and_exit_2(files, tmp_path, capsys, argv, needle):
    names = {p.stem: str(p) for p in files.iterdir()}
    out = tmp_path / "out"
    line = _one_line(capsys, [a.format(out=out, **names) for a in argv])
    assert needle in line
    assert len(line) < 400 and not re.search(r"\d{20}", line)
    assert not out.exists()                           # nothing written


def test_tune_never_writes_settings_filter_refuses(files, tmp_path, capsys):
    """Was: tune over a declared but absurd range wrote settings that `filter` refuses."""
    out = tmp_path / "tuned.json"
    line = _one_line(capsys, ["tune", str(files / "walk.txt"), "--params",
                              "acc_noise_cov=1e200:1e300", "--max-evals", "4", "--no-check",
                              "-o", str(out)])
    assert line.startswith("orientation-lab: error: tune: nothing written: the ekf estimate is "
                           "not finite")
    assert not out.exists()


def test_calibrate_still_writes_settings_from_live_sensors(files, tmp_path, capsys):
    out = tmp_path / "rest.json"
    assert cli.main(["calibrate", str(files / "rest.txt"), "--settings", "course", "-o",
                     str(out)]) == 0
    assert cli.main(["filter", str(files / "rest.txt"), "--settings", str(out), "-o",
                     str(tmp_path / "o.csv")]) == 0


# ---- a property test over the command line's numeric options --------------------------------

NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(min_value=-1e3, max_value=1e3).map(lambda v: f"{v:g}"),
    st.integers(-10**30, 10**30).map(str),
    st.sampled_from(["0", "-0", "1e308", "-1e308", "1e-308", "5e-324", "nan", "inf", "-inf",
                     "\uff19", "1_000", " 2", "0x10", "", "1e", "--1", "2**64",
                     "18446744073709551617"]))

OPTIONS = [
    ([], "--port"), ([], "--takeover-after"), ([], "--speed"), ([], "--record-max-mb"),
    ([], "--record-min-free-mb"), ([], "--exit-after"),
    (["serve"], "--port"), (["serve"], "--record-max-mb"), (["send", "x"], "--speed"),
    (["filter", "x"], "--limits"), (["evaluate", "x"], "--skip"),
    (["export", "x", "--format", "csv", "-o", "y"], "--from"),
    (["export", "x", "--format", "csv", "-o", "y"], "--to"),
    (["calibrate", "x"], "--range"), (["tune", "x"], "--max-evals"),
    (["simulate", "-o", "y"], "--duration"), (["simulate", "-o", "y"], "--rate"),
    (["simulate", "-o", "y"], "--mag-rate"), (["simulate", "-o", "y"], "--seed"),
]


@settings(max_examples=300, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(option=st.sampled_from(OPTIONS), text=NUMBERS)
def test_every_numeric_option_gives_a_usable_value_or_one_line(option, text, capsys):
    """Found: --record-max-mb 1e308 was an OverflowError traceback."""
    before, flag = option
    value = f"acc={text}" if flag == "--limits" else f"{text}:" if flag == "--range" else text
    capsys.readouterr()
    try:
        args = build_parser().parse_args([*before, f"{flag}={value}"])
    except SystemExit as error:
        err = capsys.readouterr().err.strip().splitlines()
        assert error.code == 2 and len(err) == 1 and "Traceback" not in err[0], err
        return
    parsed = getattr(args, flag.lstrip("-").replace("-", "_"), None)
    for number in _numbers(parsed):
        assert math.isfinite(number), (flag, text, parsed)


def _numbers(value) -> list[float]:
    if isinstance(value, (int, float)):
        return [float(value)]
    if isinstance(value, tuple) and value and all(isinstance(v, (int, float)) for v in value):
        return [float(v) for v in value if v != float("inf")]          # an open --range end
    return []


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(duration=NUMBERS, rate=NUMBERS, mag_rate=st.one_of(st.none(), NUMBERS), seed=NUMBERS)
@example(duration="2", rate="100", mag_rate=None, seed="0")         # a log written, every run
@example(duration="2", rate="2", mag_rate="1", seed="7")
def test_simulate_writes_a_log_the_program_reads_or_says_why_not(
        duration, rate, mag_rate, seed, tmp_path, capsys, monkeypatch):
    """simulate's numeric options: a log whose every line the program's own parser reads,
    with at least 2 samples of each sensor, or one line and exit 2 (nothing written). The
    size limit is lowered so that what it accepts stays quick to write."""
    monkeypatch.setattr(ekf.simulate, "MAX_SAMPLES", 4000)
    out = tmp_path / "sim.txt"
    out.unlink(missing_ok=True)
    argv = ["simulate", "-o", str(out), f"--duration={duration}", f"--rate={rate}",
            f"--seed={seed}"] + ([] if mag_rate is None else [f"--mag-rate={mag_rate}"])
    capsys.readouterr()
    try:
        code = cli.main(argv)
    except SystemExit as error:
        code = error.code
    err = capsys.readouterr().err.strip().splitlines()
    if code == 2:
        assert len(err) == 1 and "Traceback" not in err[0], err
        assert not out.exists()
        return
    assert code == 0, err
    log = read_log(out)
    parsed = log.stats.parse
    assert parsed.damaged == 0 and parsed.good == len(out.read_text().splitlines())
    assert min(parsed.per_tag.get(tag, 0) for tag in ("GYR", "ACC", "MAG", "ORI")) >= 2


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(skip=NUMBERS)
def test_evaluate_skip_gives_finite_figures_or_one_line(skip, files, capsys):
    capsys.readouterr()
    try:
        code = cli.main(["evaluate", str(files / "walk.txt"), f"--skip={skip}"])
    except SystemExit as error:
        code = error.code
    captured = capsys.readouterr()
    if code == 2:
        lines = captured.err.strip().splitlines()
        assert "Traceback" not in captured.err and lines[-1].startswith("orientation-lab")
        return
    assert code == 0
    row = next(line for line in captured.out.splitlines() if line.startswith("ekf "))
    samples, *figures = row.split()[1:]
    assert int(samples) > 0 and all(np.isfinite(float(f)) for f in figures)


def test_measured_values_the_filter_refuses_are_one_line(files, tmp_path, capsys, monkeypatch):
    """Was: a SettingsError traceback when the measured values made no valid settings."""
    from ekf.calibration import CalibrationResult
    from ekf.settings import SettingsError

    def refused(self, base=None, replace_noise=None):
        raise SettingsError("setting m0 = (0, 0, -48): must have a horizontal part")

    monkeypatch.setattr(CalibrationResult, "to_settings", refused)
    out = tmp_path / "rest.json"
    line = _one_line(capsys, ["calibrate", str(files / "rest.txt"), "-o", str(out)])
    assert "nothing written: the measured values are no settings the filter accepts" in line
    assert not out.exists()
