"""Output files: never written over one of the command's inputs, and replaced only whole.

* :func:`check_output` refuses an output path that is one of the inputs (the same file, also
  through a link), or lies inside an input folder or a recorded session's folder.
* :func:`atomic_output` writes beside the target and renames it into place on success, so a
  failed or interrupted write leaves the old file (or none), never half a file.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from app.engine.errors import ConfigError

SESSION_FILE = "session.json"      # what makes a folder a recorded session


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_output(out: str | Path, *inputs: str | Path | None) -> Path:
    """`out` as a Path; ConfigError (one line) when it is one of `inputs` or inside one that is
    a folder."""
    target = Path(out)
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
    if (resolved.parent / SESSION_FILE).is_file():
        raise ConfigError(f"{out}: is inside the recorded session {resolved.parent}; write it "
                          "elsewhere (a session's own files are never written over)")
    return target


@contextlib.contextmanager
def atomic_output(out: str | Path, mode: str = "w", **open_args) -> Iterator[IO]:
    """A stream to a temporary file beside `out`, renamed to `out` when the block ends without
    an error (removed otherwise)."""
    target = Path(out)
    handle, temporary = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part",
                                         dir=target.parent if str(target.parent) else ".")
    try:
        with os.fdopen(handle, mode, **open_args) as stream:
            yield stream
        if target.exists():
            os.chmod(temporary, target.stat().st_mode & 0o777)
        else:
            os.chmod(temporary, 0o666 & ~_umask())
        os.replace(temporary, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
