"""Recorded sessions on disk: where they go, what session.json holds, markers.

A session is a folder (DESIGN.md section 5): ``raw.txt`` (the received lines, verbatim),
``session.json`` and ``estimates.csv``. session.json (format 2) holds, besides the recorder's
fields (app version, UTC start and stop, raw line count, stream statistics):

* ``settings`` (the filter settings at the start), ``calibration`` (their calibration part:
  g, m0, gyroscope bias, noise covariances), ``estimator``, ``sensors`` (switched in at the
  start) and ``comparisons`` ({"enabled", "estimator"}): the set-up the replay starts with;
* ``host`` (this computer) and ``phone`` (the phone's address);
* ``timeline``: what happened, in order, each entry with its ``kind``, the phone time ``t_ms``,
  the UTC time and ``sample``, the number of samples the estimators had been fed since the
  recording started (so a replay applies it at exactly the same point): "sensor" (sensor,
  enabled), "estimator" (name), "settings" (settings), "reset", "align_heading",
  "comparisons" (enabled, estimator), "marker" (id, label, t_s), and "connected",
  "disconnected", "session" for the record;
* ``start_state``: when the recording started while a stream was already running, the
  engine's state at that moment (every estimator's snapshot, the samples the time orderer
  held), so that replaying raw.txt continues exactly where the live engine was; null when
  the recording started with the stream.

Markers can be added while replaying a session: :func:`write_markers` rewrites its
session.json with them, atomically (the recorder's write_json_atomic). ``label`` (optional, a
string) is the name the user gave the session (:func:`write_label`); a session without one is
named by its folder's time stamp.

Markers (:class:`Markers`): points in a session the user drops with M (an optional label typed
afterwards). They are kept where the session is: the recording in progress gets each one in its
timeline (with its sample position), the replayed session's session.json is rewritten with
them, atomically. A phone's own log has no session.json: its markers stay until it closes.
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

import ekf
from ekf.settings import read_json, shown_value
from app import paths
from app.stream.recorder import write_json_atomic


SESSION_FORMAT = 2
FILTER_EVENTS = ("sensor", "estimator", "settings", "reset", "align_heading", "comparisons")
CALIBRATION_FIELDS = ("g", "m0", "gyr_bias", "gyr_noise_cov", "acc_noise_cov", "mag_noise_cov",
                      "mag_hard_iron", "mag_soft_iron")


@dataclass
class Marker:
    """A point in a session: number (1, 2, ...), label (may be empty), t_ms (the phone's
    aligned clock), t_s (seconds since the session's start, as the plots show it)."""

    id: int
    t_ms: int | None
    t_s: float | None
    label: str = ""
    utc: str = ""
    sample: int | None = None      # its position in a recording's timeline (kept on rewrites)

    @property
    def title(self) -> str:
        return f"{self.id}: {self.label}" if self.label else str(self.id)

    def to_event(self, sample: int | None = None) -> dict[str, Any]:
        return {"kind": "marker", "t_ms": self.t_ms, "utc": self.utc,
                "sample": self.sample if sample is None else sample,
                "id": self.id, "label": self.label, "t_s": self.t_s}

    @staticmethod
    def from_event(event: dict[str, Any]) -> Marker:
        sample = event.get("sample")
        return Marker(int(event.get("id") or 0), event.get("t_ms"), event.get("t_s"),
                      str(event.get("label") or ""), str(event.get("utc") or ""),
                      sample if isinstance(sample, int) and not isinstance(sample, bool)
                      else None)


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


def sessions_dir() -> Path:
    """Where recorded sessions go by default: <the user's data folder>/sessions."""
    return paths.data_dir() / "sessions"


def default_session_folder(now: datetime | None = None) -> Path:
    """The folder a recording goes to by default, named by the local date and time (the
    recorder goes on to DIR-2, DIR-3, ... when it holds a session)."""
    now = now or datetime.now()
    return sessions_dir() / now.strftime("%Y-%m-%d_%H-%M-%S")


# ---- the set-up a replay starts with ------------------------------------------------------------

def settings_from_dict(data: dict[str, Any] | None) -> ekf.EKFSettings | None:
    """EKFSettings from session.json (a preset itself when equal to one, so the course preset
    keeps its name)."""
    if not data:
        return None
    settings = ekf.EKFSettings.from_dict(dict(data))
    for preset in ekf.PRESETS.values():
        if preset == settings:
            return preset
    return settings


def calibration_of(settings: ekf.EKFSettings) -> dict[str, Any]:
    values = settings.to_dict()
    return {name: values.get(name) for name in CALIBRATION_FIELDS}


@dataclass
class SessionInfo:
    """What a recorded session's session.json says about replaying it."""

    path: Path                                  # the session.json
    data: dict[str, Any]
    settings: ekf.EKFSettings | None = None
    estimator: str | None = None
    sensors: dict[str, bool] | None = None
    comparisons: dict[str, Any] | None = None
    timeline: list[dict[str, Any]] = field(default_factory=list)
    start_state: dict[str, Any] | None = None

    @property
    def markers(self) -> list[Marker]:
        return [Marker.from_event(e) for e in self.timeline if e.get("kind") == "marker"]

    @property
    def filter_events(self) -> list[dict[str, Any]]:
        """The timeline entries a replay applies, with their sample positions, in order."""
        return [e for e in self.timeline if e.get("kind") in FILTER_EVENTS
                and isinstance(e.get("sample"), int)]


def session_json_for(log_path: str | Path) -> Path | None:
    """The session.json beside a recorded raw.txt (None for a phone's own log)."""
    path = Path(log_path)
    candidate = path.with_name("session.json")
    return candidate if candidate.is_file() else None


def read_session(path: str | Path) -> SessionInfo:
    """A session.json, checked against the format this program writes (:func:`check_session`);
    ValueError (one line naming the file and the entry) when it is not one."""
    path = Path(path)
    try:
        data = read_json(path)
    except (OSError, ValueError) as error:
        raise ValueError(f"{path}: not a readable session file "
                         f"({getattr(error, 'strerror', None) or error})") from None
    try:
        settings = check_session(data)
        start = data.get("start_state")
        start = decode_state(start) if isinstance(start, dict) else None
    except (TypeError, ValueError, KeyError, AttributeError) as error:
        raise ValueError(f"{path}: {error}") from None
    return SessionInfo(path, data, settings, data.get("estimator"), data.get("sensors"),
                       data.get("comparisons"), list(data.get("timeline") or []), start)


def _whole(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _expect(ok: bool, where: str, value: Any, allowed: str) -> None:
    if not ok:
        raise ValueError(f"{where} = {shown_value(value)}: must be {allowed}")


def check_session(data: Any) -> ekf.EKFSettings | None:
    """Check a session.json's value against format :data:`SESSION_FORMAT` (a newer format, an
    entry of the wrong type or a value a setting does not allow raise ValueError naming it);
    the recorded settings."""
    if not isinstance(data, dict):
        raise ValueError("not a session file (expected a JSON object)")
    version = data.get("format", 1)
    _expect(_whole(version) and version >= 1, "format", version, "a whole number")
    if version > SESSION_FORMAT:
        raise ValueError(f"session format {version} is newer than this program reads "
                         f"({SESSION_FORMAT}); update Orientation Lab")
    raw = data.get("raw_file", "raw.txt")
    _expect(isinstance(raw, str) and raw not in ("", ".", "..") and "/" not in raw
            and "\\" not in raw, "raw_file", raw, "the name of a file beside session.json")
    settings = data.get("settings")
    _expect(settings is None or isinstance(settings, dict), "settings", settings,
            "an object of setting: value")
    recorded = settings_from_dict(settings)
    names = " or ".join(ekf.ESTIMATORS)
    estimator = data.get("estimator")
    _expect(estimator is None or estimator in ekf.ESTIMATORS, "estimator", estimator, names)
    sensors = data.get("sensors")
    _expect(sensors is None or (isinstance(sensors, dict) and all(
        k in ekf.SENSORS and isinstance(v, bool) for k, v in sensors.items())), "sensors",
        sensors, "an object of " + "/".join(ekf.SENSORS) + ": true or false")
    _check_comparisons(data.get("comparisons"), "comparisons")
    timeline = data.get("timeline")
    _expect(timeline is None or isinstance(timeline, list), "timeline", timeline,
            "a list of events")
    for number, event in enumerate(timeline or []):
        _check_event(event, f"timeline[{number}]")
    start = data.get("start_state")
    _expect(start is None or (isinstance(start, dict) and isinstance(start.get("runner"), dict)
                              and isinstance(start.get("orderer"), dict)),
            "start_state", start, "null or the engine state this program recorded")
    return recorded


def _check_comparisons(value: Any, where: str) -> None:
    _expect(value is None or isinstance(value, dict), where, value,
            'an object {"enabled", "estimator"}')
    if isinstance(value, dict):
        _expect(isinstance(value.get("enabled", False), bool), where + ".enabled",
                value.get("enabled"), "true or false")
        name = value.get("estimator")
        _expect(name is None or name in ekf.ESTIMATORS, where + ".estimator", name,
                " or ".join(ekf.ESTIMATORS))


def _check_event(event: Any, where: str) -> None:
    _expect(isinstance(event, dict) and isinstance(event.get("kind"), str), where, event,
            'an object with a "kind"')
    for key in ("t_ms", "sample"):
        value = event.get(key)
        _expect(value is None or (_whole(value) and (key == "t_ms" or value >= 0)),
                f"{where}.{key}", value, "null or a whole number")
    kind = event["kind"]
    if kind == "sensor":
        _expect(event.get("sensor") in ekf.SENSORS, where + ".sensor", event.get("sensor"),
                " or ".join(ekf.SENSORS))
        _expect(isinstance(event.get("enabled"), bool), where + ".enabled",
                event.get("enabled"), "true or false")
    elif kind == "estimator":
        _expect(event.get("name") in ekf.ESTIMATORS, where + ".name", event.get("name"),
                " or ".join(ekf.ESTIMATORS))
    elif kind == "settings":
        _expect(isinstance(event.get("settings"), dict), where + ".settings",
                event.get("settings"), "an object of setting: value")
        try:
            settings_from_dict(event["settings"])
        except ValueError as error:
            raise ValueError(f"{where}: {error}") from None
    elif kind == "comparisons":
        _check_comparisons({k: event.get(k) for k in ("enabled", "estimator")}, where)
    elif kind == "marker":
        _expect(_whole(event.get("id")) and event["id"] >= 1, where + ".id", event.get("id"),
                "a whole number ≥ 1")
        _expect(isinstance(event.get("label", ""), str), where + ".label", event.get("label"),
                "text")
        t_s = event.get("t_s")
        _expect(t_s is None or (isinstance(t_s, (int, float)) and not isinstance(t_s, bool)
                                and math.isfinite(t_s)), where + ".t_s", t_s,
                "null or a finite number")


def write_markers(session_json: str | Path, markers: list[Marker]) -> None:
    """Replace the markers in a session.json's timeline by `markers` (in time order among the
    other entries), atomically. OSError when it cannot be written."""
    path = Path(session_json)
    data = json.loads(path.read_text(encoding="utf-8"))
    events = [e for e in data.get("timeline") or [] if e.get("kind") != "marker"]
    events += [m.to_event() for m in markers]
    events.sort(key=lambda e: (e.get("t_ms") is None, e.get("t_ms") or 0))
    data["timeline"] = events
    write_json_atomic(path, data)


MAX_LABEL = 120


def session_json_of(path: str | Path) -> Path | None:
    """The session.json of a session given as its folder, raw.txt or session.json (None: not
    a recorded session, e.g. a phone's own log)."""
    path = Path(path)
    candidate = path / "session.json" if path.is_dir() else path.with_name("session.json")
    return candidate if candidate.is_file() else None


def session_label(path: str | Path) -> str:
    """The label the user gave a session (its folder, raw.txt or session.json): "" for none,
    for an older session without one and for anything unreadable."""
    found = session_json_of(path)
    if found is None:
        return ""
    try:
        data = json.loads(found.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return ""
    label = data.get("label") if isinstance(data, dict) else None
    return label if isinstance(label, str) else ""


def write_label(session_json: str | Path, label: str) -> str:
    """Set a session's label (one line, at most MAX_LABEL characters; "" removes it) in its
    session.json, atomically; the label written. OSError when it cannot be written, ValueError
    when the file is no session."""
    path = Path(session_json)
    data = json.loads(path.read_text(encoding="utf-8"))
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a session file")
    label = " ".join(str(label).split())[:MAX_LABEL]
    if label:
        data["label"] = label
    else:
        data.pop("label", None)
    write_json_atomic(path, data)
    return label


# ---- the engine's state as JSON (start_state) ---------------------------------------------------

_RECORDS = {"Flags": ekf.Flags, "Diagnostics": ekf.Diagnostics}


def encode_state(value: Any) -> Any:
    """Snapshots (numpy arrays, settings, flag records, tuples, bytes) -> plain JSON values,
    exactly (floats keep every bit: JSON writes their repr)."""
    if isinstance(value, np.ndarray):
        return {"__array__": value.ravel().tolist(), "dtype": value.dtype.str,
                "shape": list(value.shape)}
    if isinstance(value, ekf.EKFSettings):
        return {"__settings__": value.to_dict()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {"__record__": type(value).__name__,
                "fields": {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}}
    if isinstance(value, bytes):
        return {"__bytes__": value.decode("latin-1")}
    if isinstance(value, dict):
        return {str(k): encode_state(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [encode_state(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def decode_state(value: Any) -> Any:
    """The inverse of :func:`encode_state` (tuples come back as lists)."""
    if isinstance(value, dict):
        if "__array__" in value:
            return np.array(value["__array__"], dtype=value["dtype"]).reshape(value["shape"])
        if "__settings__" in value:
            return settings_from_dict(value["__settings__"])
        if "__record__" in value:
            return _RECORDS[value["__record__"]](**value["fields"])
        if "__bytes__" in value:
            return value["__bytes__"].encode("latin-1")
        return {k: decode_state(v) for k, v in value.items()}
    if isinstance(value, list):
        return [decode_state(v) for v in value]
    return value


class Markers:
    """The markers of the session shown, oldest first."""

    def __init__(self) -> None:
        self.items: list[Marker] = []

    def replace(self, markers: list[Marker]) -> None:
        self.items = list(markers)

    def add(self, label: str, t_ms: int | None, t0_ms: int | None, recording: Any,
            replay: Any, fed: int) -> str:
        """A new marker at the latest sample; returns the status line (saved where)."""
        t_s = None if t_ms is None or t0_ms is None else (t_ms - t0_ms) / 1000.0
        number = max((m.id for m in self.items), default=0) + 1
        marker = Marker(number, t_ms, t_s, str(label or ""), utc_now())
        self.items.append(marker)
        where = "–" if t_s is None else f"{t_s:.1f} s"
        return f"marker {marker.title} at {where}{self._save(marker, True, recording, replay, fed)}"

    def set_label(self, number: int, label: str, recording: Any, replay: Any) -> str | None:
        for index, marker in enumerate(self.items):
            if marker.id == number:
                self.items[index] = dataclasses.replace(marker, label=str(label or ""))
                return self._save(self.items[index], False, recording, replay, 0) or None
        return None

    def _save(self, marker: Marker, new: bool, recording: Any, replay: Any, fed: int) -> str:
        """Into the recording and the replayed session; a note for the status line."""
        note = ""
        recording = recording if recording is not None and recording.active else None
        if recording is not None:
            if new:
                recording.add_marker(marker, fed)
            else:
                recording.update_marker(marker)
        if replay is not None:
            replay.markers = list(self.items)
            if replay.session is None and recording is None:
                note = " (a phone's log has no session.json: not saved)"
            problem = replay.save_markers()
            if problem:
                note = f" ({problem})"
        elif recording is None:
            note = " (not recording: not saved)"
        return note
