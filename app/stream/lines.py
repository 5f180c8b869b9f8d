"""A log's lines as bytes: open (plain or gzip), split, and the time each one is due.

Shared by the replay sources and the phone emulator, which both send a file's lines verbatim
with its original timing.
"""

from __future__ import annotations

import gzip
import zlib
from pathlib import Path

import numpy as np
from numba import njit


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


def why_unreadable(error: BaseException) -> str:
    """What went wrong reading a log, in words (a damaged gzip stream among them)."""
    if isinstance(error, (zlib.error, EOFError, gzip.BadGzipFile)):
        return f"a damaged or incomplete gzip file: {error}"
    return str(getattr(error, "strerror", None) or error)


def split_lines(data: bytes) -> list[bytes]:
    """Bytes -> lines with their LF (added to a last line that has none)."""
    lines = data.split(b"\n")
    last = lines.pop()
    out = [line + b"\n" for line in lines]
    if last:
        out.append(last + b"\n")
    return out


def read_log_bytes(path: str | Path, add_newline: bool = True) -> bytes:
    """A log's bytes (a last line without LF gets one, unless add_newline is False); LogError
    when it cannot be used."""
    path = Path(path)
    with open_log_bytes(path) as stream:
        try:
            data = stream.read()
        except (OSError, EOFError, zlib.error) as error:
            raise LogError(f"{path}: cannot read ({why_unreadable(error)})") from None
    if not data:
        raise LogError(f"{path}: empty file")
    check_text(path, data)
    return data if data.endswith(b"\n") or not add_newline else data + b"\n"


def read_lines(path: str | Path) -> list[bytes]:
    """A log's lines verbatim (each ending in LF); LogError when it cannot be used."""
    return split_lines(read_log_bytes(path))


_jit = njit(cache=True, nogil=True)


@_jit
def _line_starts(buf, out):
    k = 1
    for i in range(buf.shape[0]):
        if buf[i] == 10:
            out[k] = i + 1
            k += 1
    return k


def line_starts(data: bytes) -> np.ndarray:
    """(n + 1,) int64 offsets of the n lines of `data` (which ends with LF): line k is
    data[starts[k]:starts[k + 1]], its LF included. No temporaries (an hour of lines is 60 MB
    of text)."""
    out = np.empty(data.count(b"\n") + 1, np.int64)
    out[0] = 0
    if len(out) > 1:
        _line_starts(np.frombuffer(data, dtype=np.uint8), out)
    return out
_MAX_PACE_TAGS = 64


@_jit
def _pacing(buf, starts, out):
    """pacing_times on a buffer of lines; False when it cannot (a time of more than 18 digits,
    too many distinct tags): the caller falls back to Python."""
    hashes = np.zeros(_MAX_PACE_TAGS, np.uint64)
    firsts = np.zeros(_MAX_PACE_TAGS, np.int64)
    tags = 0
    latest = 0
    for k in range(starts.shape[0] - 1):
        a = starts[k]
        b = starts[k + 1]
        p = a
        t = 0
        while p < b and 48 <= buf[p] <= 57:
            t = t * 10 + (buf[p] - 48)
            p += 1
        if p - a > 18:
            return False
        if p > a and p < b and buf[p] == 9:
            # the tag: up to the next TAB or the line's end (LF included, as split() has it)
            h = np.uint64(14695981039346656037)
            q = p + 1
            while q < b and buf[q] != 9:
                h = (h ^ np.uint64(buf[q])) * np.uint64(1099511628211)
                q += 1
            slot = -1
            for i in range(tags):
                if hashes[i] == h:
                    slot = i
                    break
            if slot < 0:
                if tags == _MAX_PACE_TAGS:
                    return False
                slot = tags
                hashes[slot] = h
                firsts[slot] = t
                tags += 1
            elapsed = t - firsts[slot]
            if elapsed > latest:
                latest = elapsed
        out[k] = latest / 1000.0
    return True


def pacing_array(data: bytes, starts: np.ndarray) -> np.ndarray:
    """:func:`pacing_times` of the lines of `data` (offsets `starts`), compiled: (n,) seconds."""
    out = np.zeros(len(starts) - 1)
    if len(out) and _pacing(np.frombuffer(data, dtype=np.uint8), starts, out):
        return out
    if not len(out):
        return out
    return np.array(pacing_times([data[a:b] for a, b in zip(starts[:-1].tolist(),
                                                          starts[1:].tolist())]))


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
