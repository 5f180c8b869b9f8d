"""One configuration for the command line and the window alike.

Everything a user names by text goes through here once: filter settings (a JSON file or a preset
name), estimator names, sensor lists, ports, replay speeds, the physical bounds of a sample
(``--limits``), who may connect (``--allow``), recording folders and limits, and the source to
read (the phone over TCP, a log or recorded session, the built-in demo). Problems raise :class:`ConfigError` with a
one-line message; the command line prints it and exits with status 2, the window shows it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import ekf
from ekf import SENSORS
from ekf.settings import read_json
from app.engine.tuning import profiles
from app.engine.errors import ConfigError   # defined apart (profiles raise it too)
from app.engine.processing.pipeline import check_start_state
from app.engine.sessions.session import read_session, session_json_for
from app.engine.userfilter.code import is_filter_file
from app.engine.userfilter.octave import (OctaveNotFound, filter_folder, find_octave,
                                          is_matlab_filter)
from app.stream.fastparse import FastLineParser
from app.stream.lines import LogError, log_chunks
from app.stream.logfile import LogData, LogFile, read_log
from app.stream.protocol import DEFAULT_LIMITS, Limits
from app.stream.phyphox import PhyphoxSource
from app.stream.phyphox import parse_address as _phyphox_address
from app.stream.sensor_logger import DEFAULT_PORT as SENSOR_LOGGER_PORT
from app.stream.sensor_logger import FRAMES as SENSOR_LOGGER_FRAMES
from app.stream.sensor_logger import SensorLoggerSource
from app.stream.sources import DemoOrPhoneSource, LogFileSource, Source, TcpSource, demo_source
from app.stream.tcp_server import DEFAULT_PORT, parse_networks

DEFAULT_HOST = "0.0.0.0"
DEFAULT_TAKEOVER_S = 3.0

__all__ = ["ConfigError", "DEFAULT_HOST", "DEFAULT_PORT", "SENSORS", "SourceOptions",
           "load_settings", "estimator_names", "sensor_list", "port_number", "replay_speed",
           "make_source", "open_log", "open_replay", "resolve_log_path", "read_intervals",
           "sensor_limits", "allowed_network", "allowed_networks", "recording_note",
           "megabytes", "filter_file", "forward_target", "phyphox_url",
           "sensor_logger_listen", "sensor_logger_frames"]


# ---- filter settings, estimators, sensors ------------------------------------------------------

def load_settings(spec: str | Path | None) -> ekf.EKFSettings | None:
    """Settings from a preset name ("default", "course"), a stored profile ("profile:NAME",
    applied onto the default preset) or a JSON file: plain settings, a `calibrate`/`tune`
    output or a recorded session.json (both hold them under "settings"), or a profile file.
    None -> None (the estimators then use the default preset). A file of a preset's name wins
    over the preset."""
    if spec is None:
        return None
    text = str(spec)
    if text in ekf.PRESETS and not Path(text).exists():
        return ekf.PRESETS[text]
    if text.startswith("profile:") and not Path(text).exists():
        return profiles.ProfileStore().load(text.split(":", 1)[1]).to_settings()
    path = Path(text)
    if not path.exists():
        presets = ", ".join(ekf.PRESETS)
        raise ConfigError(f"settings file not found: {text} (or give a preset: {presets})")
    try:
        data = read_json(path)
        if isinstance(data, dict) and data.get("kind") == profiles.KIND:
            return profiles.Profile.from_dict(data).to_settings()
        return ekf.EKFSettings.from_file_value(data)
    except (OSError, ValueError, TypeError) as error:
        raise ConfigError(f"bad settings file {text}: "
                          f"{getattr(error, 'strerror', None) or error}") from None


def estimator_names(text: str) -> list[str]:
    """"ekf,course,my_filter.py" -> ["ekf", "course", "my_filter.py"]; unknown names raise
    ConfigError; a name ending in .py is a user's filter file, which must exist."""
    names = [name.strip() for name in str(text).split(",") if name.strip()]
    bad = [name for name in names if name not in ekf.ESTIMATORS and not is_filter_file(name)]
    for name in bad:
        if Path(name).expanduser().is_dir():
            filter_file(name)                # a folder without .m files: says so
    if bad or not names:
        raise ConfigError(f"--estimator: unknown {', '.join(repr(b) for b in bad) or repr(text)}; "
                          f"choose from {', '.join(ekf.ESTIMATORS)} or give your filter "
                          "FILE.py or DIR (MATLAB)")
    for name in names:
        if name not in ekf.ESTIMATORS and is_filter_file(name):
            filter_file(name)
    return names


def filter_file(path: str | Path) -> str:
    """A user's filter that exists (``--filter``, ``--estimator FILE.py|DIR``): a Python file, or
    a MATLAB filter (a folder of .m files, or a .m file in one)."""
    path = Path(path).expanduser()
    if not is_filter_file(path):
        found = " (this folder has none)" if path.is_dir() else ""
        raise ConfigError(f"{path}: your filter is a Python file (.py) or a folder of MATLAB .m "
                          f"files{found}")
    if is_matlab_filter(path):
        folder = filter_folder(path)
        if not folder.is_dir() or (path.suffix.lower() == ".m" and not path.is_file()):
            raise ConfigError(f"{path}: no such MATLAB filter (orientation-lab new-filter "
                              f"--matlab {folder} writes the course's functions)")
        return str(folder) if path.suffix.lower() == ".m" else str(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such filter file (orientation-lab new-filter {path} "
                          "writes a template)")
    return str(path)


def octave_program(text: str) -> str:
    """``--octave PATH``: an octave-cli that exists (or the folder it is in)."""
    try:
        return str(find_octave(text))
    except OctaveNotFound as error:
        raise ConfigError(str(error)) from None


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


def sensor_limits(text: str | Limits) -> Limits:
    """"acc=2000,gyr=100,mag=10000,ori=0.01,floor=1e-6" (any of them; the others keep their
    defaults) -> the physical bounds a sample must respect (others are damaged lines)."""
    if isinstance(text, Limits):
        return text
    names = {f.name: f.name for f in fields(Limits)} | {"ori": "ori_tolerance"}
    changes = {}
    for part in str(text).split(","):
        if not part.strip():
            continue
        name, _, value = part.partition("=")
        key = names.get(name.strip())
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if key is None or not number > 0 or number == math.inf:
            raise ConfigError(f"--limits: expected NAME=VALUE with NAME in acc, gyr, mag, ori, "
                              f"floor and VALUE > 0, got {part.strip()!r}")
        changes[key] = number
    if changes.get("ori_tolerance", 0.0) >= 1.0:
        raise ConfigError("--limits: ori (the tolerance on the quaternion's norm) must be < 1")
    return replace(DEFAULT_LIMITS, **changes)


def allowed_network(text: str) -> str:
    """One ADDRESS[/PREFIX] (192.168.1.42, 192.168.1.0/24) -> its normal text."""
    try:
        return str(parse_networks([text])[0])
    except (ValueError, IndexError):
        raise ConfigError(f"--allow: not an address or network: {text!r} (e.g. 192.168.1.42 "
                          "or 192.168.1.0/24)") from None


def allowed_networks(text: str | Iterable[str] | None) -> tuple[str, ...]:
    """Addresses and networks separated by commas or spaces (the connection panel's field), or
    a list of them (repeated --allow) -> their normal texts; empty: anyone may connect."""
    if text is None:
        return ()
    parts = text.replace(",", " ").split() if isinstance(text, str) else list(text)
    return tuple(allowed_network(part) for part in parts if str(part).strip())


MAX_MEGABYTES = 1e12          # a million terabytes


def megabytes(value: float | str) -> int:
    """A size in MB (>= 0; 0 = no limit) -> bytes."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"not a size in MB: {value!r}") from None
    if not 0.0 <= number <= MAX_MEGABYTES:
        raise ConfigError(f"expected a size in MB from 0 (no limit) to {MAX_MEGABYTES:.0e}, "
                          f"got {value}")
    return int(number * 2**20)


def recording_note(requested: str | Path, folder: Path) -> str | None:
    """What to say when a recording asked for `requested` went to `folder` (DIR-2, DIR-3, ...:
    the folder held a session, or another recorder claimed it first); None when it did not."""
    if Path(requested) == folder:
        return None
    return f"{requested} already holds a recorded session: recording into {folder}"


def phyphox_url(text: str) -> str:
    """The address phyphox shows ("http://192.168.1.5:8080", "192.168.1.5:8080", an iPhone's
    "192.168.1.5") -> its normal form "http://HOST:PORT"."""
    try:
        return _phyphox_address(text).url
    except ValueError as error:
        raise ConfigError(f"--phyphox: {error}") from None


def sensor_logger_listen(text: str | int) -> tuple[str, int]:
    """"[HOST:]PORT" where Sensor Logger pushes to -> (host, port); HOST defaults to every
    interface (the phone must reach it)."""
    host, sep, port = str(text).strip().rpartition(":")
    if not sep:
        host, port = "", str(text).strip()
    number = port_number(port) if port else SENSOR_LOGGER_PORT
    return host.strip("[]") or DEFAULT_HOST, number


def sensor_logger_frames(text: str) -> str:
    """auto | standardised | not-standardised: what Sensor Logger's Standardise Units & Frames
    setting is (auto: told from its gravity and orientation)."""
    value = str(text).strip().lower()
    if value not in SENSOR_LOGGER_FRAMES:
        raise ConfigError(f"--sensor-logger-frames: one of {', '.join(SENSOR_LOGGER_FRAMES)}, "
                          f"got {text!r}")
    return value


# ---- logs and sessions -------------------------------------------------------------------------

def resolve_log_path(path: str | Path) -> Path:
    """The log file behind a path: a log file itself, a recorded session folder (its raw.txt)
    or a session's session.json (the raw file it names). A session.json that is not one this
    program can replay is a ConfigError (one line naming it and the entry)."""
    raw = _log_path(Path(path))
    found = session_json_for(raw)
    if found is not None:
        try:
            check_start_state(read_session(found).start_state)
        except ValueError as error:
            raise ConfigError(f"{found}: {error}" if str(found) not in str(error)
                              else str(error)) from None
    return raw


def _log_path(path: Path) -> Path:
    if path.is_dir():
        raw = path / "raw.txt"
        if raw.is_file():
            return raw
        raise ConfigError(f"{path}: a folder without raw.txt (expected a recorded session "
                          "folder or a log file)")
    if path.name == "session.json" and path.is_file():
        try:
            raw_name = read_session(path).data.get("raw_file", "raw.txt")
        except ValueError as error:
            raise ConfigError(str(error)) from None
        return path.with_name(str(raw_name))
    if not path.exists():
        raise ConfigError(f"{path}: no such file or folder")
    return path


REPLAY_EXPECTED = ("expected a recorded session folder, its raw.txt or session.json, or a log "
                   "saved by the Sensor Fusion app, lines like 12345<TAB>ACC<TAB>x<TAB>y<TAB>z")
_PROBE_BYTES = 1 << 18


def open_replay(path: str | Path, speed: float = 1.0, loop: bool = False,
                paused: bool = False, limits: Limits = DEFAULT_LIMITS) -> LogFileSource:
    """The replay of a session folder, its raw.txt or session.json, or a phone's log; the one
    resolution for --replay, File → Open and a file dropped on the window. ConfigError (one
    line naming the file and what was expected) for anything else."""
    raw = resolve_log_path(path)
    try:
        source = LogFileSource(raw, speed=replay_speed(speed), loop=bool(loop), paused=paused)
    except LogError as error:
        raise ConfigError(f"{error}; {REPLAY_EXPECTED}") from None
    except OSError as error:
        raise ConfigError(f"cannot read {raw}: {error.strerror or error}") from None
    check_replay_start(raw, source.data, limits)
    return source


def check_replay_start(raw: Path, data: bytes, limits: Limits = DEFAULT_LIMITS) -> None:
    """ConfigError (one line) unless the start of a log's bytes (its first 256 KiB) holds a
    line of the phone's format."""
    probe = FastLineParser(limits=limits)
    probe.feed_arrays(data[:_PROBE_BYTES])
    if probe.stats.good == 0:
        probe.finish_arrays()
    if probe.stats.good == 0:
        raise ConfigError(f"{raw}: not a phone log or recorded session; {REPLAY_EXPECTED}")


def replay_log(path: str | Path, limits: Limits = DEFAULT_LIMITS) -> Path:
    """The log behind a session folder, its raw.txt or session.json, or a phone's log, checked
    as :func:`open_replay` checks it but without reading it whole (its start only: exports
    read it as a stream). ConfigError (one line) for anything else."""
    raw = resolve_log_path(path)
    chunks = log_chunks(raw, _PROBE_BYTES)
    try:
        start = next(chunks)
    except LogError as error:
        raise ConfigError(f"{error}; {REPLAY_EXPECTED}") from None
    finally:
        chunks.close()
    check_replay_start(raw, start, limits)
    return raw


def log_file(path: str | Path, limits: Limits = DEFAULT_LIMITS) -> LogFile:
    """A log (or recorded session) to read chunk by chunk (LogError while it is read when it
    turns out unusable); ConfigError when the path is not a log or session at all."""
    return LogFile(resolve_log_path(path), limits)


def open_log(path: str | Path, limits: Limits = DEFAULT_LIMITS) -> LogData:
    """Read a whole log (or recorded session) into ordered samples; ConfigError if unusable."""
    try:
        return read_log(resolve_log_path(path), limits=limits)
    except LogError as error:
        raise ConfigError(str(error)) from None
    except OSError as error:
        raise ConfigError(f"cannot read {path}: {error.strerror or error}") from None


def read_intervals(path: str | Path) -> list[list[float]]:
    """score_intervals_ms from a JSON file (the shared trials' NAME.json): a non-empty list of
    [start, end] pairs of finite numbers (phone ms), each ending after it starts."""
    try:
        data = read_json(path)
        intervals = data["score_intervals_ms"] if isinstance(data, dict) else None
        if not isinstance(intervals, list) or not intervals:
            raise ValueError("score_intervals_ms must be a non-empty list of [start, end] pairs")
        for k, pair in enumerate(intervals, 1):
            _check_interval(k, pair)
    except FileNotFoundError:
        raise ConfigError(f"intervals file not found: {path}") from None
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ConfigError(f"bad intervals file {path}: "
                          f"{getattr(error, 'strerror', None) or error}") from None
    return [[float(start), float(end)] for start, end in intervals]


def _check_interval(k: int, pair: object) -> None:
    def number(value: object) -> bool:
        return isinstance(value, (int, float)) and not isinstance(value, bool) \
            and math.isfinite(value)

    if not (isinstance(pair, list) and len(pair) == 2 and all(number(v) for v in pair)):
        shown = json.dumps(pair)
        raise ValueError(f"interval {k} is {shown[:60] + '...' if len(shown) > 60 else shown}: "
                         "expected [start, end], two finite numbers (phone ms)")
    if not pair[0] < pair[1]:
        raise ValueError(f"interval {k} [{pair[0]:g}, {pair[1]:g}] ends before it starts")


# ---- the source --------------------------------------------------------------------------------

@dataclass
class SourceOptions:
    """Where samples come from. replay: a log, session folder or session.json; demo: the built-in
    session while listening for the phone; neither: the phone over TCP. allow: who may connect
    (ADDRESS[/PREFIX] texts; empty: anyone); takeover_after_s: a waiting connection takes over
    once the stream has been silent this long; limits: the physical bounds of a sample."""

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    demo: bool = False
    replay: str | None = None
    speed: float = 1.0
    loop: bool = False
    allow: tuple[str, ...] = ()
    takeover_after_s: float = DEFAULT_TAKEOVER_S
    limits: Limits = field(default_factory=lambda: DEFAULT_LIMITS)
    phyphox: str | None = None          # the address phyphox shows: poll the phone there
    sensor_logger: str | None = None    # [HOST:]PORT: take Sensor Logger's pushes there
    sensor_logger_frames: str = "auto"


def make_source(options: SourceOptions) -> Source:
    """The (unstarted) source for these options. ConfigError for a bad path or value.

    --demo plays the demo while the TCP server listens; a phone that connects takes over."""
    port = port_number(options.port)
    speed = replay_speed(options.speed)
    allow = allowed_networks(options.allow)
    takeover = float(options.takeover_after_s)
    if not 0.0 <= takeover < math.inf:
        raise ConfigError(f"--takeover-after: expected seconds >= 0, got {takeover}")

    def phone() -> TcpSource:
        return TcpSource(options.host, port, allow=allow, takeover_after_s=takeover,
                         limits=options.limits)

    chosen = [name for name, given in (("--replay", options.replay), ("--demo", options.demo),
                                       ("--phyphox", options.phyphox),
                                       ("--sensor-logger", options.sensor_logger)) if given]
    if len(chosen) > 1:
        raise ConfigError(f"{' and '.join(chosen)}: give one source at a time")
    if options.phyphox:
        return PhyphoxSource(phyphox_url(options.phyphox))
    if options.sensor_logger:
        host, listen_port = sensor_logger_listen(options.sensor_logger)
        return SensorLoggerSource(host, listen_port,
                                  sensor_logger_frames(options.sensor_logger_frames),
                                  takeover_after_s=takeover, allow=allow)
    try:
        if options.replay:
            return open_replay(options.replay, speed, bool(options.loop),
                               limits=options.limits)
        if options.demo:
            return DemoOrPhoneSource(demo_source(speed), phone())
    except LogError as error:
        raise ConfigError(str(error)) from None
    return phone()
