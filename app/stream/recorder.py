"""Crash-safe session recording (DESIGN.md section 5).

A session is a folder: ``raw.txt`` holds every received known-tag line verbatim, in the phone's
format with no header (the course's MATLAB reader and our own replay read it), appended and
flushed at least twice a second; ``session.json`` holds the app version, UTC start time,
settings, the sensor-toggle/marker timeline and stream statistics, rewritten atomically.
"""

from __future__ import annotations

import json
import os
import threading
import time
from dataclasses import asdict, is_dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from app import __version__

FLUSH_INTERVAL_S = 0.4     # < 0.5: "flushed at least twice a second"
JSON_INTERVAL_S = 2.0


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


class Recorder:
    """Record a session into `directory` (created if needed; raw.txt is appended to).

    write_line() is the LineParser's raw_sink, write_block() the FastLineParser's block sink;
    tick() is called often by the engine (it flushes raw.txt every FLUSH_INTERVAL_S and
    rewrites session.json when something changed).
    Thread-safe: the engine thread writes, a GUI may read size/elapsed.
    """

    def __init__(self, directory: str | Path, settings: Any = None,
                 info: dict[str, Any] | None = None) -> None:
        self.directory = Path(directory)
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self._raw = open(self.directory / "raw.txt", "ab")
        except OSError as error:
            raise OSError(f"cannot record into {self.directory}: {error.strerror or error}") \
                from None
        self._lock = threading.Lock()
        self.started_utc = datetime.now(timezone.utc).isoformat(timespec="milliseconds")
        self._started = time.monotonic()
        self._last_flush = self._started
        self._last_json = 0.0
        self._dirty = True
        self.lines_written = 0
        self.bytes_written = self._raw.tell()
        self.closed = False
        self.session: dict[str, Any] = {
            "app": "orientation-lab", "app_version": __version__,
            "started_utc": self.started_utc, "stopped_utc": None,
            "raw_file": "raw.txt", "settings": _jsonable(settings),
            "timeline": [], "stats": {}, **(info or {}),
        }
        self._write_json()

    @property
    def elapsed_s(self) -> float:
        return time.monotonic() - self._started

    def write_line(self, raw: bytes) -> None:
        """Append one received line verbatim (with its terminator)."""
        with self._lock:
            if self.closed:
                return
            self._raw.write(raw)
            self.lines_written += 1
            self.bytes_written += len(raw)

    def write_block(self, data: bytes, lines: int) -> None:
        """Append `lines` received lines at once, verbatim (`data` ends with a terminator)."""
        with self._lock:
            if self.closed:
                return
            self._raw.write(data)
            self.lines_written += lines
            self.bytes_written += len(data)

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
        """Flush raw.txt if due; rewrite session.json if it changed and is due."""
        now = time.monotonic()
        with self._lock:
            if self.closed:
                return
            if now - self._last_flush >= FLUSH_INTERVAL_S:
                self._raw.flush()
                self._last_flush = now
            if self._dirty and now - self._last_json >= JSON_INTERVAL_S:
                self._write_json()

    def flush(self) -> None:
        with self._lock:
            if not self.closed:
                self._raw.flush()
                self._write_json()

    def close(self) -> None:
        """Flush everything, stamp the stop time, close. Idempotent."""
        with self._lock:
            if self.closed:
                return
            self._raw.flush()
            self._raw.close()
            self.session["stopped_utc"] = datetime.now(timezone.utc).isoformat(
                timespec="milliseconds")
            self._write_json()
            self.closed = True

    def _write_json(self) -> None:
        self.session["raw_lines"] = self.lines_written
        self.session["raw_bytes"] = self.bytes_written
        write_json_atomic(self.directory / "session.json", self.session)
        self._last_json = time.monotonic()
        self._dirty = False
