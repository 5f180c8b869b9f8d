"""Per-phone calibration profiles: named JSON files in the user's data folder (profiles/).

A profile keeps what the calibration workspace (or `calibrate`, `calibrate-mag`, `tune`) found
for one phone: the rest statistics (task 2: means, covariances, g, m0, gyro bias), the Allan
read-offs, the magnetometer correction, and optionally a whole set of settings (a tuned one).
:meth:`Profile.to_settings` turns it into filter settings ("Apply"); the engine records the
profile in the session (session.json "calibration") when it is applied with
``SetSettings(settings, calibration=profile.to_dict())``.

Qt-free: the window and the command line share it. Problems raise ConfigError (one line).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field, fields
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

import ekf
from ekf import magcal
from ekf.calibration import _level_rotation
from ekf.settings import read_json
from app import __version__, paths
from app.engine.errors import ConfigError

KIND = "orientation-lab profile"


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


@dataclass
class Profile:
    """name: the user's name for it (e.g. "Pixel 7, desk"); rest: the task-2 statistics
    (ekf.calibration.CalibrationResult.to_dict() form); allan: ekf.allan.AllanResult.to_dict();
    mag: ekf.magcal.MagCalibration.to_dict(); settings: a whole EKFSettings dict (a tuned set),
    used as the base when present; tuning: what the auto-tune did (ranges, figures); notes."""

    name: str
    rest: dict[str, Any] | None = None
    allan: dict[str, Any] | None = None
    mag: dict[str, Any] | None = None
    settings: dict[str, Any] | None = None
    tuning: dict[str, Any] | None = None
    notes: str = ""
    created_utc: str = field(default_factory=_now)
    app_version: str = __version__

    # -- settings -----------------------------------------------------------------------------

    def mag_correction(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(offset, soft_iron) when the profile has a magnetometer fit worth applying."""
        if not self.mag or self.mag.get("nothing_to_correct"):
            return None
        return (np.asarray(self.mag["offset"], float).reshape(3),
                np.asarray(self.mag["soft_iron"], float).reshape(3, 3))

    def to_settings(self, base: ekf.EKFSettings | None = None,
                    replace_noise: bool | None = None) -> ekf.EKFSettings:
        """The profile's settings: its own `settings` (else `base`, else the default preset)
        with the magnetometer correction, g, the gyro bias and m0 (from the rest mean field,
        corrected, tilt-compensated) replaced, and the noise covariances too when
        `replace_noise` (None: only onto the plain course model, as `calibrate` does)."""
        settings = (ekf.EKFSettings.from_dict(self.settings) if self.settings
                    else base if base is not None else ekf.PRESETS["default"])
        if replace_noise is None:
            replace_noise = settings.acc_lowpass_s <= 0.0
        changes: dict[str, Any] = {}
        correction = self.mag_correction()
        if self.mag is not None:
            offset, soft = correction if correction else (np.zeros(3), np.eye(3))
            changes.update(mag_hard_iron=tuple(float(v) for v in offset),
                           mag_soft_iron=soft.tolist())
        if self.rest:
            changes.update(_rest_changes(self.rest, correction, replace_noise))
        return settings.with_changes(**changes)

    def warnings(self, settings: ekf.EKFSettings) -> list[str]:
        """What is implausible in the settings this profile gives (one line each): an Earth
        field outside 25-65 uT (a rest taken beside iron, or a magnetometer fit of readings
        that did not turn)."""
        low, high = magcal.EARTH_FIELD_RANGE_UT
        out = []
        if settings.m0 is not None:
            strength = float(np.linalg.norm(settings.m0))
            if not low <= strength <= high:
                out.append(f"m0 is {strength:.1f} uT, not the Earth's {low:g}-{high:g} uT: "
                           "calibrate at rest away from iron, and fit the magnetometer on "
                           "readings taken while turning the phone")
        return out

    # -- JSON ---------------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        out = {"kind": KIND}
        out.update({f.name: getattr(self, f.name) for f in fields(self)})
        return jsonable(out)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Profile":
        if not isinstance(data, dict) or data.get("kind") != KIND:
            raise ConfigError("not an Orientation Lab profile (no \"kind\": \"" + KIND + "\")")
        known = {f.name for f in fields(cls)}
        values = {k: v for k, v in data.items() if k in known}
        if not str(values.get("name", "")).strip():
            raise ConfigError("profile without a name")
        name = values["name"] = str(values["name"]).strip()
        for key in ("rest", "allan", "mag", "settings", "tuning"):
            if values.get(key) is not None and not isinstance(values[key], dict):
                raise ConfigError(f"profile {name!r}: {key} must be an object, not "
                                  f"{type(values[key]).__name__}")
        profile = cls(**values)
        try:
            profile.to_settings()
        except ValueError as error:
            if isinstance(error, ekf.SettingsError):
                raise ConfigError(f"profile {name!r}: {error}") from None
            raise ConfigError(f"profile {name!r}: its calibration is not one this program "
                              f"writes ({error})") from None
        except (TypeError, KeyError, IndexError, AttributeError) as error:
            what = f"missing {error}" if isinstance(error, KeyError) else str(error)
            raise ConfigError(f"profile {name!r}: its calibration is not one this program "
                              f"writes ({what})") from None
        return profile


def _rest_changes(rest: dict[str, Any], correction: tuple[np.ndarray, np.ndarray] | None,
                  replace_noise: bool) -> dict[str, Any]:
    """g, gyr_bias, m0 (and the covariances) from a CalibrationResult.to_dict()."""
    changes: dict[str, Any] = {}
    acc, gyr, mag = rest.get("acc"), rest.get("gyr"), rest.get("mag")
    level = np.eye(3)
    if acc:
        mean = np.asarray(acc["mean"], float)
        changes["g"] = float(np.linalg.norm(mean))
        level = _level_rotation(mean)
        if replace_noise:
            changes["acc_noise_cov"] = np.asarray(acc["cov"], float).tolist()
    if gyr:
        changes["gyr_bias"] = tuple(float(v) for v in gyr["mean"])
        if replace_noise:
            changes["gyr_noise_cov"] = np.asarray(gyr["cov"], float).tolist()
    if mag:
        mean = np.asarray(mag["mean"], float)
        cov = np.asarray(mag["cov"], float)
        if correction is not None:        # the filter sees corrected readings
            offset, soft = correction
            mean, cov = soft @ (mean - offset), soft @ cov @ soft.T
        m = level @ mean
        changes["m0"] = (0.0, float(np.hypot(m[0], m[1])), float(m[2]))
        if replace_noise:
            changes["mag_noise_cov"] = cov.tolist()
    return changes


def jsonable(value: Any) -> Any:
    """Plain JSON types (numpy arrays and numbers, tuples, inf as "inf")."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return None if math.isnan(value) else value
    return value


# ---- the store ----------------------------------------------------------------------------------

def _file_stem(name: str) -> str:
    """A file name for a profile name: letters, digits, '-', '_', '.', the rest as '_'."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", name.strip()).strip("._")
    if not stem:
        raise ConfigError(f"profile name {name!r} has no letters or digits")
    return stem[:80]


class ProfileStore:
    """The profiles in `folder` (default: the user's data folder's profiles/)."""

    def __init__(self, folder: str | Path | None = None) -> None:
        self.folder = Path(folder) if folder is not None else paths.data_dir() / "profiles"

    def path(self, name: str) -> Path:
        return self.folder / f"{_file_stem(name)}.json"

    def names(self) -> list[str]:
        """The stored profiles' names, sorted (unreadable files are skipped)."""
        if not self.folder.is_dir():
            return []
        out = []
        for path in sorted(self.folder.glob("*.json")):
            try:
                out.append(Profile.from_dict(read_json(path)).name)
            except (OSError, ValueError, ConfigError):
                continue
        return sorted(out, key=str.lower)

    def save(self, profile: Profile) -> Path:
        """Write (or overwrite) the profile, atomically; returns its file."""
        path = self.path(profile.name)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            temporary = path.with_name(path.name + ".tmp")
            temporary.write_text(json.dumps(profile.to_dict(), indent=2) + "\n")
            temporary.replace(path)
        except OSError as error:
            raise ConfigError(f"cannot save profile {profile.name!r}: "
                              f"{error.strerror or error}") from None
        return path

    def load(self, name: str) -> Profile:
        return load_profile(self.path(name))

    def delete(self, name: str) -> None:
        try:
            self.path(name).unlink()
        except FileNotFoundError:
            raise ConfigError(f"no profile named {name!r}") from None

    def unique_name(self, name: str) -> str:
        """`name`, or `name (2)`, `name (3)`, ... : the first not yet stored."""
        taken = {_file_stem(n) for n in self.names()}
        candidate, k = name, 2
        while _file_stem(candidate) in taken:
            candidate, k = f"{name} ({k})", k + 1
        return candidate


def load_profile(path: str | Path) -> Profile:
    """A profile from its JSON file; ConfigError when missing or not a profile."""
    path = Path(path)
    try:
        data = read_json(path)
    except FileNotFoundError:
        raise ConfigError(f"no profile file {path}") from None
    except (OSError, ValueError) as error:
        raise ConfigError(f"cannot read profile {path}: "
                          f"{getattr(error, 'strerror', None) or error}") from None
    return Profile.from_dict(data)
