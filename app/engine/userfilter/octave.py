"""Your filter written in MATLAB, run by GNU Octave: finding Octave, the folder, the command.

A MATLAB filter is a folder of ``.m`` files with the course's functions (``tu_qw``, ``mu_g``,
``mu_m``, ``mu_normalizeQ``; optionally ``acc_outlier``, ``mag_outlier``, ``filter_settings``).
Any ``.m`` file names its folder. Orientation Lab runs the course's filterTemplate loop around
those functions in a persistent ``octave-cli`` (the host in ``octave_host/``, fed blocks of
samples through pipes: docs/decisions/octave-bridge.md).

:class:`MatlabFolder` copies the folder's files into a private directory before Octave starts:
the ``.m`` files Octave runs are exactly the bytes hashed (the SHA-256 a recording notes), and a
file saved while the filter runs reaches it only with the next reload. Data files beside them
(a ``.mat`` of calibration results that ``filter_settings.m`` loads) are copied too.

:func:`find_octave` finds ``octave-cli``: the path given (``--octave``, the window's setting),
else on PATH, else where the installers put it; when there is none it says how to install it,
for the system it runs on.
"""

from __future__ import annotations

import glob
import hashlib
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

HOST_DIR = Path(__file__).resolve().with_name("octave_host")
HOST_SCRIPT = HOST_DIR / "ol_host.m"
COURSE_FUNCTIONS = ("tu_qw", "mu_g", "mu_m", "mu_normalizeQ")
MAX_COPIED_BYTES = 64 * 1024 * 1024      # data files beside the .m files, copied along
ENV_OCTAVE = "ORIENTATION_LAB_OCTAVE"    # the Octave to use when none is given


_chosen: str | None = None


def use_octave(path: str | os.PathLike | None) -> None:
    """The octave-cli MATLAB filters run in from now on (``--octave PATH``, the window's
    setting); None or "": found as :func:`find_octave` finds it. Checked when a filter loads."""
    global _chosen
    _chosen = str(path) if path is not None and str(path).strip() else None


def chosen_octave() -> str | None:
    """The octave-cli chosen with :func:`use_octave` (None: none chosen)."""
    return _chosen


class OctaveNotFound(Exception):
    """No usable octave-cli: the message says how to install it (one line)."""


def install_hint(platform: str = sys.platform) -> str:
    """How to install GNU Octave on this system, in one sentence."""
    if platform.startswith("win"):
        return ("install GNU Octave from https://octave.org/download (the Windows installer), "
                "then give its octave-cli.exe with --octave PATH or in the window's Your filter "
                "dock")
    if platform == "darwin":
        return ("install GNU Octave with `brew install octave` (Homebrew) or the app from "
                "https://octave.org/download, or give octave-cli with --octave PATH")
    return ("install GNU Octave (Debian, Ubuntu: `sudo apt-get install octave`; Fedora: `sudo dnf "
            "install octave`), or give octave-cli with --octave PATH")


def _installed_elsewhere() -> list[str]:
    """Where the Windows and macOS installers put octave-cli (newest first)."""
    patterns = []
    if sys.platform.startswith("win"):
        for root in (os.environ.get("ProgramFiles", r"C:\Program Files"),
                     os.environ.get("LOCALAPPDATA", "")):
            if root:
                patterns.append(os.path.join(root, "GNU Octave", "Octave-*", "mingw64", "bin",
                                             "octave-cli.exe"))
                patterns.append(os.path.join(root, "Programs", "GNU Octave", "Octave-*",
                                             "mingw64", "bin", "octave-cli.exe"))
    elif sys.platform == "darwin":
        patterns += ["/opt/homebrew/bin/octave-cli", "/usr/local/bin/octave-cli",
                     "/Applications/Octave-*.app/Contents/Resources/usr/bin/octave-cli"]
    found: list[str] = []
    for pattern in patterns:
        found += sorted(glob.glob(pattern), reverse=True)
    return found


def find_octave(given: str | os.PathLike | None = None) -> Path:
    """The octave-cli to run: `given` (a file, or a command on PATH), else the one chosen
    (:func:`use_octave`), else $ORIENTATION_LAB_OCTAVE, else ``octave-cli`` (or ``octave``) on
    PATH, else where the installers put it. OctaveNotFound when there is none."""
    if given is None or str(given).strip() == "":
        given = _chosen or os.environ.get(ENV_OCTAVE) or None
    if given is not None:
        text = str(given)
        path = Path(text).expanduser()
        if path.is_dir():
            for name in ("octave-cli", "octave-cli.exe", "bin/octave-cli",
                         "mingw64/bin/octave-cli.exe"):
                if (path / name).is_file():
                    return (path / name).resolve()
        if path.is_file() and os.access(path, os.X_OK):
            return path.resolve()
        which = shutil.which(text)
        if which:
            return Path(which)
        raise OctaveNotFound(f"Octave not found at {text}: {install_hint()}")
    for name in ("octave-cli", "octave"):
        which = shutil.which(name)
        if which:
            return Path(which)
    for candidate in _installed_elsewhere():
        return Path(candidate)
    raise OctaveNotFound(f"GNU Octave is not installed (a MATLAB filter runs in it): "
                         f"{install_hint()}")


def octave_command(octave: Path, code_dir: Path, folder: Path) -> list[str]:
    """The command line of the Octave host for a filter copied to code_dir from folder."""
    return [str(octave), "--no-gui", "--norc", "--quiet", "--no-window-system",
            "--no-history", str(HOST_SCRIPT), str(code_dir), str(folder)]


def is_matlab_filter(name: str | os.PathLike) -> bool:
    """Whether an estimator name is a MATLAB filter: a .m file, or a folder with .m files in it."""
    text = str(name)
    if text.lower().endswith(".m"):
        return True
    try:
        return any(entry.name.endswith(".m") for entry in os.scandir(Path(text).expanduser()))
    except OSError:
        return False


def filter_folder(path: str | os.PathLike) -> Path:
    """The folder a MATLAB filter is (a folder, or the folder of a .m file in it)."""
    path = Path(path).expanduser().resolve()
    return path if path.is_dir() or path.suffix.lower() != ".m" else path.parent


@dataclass(frozen=True)
class FolderFile:
    name: str
    data: bytes


class MatlabFolder:
    """A MATLAB filter's folder as it is now: its top-level ``.m`` files (the code) and the
    other files beside them, read once. :attr:`source` is the code as one byte string (each .m
    file's name, length and bytes, in name order), :attr:`sha256` its hash; :meth:`stat`
    changes whenever a .m file is saved, added or removed; :meth:`copy_to` writes exactly these
    bytes into a directory."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.folder = filter_folder(path)
        self.name = self.folder.name
        if not self.folder.is_dir():
            raise FileNotFoundError(f"{self.folder}: no such folder")
        self.code: list[FolderFile] = []
        self.data: list[FolderFile] = []
        self.skipped: list[str] = []
        copied = 0
        for entry in sorted(self.folder.iterdir(), key=lambda p: p.name):
            if not entry.is_file() or entry.name.startswith("."):
                continue
            if entry.suffix == ".m":
                self.code.append(FolderFile(entry.name, entry.read_bytes()))
                continue
            size = entry.stat().st_size
            if copied + size > MAX_COPIED_BYTES:
                self.skipped.append(entry.name)
                continue
            self.data.append(FolderFile(entry.name, entry.read_bytes()))
            copied += size
        self.source = b"".join(item.name.encode("utf-8") + b"\0"
                               + len(item.data).to_bytes(8, "little") + item.data
                               for item in self.code)
        self.sha256 = hashlib.sha256(self.source).hexdigest()

    @staticmethod
    def stat(path: str | os.PathLike) -> tuple | None:
        """The .m files' names, modification times and sizes (None: no such folder): it
        changes whenever one is saved, added or removed."""
        folder = filter_folder(path)
        try:
            entries = sorted((e.name, e.stat().st_mtime_ns, e.stat().st_size)
                             for e in os.scandir(folder)
                             if e.name.endswith(".m") and e.is_file())
        except OSError:
            return None
        return tuple(entries)

    def copy_to(self, directory: Path) -> None:
        for item in self.code + self.data:
            (directory / item.name).write_bytes(item.data)


def private_copy(folder: MatlabFolder) -> Path:
    """A new private directory holding the folder's files (the caller removes it)."""
    directory = Path(tempfile.mkdtemp(prefix="orientation-lab-matlab-"))
    folder.copy_to(directory)
    return directory
