"""Where the user's own files live: recorded sessions, profiles and the log file.

The platform's standard per-user data folder, without Qt so the headless commands find the same
place as the window (what Qt's QStandardPaths.AppDataLocation gives for the application name
"OrientationLab"): %APPDATA%\\OrientationLab on Windows, ~/Library/Application Support/
OrientationLab on macOS, $XDG_DATA_HOME/OrientationLab (default ~/.local/share/OrientationLab)
elsewhere. The environment variable ORIENTATION_LAB_DATA overrides it (tests, portable set-ups).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

APP_NAME = "OrientationLab"


class DataDirError(OSError):
    """The data folder is a file, or cannot be made; the message says which, on one line."""


def data_dir(create: bool = True) -> Path:
    """The user's data folder for Orientation Lab (created unless create=False);
    :class:`DataDirError` when it is a file or cannot be made."""
    override = os.environ.get("ORIENTATION_LAB_DATA")
    if override:
        folder = Path(override)
    elif sys.platform == "win32":
        folder = Path(os.environ.get("APPDATA") or Path.home() / "AppData" / "Roaming") / APP_NAME
    elif sys.platform == "darwin":
        folder = Path.home() / "Library" / "Application Support" / APP_NAME
    else:
        base = os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share"
        folder = Path(base) / APP_NAME
    where = f"{folder} (ORIENTATION_LAB_DATA)" if override else str(folder)
    if folder.exists() and not folder.is_dir():
        raise DataDirError(f"the data folder {where} is a file, not a folder")
    if create:
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise DataDirError(f"cannot make the data folder {where}: "
                               f"{error.strerror or error}") from None
    return folder


def log_file() -> Path:
    """Where the window writes its log (engine failures with their tracebacks)."""
    return data_dir() / "orientation-lab.log"
