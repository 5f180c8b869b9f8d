"""One configuration for the command line and the window alike.

Everything a user names by text goes through here once: filter settings (a JSON file or a preset
name), estimator names, sensor lists, ports, replay speeds and the source to read (the phone over
TCP, a log or recorded session, the built-in demo). Problems raise :class:`ConfigError` with a
one-line message; the command line prints it and exits with status 2, the window shows it.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import ekf
from ekf import SENSORS
from app.engine.user_code import UserFilterError, is_filter_file
from app.engine.user_filter import make_estimator as _make_estimator
from app.stream.lines import LogError
from app.stream.logfile import LogData, read_log
from app.stream.sources import DemoOrPhoneSource, LogFileSource, Source, TcpSource, demo_source
from app.stream.tcp_server import DEFAULT_PORT

DEFAULT_HOST = "0.0.0.0"

__all__ = ["ConfigError", "DEFAULT_HOST", "DEFAULT_PORT", "SENSORS", "SourceOptions",
           "load_settings", "estimator_names", "sensor_list", "port_number", "replay_speed",
           "make_source", "open_log", "resolve_log_path", "read_intervals", "filter_file",
           "forward_target", "make_estimator"]


class ConfigError(Exception):
    """Something the user asked for cannot be done: a one-line message, no traceback."""


# ---- filter settings, estimators, sensors ------------------------------------------------------

def load_settings(spec: str | Path | None) -> ekf.EKFSettings | None:
    """Settings from a preset name ("default", "course") or a JSON file: plain settings, a
    `calibrate` output or a recorded session.json (both hold them under "settings").
    None -> None (the estimators then use the default preset). A file of a preset's name wins
    over the preset."""
    if spec is None:
        return None
    text = str(spec)
    if text in ekf.PRESETS and not Path(text).exists():
        return ekf.PRESETS[text]
    path = Path(text)
    if not path.exists():
        presets = ", ".join(ekf.PRESETS)
        raise ConfigError(f"settings file not found: {text} (or give a preset: {presets})")
    try:
        return ekf.EKFSettings.load(path)
    except (OSError, ValueError, TypeError) as error:
        raise ConfigError(f"bad settings file {text}: {error}") from None


def estimator_names(text: str) -> list[str]:
    """"ekf,course,my_filter.py" -> ["ekf", "course", "my_filter.py"]; unknown names raise
    ConfigError; a name ending in .py is a user's filter file, which must exist."""
    names = [name.strip() for name in str(text).split(",") if name.strip()]
    bad = [name for name in names if name not in ekf.ESTIMATORS and not is_filter_file(name)]
    if bad or not names:
        raise ConfigError(f"--estimator: unknown {', '.join(repr(b) for b in bad) or repr(text)}; "
                          f"choose from {', '.join(ekf.ESTIMATORS)} or give your filter "
                          "FILE.py")
    for name in names:
        if is_filter_file(name):
            filter_file(name)
    return names


def filter_file(path: str | Path) -> str:
    """A user's filter file that exists (``--filter``, ``--estimator FILE.py``)."""
    path = Path(path).expanduser()
    if not is_filter_file(path):
        raise ConfigError(f"{path}: a filter file is a Python file (.py)")
    if not path.is_file():
        raise ConfigError(f"{path}: no such filter file (orientation-lab new-filter {path} "
                          "writes a template)")
    return str(path)


def make_estimator(name: str, settings: ekf.EKFSettings | None = None,
                   sensors: Iterable[str] = SENSORS) -> ekf.Estimator:
    """The estimator a name stands for: a built-in or a user's filter file (loaded; a file that
    does not load is a ConfigError naming its line)."""
    try:
        return _make_estimator(name, settings, tuple(sensors))
    except UserFilterError as error:
        raise ConfigError(error.problem.message) from None


def forward_target(text: str) -> tuple[str, int]:
    """"HOST:PORT" (or ":PORT", "PORT": this machine) -> (host, port) for ``--forward``."""
    host, sep, port = str(text).strip().rpartition(":")
    if not sep:
        host, port = "", str(text).strip()
    number = port_number(port)
    if number == 0:
        raise ConfigError(f"--forward: give the receiver's port, got {text!r}")
    return host or "127.0.0.1", number


def sensor_list(text: str | Iterable[str]) -> tuple[str, ...]:
    """"gyr,acc" -> ("gyr", "acc"), in the canonical order; a non-empty subset of gyr,acc,mag."""
    parts = ([s.strip() for s in text.split(",") if s.strip()] if isinstance(text, str)
             else list(text))
    bad = [s for s in parts if s not in SENSORS]
    if bad or not parts:
        raise ConfigError(f"--sensors: expected a non-empty subset of gyr,acc,mag, got "
                          f"{text if isinstance(text, str) else ','.join(parts)!r}")
    return tuple(s for s in SENSORS if s in parts)


def port_number(value: int | str) -> int:
    """A TCP port 0-65535 (0: any free port)."""
    try:
        port = int(value)
    except (TypeError, ValueError):
        raise ConfigError(f"not a port number: {value!r}") from None
    if not 0 <= port <= 65535:
        raise ConfigError(f"port out of range 0-65535: {port}")
    return port


def replay_speed(value: float | str) -> float:
    """A replay speed: 1 = the original timing, 2 = twice as fast, 0 = as fast as possible."""
    try:
        speed = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"not a speed: {value!r}") from None
    if not speed >= 0.0 or speed == float("inf"):
        raise ConfigError(f"speed must be 0 (as fast as possible) or positive, got {value}")
    return speed


# ---- logs and sessions -------------------------------------------------------------------------

def resolve_log_path(path: str | Path) -> Path:
    """The log file behind a path: a log file itself, a recorded session folder (its raw.txt)
    or a session's session.json (the raw file it names)."""
    path = Path(path)
    if path.is_dir():
        raw = path / "raw.txt"
        if raw.is_file():
            return raw
        raise ConfigError(f"{path}: a folder without raw.txt (expected a log file or a recorded "
                          "session folder)")
    if path.name == "session.json" and path.is_file():
        try:
            raw_name = json.loads(path.read_text()).get("raw_file", "raw.txt")
        except (OSError, ValueError, AttributeError) as error:
            raise ConfigError(f"{path}: not a readable session file ({error})") from None
        return path.with_name(str(raw_name))
    if not path.exists():
        raise ConfigError(f"{path}: no such file")
    return path


def open_log(path: str | Path) -> LogData:
    """Read a whole log (or recorded session) into ordered samples; ConfigError if unusable."""
    try:
        return read_log(resolve_log_path(path))
    except LogError as error:
        raise ConfigError(str(error)) from None
    except OSError as error:
        raise ConfigError(f"cannot read {path}: {error.strerror or error}") from None


def read_intervals(path: str | Path) -> list[list[float]]:
    """score_intervals_ms from a JSON file (the shared trials' NAME.json)."""
    try:
        data = json.loads(Path(path).read_text())
        intervals = data["score_intervals_ms"]
        if not all(len(pair) == 2 for pair in intervals):
            raise ValueError("score_intervals_ms must be a list of [start, end] pairs")
    except FileNotFoundError:
        raise ConfigError(f"intervals file not found: {path}") from None
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ConfigError(f"bad intervals file {path}: {error}") from None
    return intervals


# ---- the source --------------------------------------------------------------------------------

@dataclass
class SourceOptions:
    """Where samples come from. replay: a log, session folder or session.json; demo: the built-in
    session while listening for the phone; neither: the phone over TCP."""

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    demo: bool = False
    replay: str | None = None
    speed: float = 1.0
    loop: bool = False


def make_source(options: SourceOptions) -> Source:
    """The (unstarted) source for these options. ConfigError for a bad path or value.

    --demo plays the demo while the TCP server listens; a phone that connects takes over."""
    port = port_number(options.port)
    speed = replay_speed(options.speed)
    try:
        if options.replay:
            return LogFileSource(resolve_log_path(options.replay), speed=speed,
                                 loop=bool(options.loop))
        if options.demo:
            return DemoOrPhoneSource(demo_source(speed), TcpSource(options.host, port))
    except LogError as error:
        raise ConfigError(str(error)) from None
    return TcpSource(options.host, port)
