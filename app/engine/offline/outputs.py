"""Output files: never written over one of the command's inputs, and written as a shell's
redirection would, but never half.

One rule for every path a user chooses to write (``-o`` of filter, export, calibrate,
calibrate-mag, tune and simulate; the window's Export, Save settings and ``--screenshot``):

* :func:`check_output` refuses an output path that is one of the inputs (the same file, also
  through a link), lies inside an input folder or a recorded session's folder, or is a folder,
  a block device or a socket.
* :func:`open_output` writes by what the path is. A regular file, or a new one: a temporary
  file beside it, flushed to the disk and renamed over it on success, so a failed or
  interrupted write leaves the old file (or none), never half a file; the file keeps its
  permission bits. A character device (``/dev/null``, ``/dev/full``, a terminal) or a FIFO:
  written straight into, never replaced (a FIFO waits for its reader, as ``> FIFO`` does). A
  symbolic link: followed to its target, which is written by the same rule (a dangling link
  gets its target created). A write error (no space left, a closed pipe, no permission, a
  read-only folder) is a one-line :class:`ConfigError` naming the path.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from app.engine.errors import ConfigError

SESSION_FILE = "session.json"      # what makes a folder a recorded session

_STRAIGHT_KINDS = {stat.S_IFCHR: "a character device", stat.S_IFIFO: "a FIFO"}
_REFUSED_KINDS = {stat.S_IFBLK: "a block device", stat.S_IFSOCK: "a socket",
                  stat.S_IFDIR: "a folder"}


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _kind(path: str | Path) -> int | None:
    """The file type bits of what `path` names (links followed), None when nothing is there."""
    try:
        return stat.S_IFMT(os.stat(path).st_mode)
    except FileNotFoundError:
        return None
    except OSError as error:          # a loop of links, a folder we may not enter, ...
        raise ConfigError(f"cannot write {path}: {error.strerror or error}") from None


def check_output(out: str | Path, *inputs: str | Path | None) -> Path:
    """`out` as a Path; ConfigError (one line) when it is one of `inputs`, inside one that is
    a folder or inside a recorded session, or when it is a folder, a block device or a
    socket (nothing a command writes its output into)."""
    target = Path(out)
    kind = _kind(target)
    if kind in _REFUSED_KINDS:
        what = _REFUSED_KINDS[kind]
        raise ConfigError(f"{out}: is {what}; give a file name to write (a new or regular "
                          "file, a character device such as /dev/null, or a FIFO)")
    resolved = target.resolve()
    for given in inputs:
        if given is None:
            continue
        source = Path(given)
        if _same(target, source) or resolved == source.resolve():
            raise ConfigError(f"{out}: is the input {given}; give another file name to write "
                              "(an input is never written over)")
        if source.is_dir() and resolved.is_relative_to(source.resolve()):
            raise ConfigError(f"{out}: is inside the input folder {given}; write it elsewhere "
                              "(a session's own files are never written over)")
    if kind in (None, stat.S_IFREG) and (resolved.parent / SESSION_FILE).is_file():
        raise ConfigError(f"{out}: is inside the recorded session {resolved.parent}; write it "
                          "elsewhere (a session's own files are never written over)")
    return target


@contextlib.contextmanager
def open_output(out: str | Path, mode: str = "w", **open_args) -> Iterator[IO]:
    """A stream that writes `out` by the module's rule (atomically over a regular or new file,
    straight into a character device or a FIFO, through a symbolic link to its target).
    Any OSError while opening, writing or closing becomes a one-line ConfigError; an error
    of the block (anything else) leaves the old file as it was."""
    try:
        with _open(Path(out), mode, **open_args) as stream:
            yield stream
    except OSError as error:
        raise ConfigError(f"cannot write {out}: {error.strerror or error}") from None


def write_output(out: str | Path, data: str | bytes, encoding: str = "utf-8") -> None:
    """`data` written to `out` by :func:`open_output`."""
    if isinstance(data, bytes):
        with open_output(out, "wb") as stream:
            stream.write(data)
    else:
        with open_output(out, "w", encoding=encoding, newline="\n") as stream:
            stream.write(data)


def _open(path: Path, mode: str, **open_args) -> contextlib.AbstractContextManager[IO]:
    kind = _kind(path)
    if kind in _STRAIGHT_KINDS:
        return _straight(path, mode, kind, **open_args)
    if kind in _REFUSED_KINDS:
        raise ConfigError(f"{path}: is {_REFUSED_KINDS[kind]}; give a file name to write")
    return _atomic(Path(os.path.realpath(path)), mode, **open_args)


@contextlib.contextmanager
def _straight(path: Path, mode: str, kind: int, **open_args) -> Iterator[IO]:
    """Write into the device or FIFO itself: opened without creating anything (the node
    stays what it is), then checked to be what it was."""
    descriptor = os.open(path, os.O_WRONLY | getattr(os, "O_NOCTTY", 0)
                         | getattr(os, "O_CLOEXEC", 0))
    try:
        if stat.S_IFMT(os.fstat(descriptor).st_mode) != kind:
            raise ConfigError(f"{path}: changed while it was opened; not written")
    except BaseException:
        os.close(descriptor)
        raise
    with os.fdopen(descriptor, mode, **open_args) as stream:
        yield stream


@contextlib.contextmanager
def _atomic(target: Path, mode: str, **open_args) -> Iterator[IO]:
    """A temporary file beside `target`, synced and renamed to it when the block ends without
    an error (removed otherwise). A new file gets the permissions the umask gives; an
    existing one keeps its own (and, written by root, its owner)."""
    existing = None
    with contextlib.suppress(OSError):
        existing = os.stat(target)
    descriptor, temporary = _temporary_beside(target)
    try:
        with os.fdopen(descriptor, mode, **open_args) as stream:
            yield stream
            stream.flush()
            os.fsync(stream.fileno())
        if existing is not None:
            os.chmod(temporary, stat.S_IMODE(existing.st_mode))
            if _root() and (existing.st_uid, existing.st_gid) != (0, 0):
                with contextlib.suppress(OSError):
                    os.chown(temporary, existing.st_uid, existing.st_gid)
        os.replace(temporary, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise


def _temporary_beside(target: Path) -> tuple[int, Path]:
    """A new, empty file in target's folder (mode 0o666 less the umask, as open() makes it)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
    while True:
        temporary = target.with_name(f".{target.name}.{secrets.token_hex(4)}.part")
        try:
            return os.open(temporary, flags, 0o666), temporary
        except FileExistsError:
            continue


def _root() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0
