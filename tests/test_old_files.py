"""Settings files, profiles and recorded sessions written before the settings were grouped
(by main at fa86688, tests/files_before_groups/README.md) load into the settings they were
written from and give the estimates they gave then."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import ekf
from app.cli import main
from app.engine import config
from app.engine.tuning.profiles import Profile, load_profile

OLD = Path(__file__).resolve().parent / "files_before_groups"
SESSION = OLD / "session"
# The values settings.json and the session were written from: one non-default value in every
# part of the filter, on the default preset.
VALUES = json.loads((OLD / "values.json").read_text())
PARTIAL = {"acc_lowpass_s": 0.5, "acc_noise_adapt": 40.0, "mag_gate": math.inf,
           "estimate_gyro_bias": True, "mag_strength_update": "accepted", "mag_relearn_s": 8.0}


def _from_values() -> ekf.EKFSettings:
    return ekf.PRESETS["default"].with_changes(**VALUES)


def _profile_from_values() -> Profile:
    """The profile profiles/Old_phone_desk.json was written from."""
    rest = {"acc": {"mean": [0.12, -0.05, 9.79], "cov": np.diag([2e-3, 2.5e-3, 3e-3]).tolist()},
            "gyr": {"mean": [0.0101, -0.0198, 0.0052],
                    "cov": np.diag([1e-5, 1.2e-5, 9e-6]).tolist()},
            "mag": {"mean": [7.5, 13.5, -48.0], "cov": np.diag([0.3, 0.35, 0.4]).tolist()}}
    mag = {"offset": [1.5, -2.0, 0.5], "nothing_to_correct": False,
           "soft_iron": [[1.02, 0.01, 0.0], [0.01, 0.98, 0.0], [0.0, 0.0, 1.0]]}
    settings = ekf.PRESETS["default"].with_changes(acc_gate=3.0, mag_return_s=5.0,
                                                   mag_hard_iron_tau_s=120.0)
    return Profile("Old phone (desk)", rest=rest, mag=mag, settings=settings.to_dict())


def _rows(raw: Path) -> tuple[np.ndarray, ...]:
    """The recorded lines as rows for ekf.filter_batch: one row per GYR, ACC or MAG line."""
    t, columns = [], {"GYR": [], "ACC": [], "MAG": []}
    for line in raw.read_text().splitlines():
        parts = line.split("\t")
        if parts[1] not in columns:
            continue
        t.append(int(parts[0]) / 1000.0)
        for tag, values in columns.items():
            values.append([float(x) for x in parts[2:5]] if tag == parts[1] else [math.nan] * 3)
    return (np.array(t),) + tuple(np.array(columns[tag]) for tag in ("GYR", "ACC", "MAG"))


def _same_estimates_bit_for_bit(a: ekf.EKFSettings, b: ekf.EKFSettings) -> None:
    t, gyr, acc, mag = _rows(SESSION / "raw.txt")
    first, second = ekf.filter_batch(t, gyr, acc, mag, a), ekf.filter_batch(t, gyr, acc, mag, b)
    assert np.array_equal(first.quat, second.quat)
    assert not np.array_equal(first.quat, ekf.filter_batch(t, gyr, acc, mag).quat)


def _filtered(tmp_path: Path, log: Path, *settings: str) -> str:
    out = tmp_path / "estimates.csv"
    assert main(["filter", str(log), *settings, "-o", str(out)]) == 0
    return out.read_text()


def test_an_old_settings_file_loads_the_values_it_was_written_from(tmp_path):
    assert set(json.loads((OLD / "settings.json").read_text())) == set(VALUES)  # every setting
    loaded = ekf.EKFSettings.load(OLD / "settings.json")
    assert loaded == _from_values()
    assert config.load_settings(OLD / "settings.json") == loaded
    _same_estimates_bit_for_bit(loaded, _from_values())
    assert (_filtered(tmp_path, SESSION / "raw.txt", "--settings", str(OLD / "settings.json"))
            == (SESSION / "estimates.csv").read_text())


def test_an_old_partial_settings_file_on_the_course_preset_gives_its_estimates(tmp_path):
    loaded = config.load_settings(OLD / "settings_partial.json")
    assert loaded == ekf.PRESETS["course"].with_changes(**PARTIAL)
    _same_estimates_bit_for_bit(loaded, ekf.PRESETS["course"].with_changes(**PARTIAL))
    assert (_filtered(tmp_path, SESSION / "raw.txt", "--settings",
                      str(OLD / "settings_partial.json"))
            == (OLD / "estimates_settings_partial.csv").read_text())


def test_an_old_profile_gives_the_settings_and_estimates_it_gave(tmp_path):
    path = OLD / "profiles" / "Old_phone_desk.json"
    profile = load_profile(path)
    assert profile.name == "Old phone (desk)"
    written = _profile_from_values().to_settings()
    assert profile.to_settings() == written
    assert config.load_settings(path) == written
    _same_estimates_bit_for_bit(profile.to_settings(), written)
    assert (_filtered(tmp_path, SESSION / "raw.txt", "--settings", str(path))
            == (OLD / "estimates_profile.csv").read_text())


def test_an_old_session_replays_with_its_settings_and_its_recorded_estimates(tmp_path):
    loaded = config.load_settings(SESSION / "session.json")
    assert loaded == _from_values()
    _same_estimates_bit_for_bit(loaded, _from_values())
    recorded = (SESSION / "estimates.csv").read_text()
    assert _filtered(tmp_path, SESSION) == recorded
    assert _filtered(tmp_path, SESSION / "raw.txt", "--settings",
                     str(SESSION / "session.json")) == recorded
