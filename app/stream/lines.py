"""A log's lines as bytes: open (plain or gzip), split, and the time each one is due.

Shared by the replay sources and the phone emulator, which both send a file's lines verbatim
with its original timing.
"""

from __future__ import annotations

import contextlib
import gzip
import zlib
from collections.abc import Callable, Iterator
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


CHUNK_BYTES = 1 << 18          # the offline commands' reading: 256 KiB at a time (~5,000 lines)
_MAX_CARRY_BYTES = 1 << 24     # a "line" longer than this is passed on in pieces (bounded)


def log_chunks(path: str | Path, chunk_bytes: int = CHUNK_BYTES,
               on_read: Callable[[int], None] | None = None) -> Iterator[bytes]:
    """A log's bytes (plain or gzip) chunk by chunk, as read: memory for one chunk whatever the
    file's size. The first chunk is checked as text; `on_read` gets the bytes of the file read
    so far (of a gzip file: compressed) after each chunk. LogError when the file is missing, a
    folder, unreadable (a damaged gzip stream among them, wherever it breaks), mostly binary or
    empty (raised at the end, when nothing was read)."""
    path = Path(path)
    total = 0
    with open_log_bytes(path) as stream:
        underlying = getattr(stream, "fileobj", None) or stream    # a gzip file's own bytes
        while True:
            try:
                chunk = stream.read(chunk_bytes)
            except (OSError, EOFError, zlib.error) as error:
                raise LogError(f"{path}: cannot read ({why_unreadable(error)})") from None
            if on_read is not None:
                with contextlib.suppress(OSError, ValueError):
                    on_read(underlying.tell())
            if not chunk:
                break
            if total == 0:
                check_text(path, chunk)
            total += len(chunk)
            yield chunk
    if total == 0:
        raise LogError(f"{path}: empty file")


def line_blocks(path: str | Path, block_bytes: int = CHUNK_BYTES,
                drop_torn: bool = False) -> Iterator[bytes]:
    """A log's lines in blocks of whole lines, each block ending with LF (:func:`log_chunks`
    cut after its last LF). A last line without LF gets one, or, with `drop_torn` (a recording's
    raw.txt cut by a crash: the torn line could parse to a wrong value), is left out; LogError
    when that leaves no line at all. A line longer than 16 MiB is passed on in pieces, so memory
    stays bounded whatever the file holds."""
    carry = b""
    whole = False
    for chunk in log_chunks(path, block_bytes):
        data = carry + chunk if carry else chunk
        end = data.rfind(b"\n") + 1
        if end == 0:
            if len(data) <= _MAX_CARRY_BYTES:
                carry = data
                continue
            end = len(data)
        carry = data[end:]
        whole = True
        yield data[:end]
    if carry and not drop_torn:
        yield carry + b"\n"
    elif drop_torn and not whole:
        raise LogError(f"{path}: no whole line (a recording cut at its start)")


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
def _pacing(buf, starts, out, hashes, firsts, state):
    """pacing_times on a buffer of lines, going on from `state` (hashes and first times of the
    tags seen so far, state[0] their count, state[1] the latest elapsed time, ms), which it
    updates; False when it cannot (a time of more than 18 digits, too many distinct tags): the
    caller falls back to Python, and the state is left as it was."""
    hashes_now = hashes.copy()
    firsts_now = firsts.copy()
    tags = state[0]
    latest = state[1]
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
                if hashes_now[i] == h:
                    slot = i
                    break
            if slot < 0:
                if tags == _MAX_PACE_TAGS:
                    return False
                slot = tags
                hashes_now[slot] = h
                firsts_now[slot] = t
                tags += 1
            elapsed = t - firsts_now[slot]
            if elapsed > latest:
                latest = elapsed
        out[k] = latest / 1000.0
    hashes[:] = hashes_now
    firsts[:] = firsts_now
    state[0] = tags
    state[1] = latest
    return True


_FNV_OFFSET = 14695981039346656037
_FNV_PRIME = 1099511628211
_INT64_MAX = 2**63 - 1


def _tag_hash(tag: bytes) -> int:
    """The compiled pacing's hash of a tag (64-bit FNV-1a)."""
    h = _FNV_OFFSET
    for byte in tag:
        h = ((h ^ byte) * _FNV_PRIME) & 0xFFFFFFFFFFFFFFFF
    return h


class Pacer:
    """:func:`pacing_times` of a log's lines block after block (each tag's first time and the
    latest elapsed time carry over from one block to the next), compiled; a block the kernel
    cannot take (a time of more than 18 digits, more than 64 tags) goes through Python with the
    same state."""

    def __init__(self) -> None:
        self._firsts: dict[int, int] = {}       # tag hash -> the tag's first time [ms]
        self._latest = 0

    def times(self, data: bytes, starts: np.ndarray) -> np.ndarray:
        """(n,) seconds from the start at which each of the n lines of `data` (offsets
        `starts`, :func:`line_starts`) is due."""
        out = np.zeros(len(starts) - 1)
        if not len(out):
            return out
        firsts = self._firsts
        if len(firsts) <= _MAX_PACE_TAGS and self._latest <= _INT64_MAX and all(
                abs(t) <= _INT64_MAX for t in firsts.values()):
            hashes = np.zeros(_MAX_PACE_TAGS, np.uint64)
            known = np.zeros(_MAX_PACE_TAGS, np.int64)
            hashes[:len(firsts)] = list(firsts)
            known[:len(firsts)] = list(firsts.values())
            state = np.array([len(firsts), self._latest], np.int64)
            if _pacing(np.frombuffer(data, dtype=np.uint8), starts, out, hashes, known, state):
                count = int(state[0])
                self._firsts = dict(zip(hashes[:count].tolist(), known[:count].tolist()))
                self._latest = int(state[1])
                return out
        latest = self._latest
        for k, (a, b) in enumerate(zip(starts[:-1].tolist(), starts[1:].tolist())):
            fields = data[a:b].split(b"\t", 2)
            if len(fields) >= 2 and fields[0].isdigit():
                t = int(fields[0])
                elapsed = t - firsts.setdefault(_tag_hash(fields[1]), t)
                if elapsed > latest:
                    latest = elapsed
            out[k] = min(latest, 10**300) / 1000.0
        self._latest = latest
        return out


def pacing_array(data: bytes, starts: np.ndarray) -> np.ndarray:
    """:func:`pacing_times` of the lines of `data` (offsets `starts`), compiled: (n,) seconds."""
    return Pacer().times(data, starts)


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
