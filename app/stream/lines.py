"""A log's lines as bytes: open (plain or gzip), split, and the time each one is due.

Shared by the replay sources and the phone emulator, which both send a file's lines verbatim
with its original timing.
"""

from __future__ import annotations

import gzip
from pathlib import Path


class LogError(Exception):
    """A file that cannot be used as a log: missing, unreadable, empty, binary, no samples."""


BINARY_PROBE_BYTES = 1 << 16
BINARY_SHARE = 1 / 3


def binary_share(data: bytes) -> float:
    """The share of the characters in the first 64 KiB of `data` that are not text: control
    bytes (other than TAB, CR, LF) and bytes that are not UTF-8."""
    probe = data[:BINARY_PROBE_BYTES].decode("utf-8", "replace")
    if not probe:
        return 0.0
    text = probe.translate(_TEXT_CONTROLS)
    return (len(probe) - len(text) + text.count("\ufffd")) / len(probe)


# the control characters a text log never holds (TAB, LF, CR and FF/VT stay), deleted to count
_TEXT_CONTROLS = {code: None for code in [*range(0, 9), *range(14, 32), 127]}


def check_text(path: Path, data: bytes) -> None:
    """LogError when a file is mostly binary (more than a third of its first 64 KiB is not
    text). A log with NUL bytes or other junk in places is read: those lines are damaged."""
    share = binary_share(data)
    if share > BINARY_SHARE:
        raise LogError(f"{path}: binary data ({share:.0%} of the first 64 KiB is not text), "
                       "not a text log")


def open_log_bytes(path: str | Path):
    """Open a .txt or .txt.gz log for binary reading; LogError when it cannot be."""
    path = Path(path)
    if not path.exists():
        raise LogError(f"{path}: no such file")
    if path.is_dir():
        raise LogError(f"{path}: is a directory, not a log file")
    try:
        with open(path, "rb") as probe:
            magic = probe.read(2)
        if magic == b"\x1f\x8b":
            return gzip.open(path, "rb")
        return open(path, "rb")
    except OSError as error:
        raise LogError(f"{path}: cannot read ({error.strerror or error})") from None


def split_lines(data: bytes) -> list[bytes]:
    """Bytes -> lines with their LF (added to a last line that has none)."""
    lines = data.split(b"\n")
    last = lines.pop()
    out = [line + b"\n" for line in lines]
    if last:
        out.append(last + b"\n")
    return out


def read_lines(path: str | Path) -> list[bytes]:
    """A log's lines verbatim (each ending in LF); LogError when it cannot be used."""
    path = Path(path)
    with open_log_bytes(path) as stream:
        try:
            data = stream.read()
        except (OSError, EOFError, gzip.BadGzipFile) as error:
            raise LogError(f"{path}: cannot read ({error})") from None
    if not data:
        raise LogError(f"{path}: empty file")
    check_text(path, data)
    return split_lines(data)


def pacing_times(lines: list[bytes]) -> list[float]:
    """Seconds from the start at which each line is due, to replay with the original timing.

    Each tag's clock is followed on its own (relative to its first sample: tags may sit on
    other clocks, e.g. ACC +131,072,000 ms or RSSWIFI in epoch ms) and the running maximum
    keeps the schedule monotonic while the lines keep their file order.
    """
    first: dict[bytes, int] = {}
    out: list[float] = []
    latest = 0
    for line in lines:
        fields = line.split(b"\t", 2)
        if len(fields) >= 2 and fields[0].isdigit():
            t = int(fields[0])
            tag = fields[1]
            start = first.setdefault(tag, t)
            elapsed = t - start
            if elapsed > latest:
                latest = elapsed
        out.append(latest / 1000.0)
    return out
