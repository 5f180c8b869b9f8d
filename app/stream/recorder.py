"""Crash-safe session recording (DESIGN.md section 5), that never takes the stream down.

A session is a folder: ``raw.txt`` holds every received line that parses to a sample, verbatim,
in the phone's format with no header (the course's MATLAB reader and our own replay read it),
appended and flushed at least twice a second; ``session.json`` holds the app version, UTC start
time, settings, the sensor-toggle/marker timeline and stream statistics, rewritten atomically.

Faults: a write error (disk full, the folder removed, a file size limit), also from flush or
close, stops the recording: :attr:`Recorder.error` says why in one line and every later write is
ignored, so the stream and the estimates go on. ``max_bytes`` (raw.txt's size) and
``min_free_bytes`` (free space left on the disk) stop it the same way before the disk is full.
"""

from __future__ import annotations

import json
import os
import stat
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, is_dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from app import __version__

FLUSH_INTERVAL_S = 0.4     # < 0.5: "flushed at least twice a second"
JSON_INTERVAL_S = 2.0
FREE_CHECK_INTERVAL_S = 1.0
DEFAULT_MAX_BYTES = 2 << 30          # 2 GiB of raw.txt (a 500 Hz phone writes ~6 MB a minute)
DEFAULT_MIN_FREE_BYTES = 256 << 20   # stop while 256 MiB are still free on the disk
SESSION_FILES = ("raw.txt", "session.json")


def _jsonable(value: Any) -> Any:
    if hasattr(value, "to_dict"):
        return value.to_dict()
    if is_dataclass(value) and not isinstance(value, type):
        return asdict(value)
    return value


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON to a temporary file beside `path`, then rename it over `path`."""
    temporary = path.with_name(path.name + ".tmp")
    with open(temporary, "w", encoding="utf-8") as stream:
        json.dump(data, stream, indent=2, default=str)
        stream.flush()
        os.fsync(stream.fileno())
    os.replace(temporary, path)


def holds_session(directory: str | Path) -> bool:
    """Does the folder already hold a recorded session (raw.txt or session.json)?"""
    return any((Path(directory) / name).exists() for name in SESSION_FILES)


def new_session_folder(directory: str | Path) -> Path:
    """`directory` when it holds no session yet, else the first of DIR-2, DIR-3, ... that holds
    none: a second recording never appends to the first one's raw.txt."""
    directory = Path(directory)
    if not holds_session(directory):
        return directory
    number = 2
    while holds_session(directory.with_name(f"{directory.name}-{number}")):
        number += 1
    return directory.with_name(f"{directory.name}-{number}")


def _cut_partial_line(path: Path) -> None:
    """A write that failed half-way may leave part of a line at the end of raw.txt (it could
    parse to a wrong value): cut the file after its last complete line. Best effort."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return                 # /dev/full, a pipe: nothing to cut
        with open(path, "r+b") as stream:
            size = stream.seek(0, os.SEEK_END)
            start = max(0, size - 8192)
            stream.seek(start)
            tail = stream.read(8192)
            if tail and not tail.endswith(b"\n"):
                stream.truncate(start + tail.rfind(b"\n") + 1)
    except OSError:
        pass


def _megabytes(size: int) -> str:
    return f"{size / 2**20:.0f} MB" if size >= 2**20 else f"{size / 2**10:.0f} KB"


class Recorder:
    """Record a session into `directory` (created if needed; raw.txt is appended to).

    write_line() is the LineParser's raw_sink, write_block() the FastLineParser's block sink;
    tick() is called often by the engine (it flushes raw.txt every FLUSH_INTERVAL_S, rewrites
    session.json when something changed and checks the free space). Thread-safe: the engine
    thread writes, a GUI may read size/elapsed/error. Raises OSError only from the constructor
    (the folder or raw.txt cannot be made); afterwards a fault stops the recording (see the
    module docstring). max_bytes / min_free_bytes: 0 = no limit. clock: the monotonic seconds
    the flush, session.json and free-space intervals and elapsed_s count in (tests give a fake).
    """

    def __init__(self, directory: str | Path, settings: Any = None,
                 info: dict[str, Any] | None = None, max_bytes: int = DEFAULT_MAX_BYTES,
                 min_free_bytes: int = DEFAULT_MIN_FREE_BYTES,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.directory = Path(directory)
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self._raw = open(self.directory / "raw.txt", "ab")
        except OSError as error:
            raise OSError(f"cannot record into {self.directory}: {error.strerror or error}") \
                from None
        self._lock = threading.Lock()
        self._clock = clock
        self.max_bytes = int(max_bytes)
        self.min_free_bytes = int(min_free_bytes)
        self.started_utc = datetime.now(timezone.utc).isoformat(timespec="milliseconds")
        self._started = self._clock()
        self._last_flush = self._started
        self._last_json = 0.0
        self._last_free_check = -float("inf")
        self._bytes_at_free_check = 0
        self._dirty = True
        self.lines_written = 0
        self.bytes_written = self._raw.tell()
        self.closed = False
        self.error: str | None = None     # why the recording stopped early (one line)
        self.session: dict[str, Any] = {
            "app": "orientation-lab", "app_version": __version__,
            "started_utc": self.started_utc, "stopped_utc": None,
            "raw_file": "raw.txt", "settings": _jsonable(settings),
            "timeline": [], "stats": {}, **(info or {}),
        }
        with self._lock:
            self._guarded(self._write_json)
            self._check_free_space(self._clock())

    @property
    def elapsed_s(self) -> float:
        return self._clock() - self._started

    @property
    def recording(self) -> bool:
        return not self.closed

    def write_line(self, raw: bytes) -> None:
        """Append one received line verbatim (with its terminator)."""
        self.write_block(raw, 1)

    def write_block(self, data: bytes, lines: int) -> None:
        """Append `lines` received lines at once, verbatim (`data` ends with a terminator)."""
        with self._lock:
            if self.closed:
                return
            if self.max_bytes and self.bytes_written + len(data) > self.max_bytes:
                self._stop(f"raw.txt reached the size limit of {_megabytes(self.max_bytes)}")
                return
            if self._guarded(self._raw.write, data):
                self.lines_written += lines
                self.bytes_written += len(data)
                if self.min_free_bytes and self.bytes_written - self._bytes_at_free_check \
                        > self.min_free_bytes // 4:
                    self._check_free_space(self._clock())

    def add_event(self, kind: str, t_ms: int | None = None, **data: Any) -> None:
        """A timeline entry: sensor toggles ("sensor", sensor=..., enabled=...), markers,
        settings changes, connections. t_ms is the phone time when known."""
        entry = {"kind": kind, "t_ms": t_ms,
                 "utc": datetime.now(timezone.utc).isoformat(timespec="milliseconds")}
        entry.update({key: _jsonable(value) for key, value in data.items()})
        with self._lock:
            timeline = self.session["timeline"]
            timeline.append(entry)
            del timeline[:-10_000]   # bounded: a runaway toggler cannot grow it forever
            self._dirty = True

    def set_settings(self, settings: Any) -> None:
        with self._lock:
            self.session["settings"] = _jsonable(settings)
            self._dirty = True

    def set_calibration(self, calibration: Any) -> None:
        """The calibration profile the settings came from (session.json "calibration")."""
        with self._lock:
            self.session["calibration"] = _jsonable(calibration)
            self._dirty = True

    def set_stats(self, stats: dict[str, Any]) -> None:
        with self._lock:
            self.session["stats"] = stats
            self._dirty = True

    def tick(self) -> None:
        """Flush raw.txt if due; rewrite session.json if it changed and is due; check the
        free space once a second."""
        now = self._clock()
        with self._lock:
            if self.closed:
                return
            if now - self._last_flush >= FLUSH_INTERVAL_S:
                self._last_flush = now
                if not self._guarded(self._raw.flush):
                    return
            if self._dirty and now - self._last_json >= JSON_INTERVAL_S:
                if not self._guarded(self._write_json):
                    return
            if now - self._last_free_check >= FREE_CHECK_INTERVAL_S:
                self._check_free_space(now)

    def flush(self) -> None:
        with self._lock:
            if not self.closed and self._guarded(self._raw.flush):
                self._guarded(self._write_json)

    def close(self) -> None:
        """Flush everything, stamp the stop time, close. Idempotent; never raises (an error
        here is kept in :attr:`error`)."""
        with self._lock:
            if self.closed:
                return
            self._close_files()

    # -- internals -------------------------------------------------------------------------

    def _guarded(self, operation, *args) -> bool:
        """Run a file operation; on OSError stop the recording. True when it worked."""
        try:
            operation(*args)
        except OSError as error:
            where = getattr(error, "filename", None) or self.directory / "raw.txt"
            self._stop(f"cannot write {where}: {error.strerror or error}")
            return False
        return True

    def _check_free_space(self, now: float) -> None:
        self._last_free_check = now
        self._bytes_at_free_check = self.bytes_written
        if not self.min_free_bytes or self.closed:
            return
        try:
            status = os.statvfs(self.directory)
        except FileNotFoundError:
            self._stop(f"the folder {self.directory} was removed")
            return
        except OSError as error:
            self._stop(f"cannot read the free space of {self.directory}: "
                       f"{error.strerror or error}")
            return
        free = status.f_bavail * status.f_frsize
        if free < self.min_free_bytes:
            self._stop(f"less than {_megabytes(self.min_free_bytes)} free on the disk "
                       f"({_megabytes(free)} left)")

    def _stop(self, reason: str) -> None:
        """Stop recording (called with the lock held): what was written stays, ends at a line."""
        if self.error is None:
            self.error = reason
        if not self.closed:
            self._close_files()

    def _close_files(self) -> None:
        self.closed = True
        try:
            self._raw.flush()
        except OSError as error:
            self.error = self.error or f"cannot write {self.directory / 'raw.txt'}: " \
                                       f"{error.strerror or error}"
        try:
            self._raw.close()
        except OSError as error:   # the buffer could not be written at close either
            self.error = self.error or f"cannot close {self.directory / 'raw.txt'}: " \
                                       f"{error.strerror or error}"
        self.session["stopped_utc"] = datetime.now(timezone.utc).isoformat(
            timespec="milliseconds")
        if self.error:
            self.session["stopped_because"] = self.error
            _cut_partial_line(self.directory / "raw.txt")
        try:
            self._write_json()
        except OSError:
            pass     # the folder is gone or full: raw.txt is what counts

    def _write_json(self) -> None:
        self.session["raw_lines"] = self.lines_written
        self.session["raw_bytes"] = self.bytes_written
        write_json_atomic(self.directory / "session.json", self.session)
        self._last_json = self._clock()
        self._dirty = False
