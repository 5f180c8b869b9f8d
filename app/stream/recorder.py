"""Crash-safe session recording (DESIGN.md section 5), that never takes the stream down.

A session is a folder: ``raw.txt`` holds every received line that parses to a sample, verbatim,
in the phone's format with no header (the course's MATLAB reader and our own replay read it),
appended and flushed at least twice a second; ``session.json`` holds the app version, UTC start
time, settings, the sensor-toggle/marker timeline and stream statistics, rewritten atomically.

A folder is claimed atomically: a recording creates its ``raw.txt`` exclusively (``O_EXCL``),
so of two recorders started on one folder at the same moment one gets it and the other the next
free ``DIR-2``, ``DIR-3``, ...; a folder that holds a session (raw.txt or session.json) is never
written to.

Faults: a write error (disk full, the folder removed, a file size limit), also from flush or
close, stops the recording: :attr:`Recorder.error` says why in one line and every later write is
ignored, so the stream and the estimates go on. ``max_bytes`` (raw.txt's size) and
``min_free_bytes`` (free space left on the disk) stop it the same way before the disk is full.
What was recorded is finished: raw.txt ends at its last whole line, and session.json gets the
stop reason and the counts of what raw.txt holds. For that last rewrite to fit on a full disk,
the folder keeps ``session.json.reserve`` allocated while recording (at least twice
session.json's size), removed just before the last rewrite; if even that fails, the rewrite is
tried again on every later :meth:`Recorder.tick` and :meth:`Recorder.close`. A recording
refused at its start (too little free space, session.json cannot be written) raises OSError and
leaves nothing behind: what it made is removed.
"""

from __future__ import annotations

import contextlib
import errno
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
RESERVE_NAME = "session.json.reserve"
RESERVE_MIN_BYTES = 64 << 10


def _jsonable(value: Any) -> Any:
    if hasattr(value, "to_dict"):
        return value.to_dict()
    if is_dataclass(value) and not isinstance(value, type):
        return asdict(value)
    return value


def write_json_atomic(path: Path, data: Any) -> int:
    """Write JSON to a temporary file beside `path`, then rename it over `path`; the size
    written. A write that fails (OSError) leaves `path` as it was and no temporary file."""
    text = json.dumps(data, indent=2, default=str).encode("utf-8")
    temporary = path.with_name(path.name + ".tmp")
    try:
        with open(temporary, "wb") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException as error:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        if isinstance(error, OSError) and not error.filename:
            error.filename = str(temporary)
        raise
    return len(text)


def holds_session(directory: str | Path) -> bool:
    """Does the folder already hold a recorded session (raw.txt or session.json)?"""
    return any((Path(directory) / name).exists() for name in SESSION_FILES)


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


def _existing_ancestor(path: Path) -> Path:
    """`path` or the nearest of its parents that exists (where a new folder would go)."""
    path = path.absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def _free_bytes(path: Path) -> int:
    status = os.statvfs(path)
    return status.f_bavail * status.f_frsize


def _allocate(path: Path, size: int) -> None:
    """Make `path` hold `size` bytes of disk space (allocated, not a sparse file)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o666)
    try:
        try:
            os.posix_fallocate(fd, 0, size)
            return
        except (AttributeError, OSError) as error:     # no fallocate here: write zeros
            if isinstance(error, OSError) and error.errno not in (errno.EOPNOTSUPP,
                                                                   errno.EINVAL):
                raise
        have = os.fstat(fd).st_size
        os.lseek(fd, have, os.SEEK_SET)
        while have < size:
            have += os.write(fd, bytes(min(size - have, 1 << 16)))
        os.fsync(fd)
    finally:
        os.close(fd)


class Recorder:
    """Record a session into `directory`, or when that holds a session already (or another
    recorder claims it at the same moment) into the first free DIR-2, DIR-3, ...:
    :attr:`directory` is the folder it claimed (made if needed, with a new raw.txt).

    write_line() is the LineParser's raw_sink, write_block() the FastLineParser's block sink;
    tick() is called often by the engine (it flushes raw.txt every FLUSH_INTERVAL_S, rewrites
    session.json when something changed and checks the free space). Thread-safe: the engine
    thread writes, a GUI may read size/elapsed/error. Raises OSError (one line) only from the
    constructor: the folder or its files cannot be made, or less than `min_free_bytes` are free
    (then nothing is left behind); afterwards a fault stops the recording (see the module
    docstring). max_bytes / min_free_bytes: 0 = no limit. clock: the monotonic seconds the
    flush, session.json and free-space intervals and elapsed_s count in (tests give a fake).
    """

    def __init__(self, directory: str | Path, settings: Any = None,
                 info: dict[str, Any] | None = None, max_bytes: int = DEFAULT_MAX_BYTES,
                 min_free_bytes: int = DEFAULT_MIN_FREE_BYTES,
                 clock: Callable[[], float] = time.monotonic) -> None:
        requested = Path(directory)
        self.max_bytes = int(max_bytes)
        self.min_free_bytes = int(min_free_bytes)
        self._made: list[Path] = []          # folders this recorder made, outermost first
        self._refuse_when_short(requested)
        try:
            self.directory, self._raw = self._claim(requested)
        except OSError as error:
            self._remove_made()
            raise OSError(f"cannot record into {requested}: {error.strerror or error}") \
                from None
        self._lock = threading.Lock()
        self._clock = clock
        self.started_utc = datetime.now(timezone.utc).isoformat(timespec="milliseconds")
        self._started = self._clock()
        self._last_flush = self._started
        self._last_json = 0.0
        self._last_free_check = self._started
        self._bytes_at_free_check = 0
        self._dirty = True
        self._json_pending = False           # the last rewrite of session.json is owed
        self._reserved = 0                   # bytes session.json.reserve holds
        self.lines_written = 0
        self.bytes_written = self._raw.tell()
        self._synced_lines = 0               # what raw.txt holds for sure (the last flush)
        self._synced_bytes = self.bytes_written
        self.closed = False
        self.error: str | None = None     # why the recording stopped early (one line)
        self.session: dict[str, Any] = {
            "app": "orientation-lab", "app_version": __version__,
            "started_utc": self.started_utc, "stopped_utc": None,
            "raw_file": "raw.txt", "settings": _jsonable(settings),
            "timeline": [], "stats": {}, **(info or {}),
        }
        try:
            self._write_json()
        except OSError as error:
            self.discard()
            raise OSError(f"cannot record into {self.directory}: cannot write "
                          f"{getattr(error, 'filename', None) or 'session.json'}: "
                          f"{error.strerror or error}") from None

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

    def set_phone(self, peer: str | None) -> None:
        """Who streams (session.json "phone")."""
        with self._lock:
            self.session["phone"] = peer
            self._dirty = True

    def relabel_marker(self, marker_id: Any, label: str) -> None:
        """A marker's new label, in the timeline."""
        with self._lock:
            for event in self.session["timeline"]:
                if event.get("kind") == "marker" and event.get("id") == marker_id:
                    event["label"] = label
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
        free space once a second. After a stop, try the owed last rewrite of session.json
        again (every JSON_INTERVAL_S)."""
        now = self._clock()
        with self._lock:
            if self.closed:
                if self._json_pending and now - self._last_json >= JSON_INTERVAL_S:
                    self._finish_json()
                return
            if now - self._last_flush >= FLUSH_INTERVAL_S:
                self._last_flush = now
                if not self._guarded(self._flush_raw):
                    return
            if self._dirty and now - self._last_json >= JSON_INTERVAL_S:
                if not self._guarded(self._write_json):
                    return
            if now - self._last_free_check >= FREE_CHECK_INTERVAL_S:
                self._check_free_space(now)

    def flush(self) -> None:
        with self._lock:
            if not self.closed and self._guarded(self._flush_raw):
                self._guarded(self._write_json)

    def close(self) -> None:
        """Flush everything, stamp the stop time, close. Idempotent; never raises (an error
        here is kept in :attr:`error`; an owed rewrite of session.json is tried again)."""
        with self._lock:
            if self.closed:
                if self._json_pending:
                    self._finish_json()
                return
            self._close_files()

    def discard(self) -> None:
        """A recording refused at its start is never a session: close it and remove what it
        made (raw.txt, session.json, the reserve, the folders it made). Only while it has
        recorded no line; otherwise the same as :meth:`close`."""
        if self.lines_written:
            self.close()
            return
        self.closed = True
        with contextlib.suppress(OSError):
            self._raw.close()
        for name in ("raw.txt", "session.json", "session.json.tmp", RESERVE_NAME):
            with contextlib.suppress(OSError):
                os.unlink(self.directory / name)
        self._remove_made()

    # -- internals -------------------------------------------------------------------------

    def _refuse_when_short(self, requested: Path) -> None:
        """OSError before anything is made when less than min_free_bytes are free."""
        if not self.min_free_bytes:
            return
        try:
            free = _free_bytes(_existing_ancestor(requested))
        except OSError:
            return                      # the claim says what is wrong with the place
        if free < self.min_free_bytes:
            raise OSError(f"cannot record into {requested}: less than "
                          f"{_megabytes(self.min_free_bytes)} free on the disk "
                          f"({_megabytes(free)} left)")

    def _claim(self, requested: Path) -> tuple[Path, Any]:
        """The first of `requested`, DIR-2, DIR-3, ... that holds no session, claimed by
        creating its raw.txt exclusively; (folder, raw.txt open for appending)."""
        base = requested if requested.name else requested.absolute()
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND \
            | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
        number = 1
        while True:
            folder = base if number == 1 else base.with_name(f"{base.name}-{number}")
            number += 1
            if holds_session(folder):
                continue
            self._make_folder(folder)
            try:
                fd = os.open(folder / "raw.txt", flags, 0o666)
            except FileExistsError:
                continue
            if os.path.lexists(folder / "session.json"):    # an old session's folder
                os.close(fd)
                os.unlink(folder / "raw.txt")
                continue
            return folder, os.fdopen(fd, "ab")

    def _make_folder(self, folder: Path) -> None:
        missing = []
        path = folder.absolute()
        while not path.exists() and path != path.parent:
            missing.append(path)
            path = path.parent
        for path in reversed(missing):
            try:
                path.mkdir()
            except FileExistsError:       # another recorder made it at the same moment
                continue
            self._made.append(path)

    def _remove_made(self) -> None:
        for path in reversed(self._made):
            with contextlib.suppress(OSError):
                path.rmdir()
        self._made = []

    def _guarded(self, operation, *args) -> bool:
        """Run a file operation; on OSError stop the recording. True when it worked."""
        try:
            operation(*args)
        except OSError as error:
            where = getattr(error, "filename", None) or self.directory / "raw.txt"
            self._stop(f"cannot write {where}: {error.strerror or error}")
            return False
        return True

    def _flush_raw(self) -> None:
        self._raw.flush()
        self._synced_lines = self.lines_written
        self._synced_bytes = self.bytes_written

    def _check_free_space(self, now: float) -> None:
        self._last_free_check = now
        self._bytes_at_free_check = self.bytes_written
        if not self.min_free_bytes or self.closed:
            return
        try:
            free = _free_bytes(self.directory)
        except FileNotFoundError:
            self._stop(f"the folder {self.directory} was removed")
            return
        except OSError as error:
            self._stop(f"cannot read the free space of {self.directory}: "
                       f"{error.strerror or error}")
            return
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
            self._flush_raw()
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
            self._count_what_is_on_disk()
        self._finish_json()

    def _count_what_is_on_disk(self) -> None:
        """After a write error: the counts of what raw.txt holds (whole lines), from what the
        last flush wrote for sure and the lines after it."""
        path = self.directory / "raw.txt"
        try:
            if not stat.S_ISREG(os.stat(path).st_mode):
                return
            with open(path, "rb") as stream:
                size = stream.seek(0, os.SEEK_END)
                start, lines = self._synced_bytes, self._synced_lines
                if size < start:                 # shorter than flushed: count all of it
                    start, lines = 0, 0
                stream.seek(start)
                while block := stream.read(1 << 20):
                    lines += block.count(b"\n")
        except OSError:
            return
        self.lines_written = lines
        self.bytes_written = size

    def _finish_json(self) -> None:
        """The last rewrite of session.json; on a full disk the reserve makes room for it; if
        it still fails it stays owed (tick/close try again)."""
        try:
            self._write_json()
        except OSError:
            self._release_reserve()
            try:
                self._write_json()
            except OSError:
                self._json_pending = True
                self._last_json = self._clock()
                return
        self._json_pending = False
        self._release_reserve()

    def _release_reserve(self) -> None:
        with contextlib.suppress(OSError):
            os.unlink(self.directory / RESERVE_NAME)
        self._reserved = 0

    def _write_json(self) -> None:
        self.session["raw_lines"] = self.lines_written
        self.session["raw_bytes"] = self.bytes_written
        size = write_json_atomic(self.directory / "session.json", self.session)
        self._last_json = self._clock()
        self._dirty = False
        if not self.closed:
            self._keep_reserve(size)

    def _keep_reserve(self, json_size: int) -> None:
        """session.json.reserve: at least twice session.json's size (best effort)."""
        wanted = max(RESERVE_MIN_BYTES, 2 * json_size)
        if wanted <= self._reserved:
            return
        try:
            _allocate(self.directory / RESERVE_NAME, wanted)
        except OSError:
            return
        self._reserved = wanted
