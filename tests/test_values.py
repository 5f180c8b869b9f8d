"""Every file and value a user hands the program: checked against its declaration, one line and
exit status 2 when wrong, never a traceback, never a silent wrong answer (settings, profiles,
session.json, logs, the data folder)."""

from __future__ import annotations

import gzip
import json
import math
import shutil
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings as hsettings, strategies as st

import ekf
from ekf.settings import MAX_FILE_BYTES, PRESETS, EKFSettings, SettingsError
from ekf.simulate import simulate
from app import cli
from app.engine.tuning.profiles import KIND, Profile, ProfileStore
from app.stream.protocol import Sample, format_line

SETTING_FIELDS = {f.name: f for f in fields(EKFSettings)}


def _write_log(path: Path, seconds: float = 4.0, seed: int = 3, tags: tuple[str, ...] | None = None,
               twice: bool = False) -> Path:
    data = simulate(duration_s=seconds, rates_hz={"gyr": 50.0, "acc": 50.0, "mag": 25.0,
                                                  "ori": 50.0}, seed=seed)
    lines = []
    for t, tag, values in data.iter_rows():
        if tags is None or tag in tags:
            line = (format_line(Sample(t, tag, values)) + "\n").encode()
            lines.append(line + line if twice else line)
    path.write_bytes(b"".join(lines))
    return path


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    return _write_log(tmp_path_factory.mktemp("values") / "log.txt")


def _run(capsys, argv: list[str]) -> tuple[int, str, str]:
    capsys.readouterr()
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _one_line_error(code: int, err: str, *needles: str) -> None:
    assert code == 2, err
    lines = [line for line in err.splitlines() if line.startswith("orientation-lab: error:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]


# ---- a settings file: the preset it names, then its values ----------------------------------------

def test_missing_keys_come_from_the_default_preset_or_the_one_named():
    assert EKFSettings.from_dict({}) == PRESETS["default"]
    assert EKFSettings.from_dict({"acc_lowpass_s": 0.75}) == PRESETS["default"]
    assert EKFSettings.from_dict({"acc_gate": 3}) == PRESETS["default"].with_changes(acc_gate=3.0)
    assert EKFSettings.from_dict({"preset": "course"}) == PRESETS["course"]
    assert (EKFSettings.from_dict({"preset": "course", "g": 9.8})
            == PRESETS["course"].with_changes(g=9.8))
    with pytest.raises(SettingsError, match="preset = \"fast\": must be 'default' or 'course'"):
        EKFSettings.from_dict({"preset": "fast"})


def test_a_one_key_settings_file_scores_as_the_default_with_that_key(tmp_path, log, capsys):
    scores = {}
    for name, content in [("default", None), ("empty", {}), ("same", {"acc_lowpass_s": 0.75})]:
        spec = "default" if content is None else tmp_path / f"{name}.json"
        if content is not None:
            spec.write_text(json.dumps(content))
        code, out, _ = _run(capsys, ["evaluate", log, "--settings", spec])
        assert code == 0
        scores[name] = out.splitlines()[-1].split()[2]
    assert scores["default"] == scores["empty"] == scores["same"]


@pytest.mark.parametrize("key,value,allowed", [
    ("g", "abc", "a finite number 1..100"), ("g", [9.8], "a finite number 1..100"),
    ("g", {"a": 1}, "a finite number 1..100"), ("g", True, "a finite number 1..100"),
    ("g", 0, "1..100"), ("g", -9.81, "1..100"), ("g", 3.5e-187, "1..100"), ("acc_gate", -1, '≥ 0 or "inf"'),
    ("exact_discretisation", "yes", "true or false"), ("mag_alpha", 1.5, "0..1"),
    ("mag_strength_update", "sometimes", "'always' or 'accepted'"),
    ("gyr_noise_cov", [[-1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 1e-4]], "positive-definite"),
    ("acc_noise_cov", [[0, 0, 0], [0, 0, 0], [0, 0, 0]], "positive-definite"),
    ("mag_noise_cov", [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]], "symmetric"),
    ("acc_noise_cov", [[1.0, 0.0], [0.0, 1.0]], "3x3"),
    ("mag_soft_iron", [[1, 0, 0], [0, 0, 0], [0, 0, 1]], "invertible"),
    ("m0", [0, 0, 0], "with a horizontal part"), ("m0", [1, 2], "3 finite numbers"),
    ("gyr_bias", [0, 0, "x"], "3 finite numbers"),
])
def test_a_value_a_setting_does_not_allow_is_one_line_naming_key_value_and_rule(
        tmp_path, log, capsys, key, value, allowed):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({key: value}))
    code, out, err = _run(capsys, ["filter", log, "--settings", path, "-o", tmp_path / "o.csv"])
    _one_line_error(code, err, f"setting {key} = ", allowed)
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("text", ['{"g": NaN}', '{"g": 1e400}', '{"max_dt": -Infinity}'])
def test_json_nan_and_overflow_are_refused(tmp_path, log, capsys, text):
    path = tmp_path / "s.json"
    path.write_text(text)
    code, _, err = _run(capsys, ["evaluate", log, "--settings", path])
    _one_line_error(code, err, "setting ")


def test_inf_is_allowed_where_the_declaration_says_so():
    s = EKFSettings.from_dict({"acc_gate": "inf", "mag_nis_gate": float("inf")})
    assert math.isinf(s.acc_gate) and math.isinf(s.mag_nis_gate)
    assert EKFSettings.from_dict(s.to_dict()) == s
    with pytest.raises(SettingsError, match="acc_lowpass_s"):
        EKFSettings.from_dict({"acc_lowpass_s": "inf"})


def test_every_construction_is_checked_not_only_files():
    with pytest.raises(SettingsError, match="setting g = -1"):
        PRESETS["default"].with_changes(g=-1)
    assert isinstance(PRESETS["default"].with_changes(g=10).g, float)


def test_a_huge_or_endless_settings_file_is_refused_without_reading_it_all(tmp_path, log, capsys):
    big = tmp_path / "big.json"
    big.write_text('{"g": 9.81' + " " * (MAX_FILE_BYTES + 10) + "}")
    code, _, err = _run(capsys, ["evaluate", log, "--settings", big])
    _one_line_error(code, err, "larger than 4 MB")
    code, _, err = _run(capsys, ["evaluate", log, "--settings", "/dev/zero"])
    _one_line_error(code, err, "larger than 4 MB")


# ---- the property: any JSON value of any setting -------------------------------------------------

_json_value = st.recursive(
    st.none() | st.booleans() | st.integers(-10**6, 10**6)
    | st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from(
        ["inf", "abc", "always", "accepted", "", "-inf"]),
    lambda inner: st.lists(inner, max_size=4), max_leaves=10)


def _plausible(name: str) -> st.SearchStrategy:
    """A value near what the setting allows (so that many examples pass the check and run)."""
    f = SETTING_FIELDS[name]
    if f.metadata["shape"] == (3, 3):
        return st.lists(st.lists(st.floats(-2, 2), min_size=3, max_size=3), min_size=3,
                        max_size=3) | st.floats(1e-6, 10).map(
            lambda d: [[d, 0, 0], [0, d, 0], [0, 0, d]])
    if f.metadata["shape"] == (3,):
        return st.lists(st.floats(-60, 60), min_size=3, max_size=3)
    if isinstance(f.default, bool):
        return st.booleans()
    if f.metadata["choices"]:
        return st.sampled_from(f.metadata["choices"])
    return st.floats(-1, 30) | st.sampled_from([0, 1e-9, 1e9, "inf"])


@st.composite
def _settings_json(draw) -> dict:
    names = draw(st.lists(st.sampled_from(sorted(SETTING_FIELDS)), min_size=1, max_size=3,
                          unique=True))
    return {name: draw(_plausible(name) | _json_value) for name in names}


@hsettings(max_examples=40, deadline=None,
           suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(values=_settings_json())
def test_any_settings_file_gives_finite_estimates_or_one_line(tmp_path, log, capsys, values):
    path = tmp_path / "s.json"
    path.write_text(json.dumps(values))
    out = tmp_path / "o.csv"
    out.unlink(missing_ok=True)
    code, _, err = _run(capsys, ["filter", log, "--settings", path, "-o", out])
    if code == 0:
        rows = np.loadtxt(out, delimiter=",", skiprows=1)
        assert len(rows) > 0 and np.isfinite(rows).all(), values
    else:
        _one_line_error(code, err, "setting ")


# ---- profiles ----------------------------------------------------------------------------------

@pytest.mark.parametrize("changes,needle", [
    ({"rest": "bad"}, "rest must be an object"),
    ({"mag": {"offset": [1.0, 2.0], "soft_iron": np.eye(3).tolist()}},
     "not one this program writes"),
    ({"rest": {"acc": {"mean": [0, 0]}}}, "not one this program writes"),
    ({"settings": {"g": "x"}}, "setting g = \"x\""),
])
def test_a_damaged_profile_is_one_line(tmp_path, log, capsys, changes, needle):
    data = {"kind": KIND, "name": "phone"} | changes
    path = tmp_path / "p.json"
    path.write_text(json.dumps(data))
    code, _, err = _run(capsys, ["evaluate", log, "--settings", path])
    _one_line_error(code, err, needle)


def test_a_profiles_settings_start_from_the_preset_it_names():
    profile = Profile("p", settings={"preset": "course", "g": 9.7})
    assert profile.to_settings() == PRESETS["course"].with_changes(g=9.7)
    assert Profile("p", settings={"g": 9.7}).to_settings() == \
        PRESETS["default"].with_changes(g=9.7)


def test_a_data_folder_that_is_a_file_is_one_line(tmp_path, log, capsys, monkeypatch):
    not_a_folder = tmp_path / "data"
    not_a_folder.write_text("x")
    monkeypatch.setenv("ORIENTATION_LAB_DATA", str(not_a_folder))
    for argv in (["evaluate", log, "--settings", "profile:phone"],
                 ["calibrate", log, "--profile", "phone"], ["filter", log]):
        code, _, err = _run(capsys, argv)
        _one_line_error(code, err, "is a file, not a folder", "ORIENTATION_LAB_DATA")
    monkeypatch.setenv("ORIENTATION_LAB_DATA", str(tmp_path / "fine"))
    ProfileStore().save(Profile("phone"))
    assert _run(capsys, ["evaluate", log, "--settings", "profile:phone"])[0] == 0


# ---- logs ----------------------------------------------------------------------------------------

def test_a_gzip_header_followed_by_garbage_is_one_line(tmp_path, log, capsys):
    bad = tmp_path / "bad.txt.gz"
    bad.write_bytes(gzip.compress(log.read_bytes())[:10] + b"garbage" * 50)
    for argv in (["filter", bad, "-o", tmp_path / "o.csv"], ["evaluate", bad],
                 ["export", bad, "--format", "csv", "-o", tmp_path / "e.csv"],
                 ["send", bad, "--port", "1"]):
        code, _, err = _run(capsys, argv)
        _one_line_error(code, err, "damaged or incomplete gzip")


@pytest.mark.parametrize("tags,needle", [(("ORI",), "no GYR, ACC or MAG"),
                                         (("MAG",), "without accelerometer"),
                                         (("GYR", "MAG", "ORI"), "without accelerometer")])
def test_a_log_no_estimate_can_be_made_from_is_one_line(tmp_path, capsys, tags, needle):
    path = _write_log(tmp_path / "part.txt", tags=tags)
    for argv in (["filter", path, "-o", tmp_path / "o.csv"], ["evaluate", path]):
        code, out, err = _run(capsys, argv)
        _one_line_error(code, err, "no estimate can be made", needle)
        assert out == ""                    # no table header before the error
    assert not (tmp_path / "o.csv").exists()


def test_sensors_switched_off_that_the_log_holds_alone_is_one_line(tmp_path, capsys):
    path = _write_log(tmp_path / "acc.txt", tags=("ACC", "ORI"))
    code, _, err = _run(capsys, ["evaluate", path, "--sensors", "gyr,mag"])
    _one_line_error(code, err, "none of --sensors gyr,mag")


# ---- sessions -------------------------------------------------------------------------------------

@pytest.fixture()
def session(tmp_path, log) -> Path:
    folder = tmp_path / "session"
    folder.mkdir()
    shutil.copy(log, folder / "raw.txt")
    (folder / "session.json").write_text(json.dumps({
        "format": 2, "settings": PRESETS["course"].to_dict(), "estimator": "ekf",
        "timeline": [{"kind": "marker", "id": 1, "label": "a", "t_s": 1.0, "t_ms": None,
                      "sample": 10}]}))
    return folder


def _damage(folder: Path, **changes) -> None:
    path = folder / "session.json"
    data = json.loads(path.read_text())
    data.update(changes)
    path.write_text(json.dumps(data))


@pytest.mark.parametrize("changes,needle", [
    ({"format": 3}, "session format 3 is newer than this program reads (2)"),
    ({"format": 99}, "newer than this program reads"), ({"format": "x"}, "format = \"x\""),
    ({"timeline": 5}, "timeline = 5"), ({"estimator": 5}, "estimator = 5"),
    ({"estimator": "nosuch"}, "estimator = \"nosuch\""),
    ({"start_state": {"junk": 1}}, "start_state"),
    ({"start_state": {"runner": {}, "orderer": {}}}, "start_state is not an engine state"),
    ({"timeline": [{"kind": "marker", "id": "x", "t_ms": None}]}, "timeline[0].id = \"x\""),
    ({"timeline": [{"kind": "settings", "settings": {"g": "x"}, "sample": 3}]},
     "timeline[0]: setting g = \"x\""),
    ({"timeline": [{"kind": "sensor", "sensor": "baro", "enabled": True}]}, "sensor"),
    ({"settings": {"g": -1}}, "setting g = -1"), ({"sensors": {"gyr": "on"}}, "sensors"),
    ({"raw_file": "../../etc/passwd"}, "raw_file"),
])
def test_a_damaged_session_json_is_one_line_everywhere(session, tmp_path, capsys, changes,
                                                       needle):
    _damage(session, **changes)
    for argv in (["export", session, "--format", "csv", "-o", tmp_path / "e.csv"],
                 ["filter", session, "-o", tmp_path / "o.csv"], ["evaluate", session]):
        code, _, err = _run(capsys, argv)
        _one_line_error(code, err, "session.json", needle)


def test_filter_and_evaluate_use_a_sessions_recorded_settings(session, tmp_path, capsys):
    code, out, err = _run(capsys, ["evaluate", session])
    assert code == 0 and "settings: the session's recorded settings" in out
    recorded = out.splitlines()[-1].split()[2]
    course = _run(capsys, ["evaluate", session / "raw.txt", "--settings", "course"])[1]
    default = _run(capsys, ["evaluate", session, "--settings", "default"])[1]
    assert "settings: --settings default" in default
    assert recorded == course.splitlines()[-1].split()[2]
    assert recorded != default.splitlines()[-1].split()[2]
    code, _, err = _run(capsys, ["filter", session, "-o", tmp_path / "o.csv"])
    assert code == 0 and "settings: the session's recorded settings" in err


def test_a_huge_session_json_is_refused(session, tmp_path, capsys):
    (session / "session.json").write_text('{"format": 2' + " " * (MAX_FILE_BYTES + 1) + "}")
    code, _, err = _run(capsys, ["evaluate", session])
    _one_line_error(code, err, "larger than 4 MB")


_session_value = st.recursive(
    st.none() | st.booleans() | st.integers(-3, 300) | st.floats(allow_nan=True)
    | st.sampled_from(["ekf", "course", "nosuch", "marker", "settings", "sensor", "gyr", "x"]),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(
        st.sampled_from(["kind", "id", "sample", "t_ms", "t_s", "label", "sensor", "enabled",
                         "name", "settings", "runner", "orderer", "g", "estimator"]),
        inner, max_size=4), max_leaves=12)


@hsettings(max_examples=30, deadline=None,
           suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(changes=st.dictionaries(st.sampled_from(
    ["format", "settings", "estimator", "sensors", "comparisons", "timeline", "start_state",
     "raw_file"]), _session_value, min_size=1, max_size=3))
def test_any_session_json_shape_exports_or_is_one_line(session, tmp_path, capsys, changes):
    original = (session / "session.json").read_text()
    try:
        _damage(session, **changes)
        out = tmp_path / "e.csv"
        out.unlink(missing_ok=True)
        code, _, err = _run(capsys, ["export", session, "--format", "csv", "-o", out])
        if code == 0:
            assert out.stat().st_size > 0
        else:
            _one_line_error(code, err)
    finally:
        (session / "session.json").write_text(original)


# ---- a user's filter that tries to end the program ---------------------------------------------

_FILTERS = {
    "exits_at_import.py": "import sys\nsys.exit(3)\n",
    "exits_in_step.py": ("import sys\nclass Filter:\n    def step(self, t, gyr, acc, mag):\n"
                         "        sys.exit(4)\n"),
    "interrupts.py": ("class Filter:\n    def step(self, t, gyr, acc, mag):\n"
                      "        raise KeyboardInterrupt\n"),
    "ends_process.py": ("import os\nclass Filter:\n    def step(self, t, gyr, acc, mag):\n"
                        "        os._exit(0)\n"),
}


def _cli_process(*argv) -> "subprocess.CompletedProcess":
    import subprocess
    import sys
    return subprocess.run([sys.executable, "-m", "app", *map(str, argv)], capture_output=True,
                          text=True, timeout=120, cwd=Path(__file__).resolve().parents[1])


@pytest.mark.parametrize("name,code,needle", [
    ("exits_at_import.py", 2, "exits_at_import.py:2 in <module>: SystemExit(3)"),
    ("exits_in_step.py", 1, "exits_in_step.py:4 in step: SystemExit(4)"),
    ("interrupts.py", 1, "interrupts.py:3 in step: KeyboardInterrupt"),
    ("ends_process.py", 1, "your filter ended the process"),
])
def test_a_filter_ending_the_program_is_a_user_error_reported_as_one(tmp_path, log, name, code,
                                                                     needle):
    path = tmp_path / name
    path.write_text(_FILTERS[name])
    out = tmp_path / "o.csv"
    result = _cli_process("filter", log, "--estimator", path, "-o", out)
    assert result.returncode == code, result.stderr
    assert needle in result.stderr and "Traceback" not in result.stderr
    assert not out.exists()
    result = _cli_process("evaluate", log, "--estimator", f"ekf,{path}")
    assert result.returncode == code, result.stderr
    assert needle in result.stderr
    if code == 1:   # the built-in estimator's row is there, the user's filter's is not
        assert any(line.startswith("ekf ") for line in result.stdout.splitlines())


# ---- samples repeated exactly ----------------------------------------------------------------

def test_a_log_with_every_line_twice_gives_the_logs_estimates(tmp_path, log, capsys):
    twice = tmp_path / "twice.txt"
    twice.write_bytes(b"".join(line + line for line in log.read_bytes().splitlines(True)))
    once_csv, twice_csv = tmp_path / "once.csv", tmp_path / "twice.csv"
    assert _run(capsys, ["filter", log, "-o", once_csv])[0] == 0
    code, _, err = _run(capsys, ["filter", twice, "-o", twice_csv])
    assert code == 0
    lines = len(log.read_bytes().splitlines())
    assert f"{lines} samples repeated exactly (each used once)" in err
    assert twice_csv.read_bytes() == once_csv.read_bytes()


def test_a_sample_at_the_same_time_with_other_values_is_no_repeat(tmp_path, capsys):
    lines = [b"1000\tACC\t0.1\t0.2\t9.8\n", b"1000\tGYR\t0.0\t0.0\t0.0\n",
             b"1000\tACC\t0.1\t0.2\t9.7\n", b"1000\tACC\t0.1\t0.2\t9.8\n",
             b"1010\tACC\t0.1\t0.2\t9.8\n"]
    path = tmp_path / "same_time.txt"
    path.write_bytes(b"".join(lines * 1))
    from app.stream.logfile import read_log
    data = read_log(path)
    assert data.stats.repeated == 1
    assert data.values[data.tag == 1, 2].tolist() == pytest.approx(
        [9.8, 9.7, 9.8, 9.8], abs=1e-6)


@hsettings(max_examples=200, deadline=None)
@given(rows=st.lists(st.tuples(st.integers(0, 3), st.integers(0, 3), st.integers(0, 2)),
                     max_size=40),
       cuts=st.lists(st.integers(0, 40), max_size=5))
def test_repeats_match_a_plain_set_of_seen_samples_however_the_stream_is_cut(rows, cuts):
    from app.stream.ordering import repeats
    rows = sorted(rows, key=lambda r: r[0])       # release times never go back
    t = np.array([r[0] for r in rows], np.int64)
    g = np.array([r[1] for r in rows], np.int64)
    v = np.array([[r[2], 0.0, 0.0, np.nan] for r in rows])
    seen, expected = set(), []
    for row in rows:
        expected.append(row in seen)
        seen.add(row)
    mask, last = [], None
    bounds = [0] + sorted(c for c in cuts if c <= len(rows)) + [len(rows)]
    for start, end in zip(bounds, bounds[1:]):
        piece, last = repeats(t[start:end], g[start:end], v[start:end], last)
        mask += piece.tolist()
    assert mask == expected
