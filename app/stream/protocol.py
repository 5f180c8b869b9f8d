"""The phone's line protocol (see ../shared/PROTOCOL.md): parse and format one line, and an
incremental byte-stream parser.

A line is ``<time>\\t<TAG>\\t<v1>\\t...\\t<vn>`` ending in LF (CRLF accepted). Fields are split
on TAB only (Wi-Fi names contain spaces). Numbers are Java float text (``3.2043457E-4``,
``-0.0``) in ASCII: digits of other scripts (a full-width ``９``) make a line damaged ("bad
number"). Times are integer milliseconds on the phone's clock.

Bad lines are never fatal: :func:`parse_line` raises :class:`ParseError` with a ``kind``
("damaged", "unknown_tag", "empty", "too_long") and :class:`LineParser` counts them; a damaged
line also has a ``reason`` (:data:`DAMAGE_REASONS`), counted per reason.

Plausibility: every sensor value is checked against physical bounds (:class:`Limits`, far
beyond any phone: |a| <= 2,000 m/s^2, |w| <= 100 rad/s, |m| <= 10,000 uT, ORI a unit
quaternion). A sample outside them is a damaged line ("ACC out of range", ...), so a finite but
absurd value (1e160) never reaches a filter.

Tags: :data:`TAGS` is the one table of every tag the app knows (../shared/PROTOCOL.md,
"Tags"): its name, how many fields a line carries, whether they are numbers or text, their
unit, the physical bound a sample must respect and whether the filters use it. Everything else
is made from it: the parsers' tag codes and value counts (here and in
:mod:`app.stream.fastparse`), the damaged-line reasons, the orderer's per-tag state
(:mod:`app.stream.ordering`), the runner's rows and the export columns (app.engine).

The tags the filters use (``role`` "sensor" or "reference") get the codes 0, 1, ...
(:data:`TAG_CODES`) in table order, which is also their order at equal times: the sensors
first, in the order of :data:`ekf.estimator.SENSORS` (each row of an estimator is fed gyr, acc,
mag), then the phone's own orientation, which estimates are compared with and which no filter
is fed.
"""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numba import njit

from ekf.estimator import SENSORS


@dataclass(frozen=True)
class Tag:
    """One stream tag.

    name: the tag on the line; width: the fields after it (ORI also accepts 3, its w dropped);
    text: the fields are strings (kept as text, never checked); unit: of its numbers;
    bound: the :class:`~app.stream.protocol.Limits` field bounding the norm of each of its
    3-vectors ("ori": a unit quaternion within ``Limits.ori_tolerance``), None: unchecked;
    floor: a zero vector is no reading of it (norm at least ``Limits.floor``);
    role: "sensor" (fed to the filters as ``name.lower()``), "reference" (the phone's own
    orientation, compared with the estimates) or None (passed through, never filtered);
    plotted: its values have plots of their own in the window."""

    name: str
    width: int
    text: bool = False
    unit: str = ""
    bound: str | None = None
    floor: bool = False
    role: str | None = None
    plotted: bool = False

    @property
    def sensor(self) -> str | None:
        """The filters' name of the sensor ("gyr", ...), None when no filter is fed it."""
        return self.name.lower() if self.role == "sensor" else None


TAGS: tuple[Tag, ...] = (
    Tag("GYR", 3, unit="rad/s", bound="gyr", role="sensor", plotted=True),
    Tag("ACC", 3, unit="m/s^2", bound="acc", floor=True, role="sensor", plotted=True),
    Tag("MAG", 3, unit="uT", bound="mag", floor=True, role="sensor", plotted=True),
    Tag("ORI", 4, bound="ori", role="reference", plotted=True),
    Tag("GPS", 3),
    Tag("PRS", 1, unit="hPa"),
    Tag("LGT", 1, unit="lx"),
    Tag("PRX", 1, unit="cm"),
    Tag("TMP", 1, unit="degC"),
    Tag("BAT", 3),
    Tag("RAWGYR", 6, unit="rad/s", bound="gyr"),
    Tag("RAWMAG", 6, unit="uT", bound="mag"),
    Tag("RSSWIFI", 4, text=True),
    Tag("RSSCELL", 6, text=True),
    Tag("RSSBLE", 3, text=True),
)

BY_NAME: dict[str, Tag] = {tag.name: tag for tag in TAGS}

#: The tags the filters use, in code order (= their order at equal times).
FILTER: tuple[Tag, ...] = tuple(tag for tag in TAGS if tag.role is not None)
FILTER_TAGS: tuple[str, ...] = tuple(tag.name for tag in FILTER)
#: tag name -> code (0, 1, ...: also their order at equal times).
TAG_CODES: dict[str, int] = {name: code for code, name in enumerate(FILTER_TAGS)}
N_FILTER_TAGS = len(FILTER)
#: Values per filter tag, by code, and the widest (the width of the value arrays).
WIDTHS: tuple[int, ...] = tuple(tag.width for tag in FILTER)
MAX_WIDTH = max(WIDTHS)
#: The codes of the sensor tags (in the order of ekf's SENSORS) and of the phone's orientation.
SENSOR_CODES: tuple[int, ...] = tuple(code for code, tag in enumerate(FILTER)
                                      if tag.role == "sensor")
REFERENCE_CODE: int = next(code for code, tag in enumerate(FILTER) if tag.role == "reference")
#: Out-of-range reasons of the tags with a bound, in table order ("GYR out of range", ...).
OUT_OF_RANGE: tuple[str, ...] = tuple(f"{tag.name} out of range" for tag in TAGS if tag.bound)

if tuple(FILTER[code].sensor for code in SENSOR_CODES) != SENSORS:
    raise ImportError(f"app.stream.protocol: the sensor tags "
                      f"{[FILTER[c].name for c in SENSOR_CODES]} do not match ekf's sensors "
                      f"{SENSORS}")
if not all(len(tag.name) == 3 and tag.name.isascii() for tag in FILTER):
    raise ImportError("app.stream.protocol: the compiled parser reads filter tags of 3 ASCII "
                      "letters")

#: The compiled parser's view of the filter tags: their ASCII bytes (N, 3), widths, the index
#: of their bound in ``Limits.squared`` (-1: the unit quaternion), whether a floor applies.
KERNEL_NAMES = np.array([[ord(c) for c in tag.name] for tag in FILTER], np.int64)
KERNEL_WIDTHS = np.array(WIDTHS, np.int64)
_SQUARED_SLOT = {"gyr": 0, "acc": 1, "mag": 2, "ori": -1}
KERNEL_BOUND_SLOTS = np.array([_SQUARED_SLOT[tag.bound] for tag in FILTER], np.int64)
KERNEL_FLOORS = np.array([tag.floor for tag in FILTER], np.bool_)

#: A hash of this module (the table above is in it): compiled stream kernels that read the
#: arrays above as constants are flushed from numba's cache when it changes (each module of
#: such kernels calls ``ekf.fast.jit.check_cache`` with it when imported; numba caches a
#: function keyed on its own source file only).
TABLE_KEY = int.from_bytes(hashlib.sha256(Path(__file__).read_bytes()).digest()[:7], "little")
#: The decorator of the stream's compiled kernels (the parser's, the orderer's, the runner's).
jit = njit(cache=True, nogil=True)


# -- the line protocol ---------------------------------------------------------------------------

#: Number of values per numeric tag. ORI also accepts 3 (w reconstructed).
NUMERIC_TAG_COUNTS: dict[str, int] = {tag.name: tag.width for tag in TAGS if not tag.text}
#: Number of text fields per text tag (kept as strings).
TEXT_TAG_COUNTS: dict[str, int] = {tag.name: tag.width for tag in TAGS if tag.text}
KNOWN_TAGS: frozenset[str] = frozenset(BY_NAME)

MAX_LINE_BYTES = 4096          # longer lines are discarded (bounded memory whatever a client sends)
PARSE_ERROR_KINDS = ("damaged", "unknown_tag", "empty", "too_long")
#: A time stamp with more digits is damaged (it would not fit the int64 times downstream).
MAX_TIME_DIGITS = 18

#: Why a line is damaged (ParseStats.damaged_reasons counts each). "binary data": a control byte
#: (NUL, ...) in the line; "cut off": the connection ended in the middle of the line.
DAMAGE_REASONS = ("binary data", "no tag", "bad time", "bad tag", "value count", "bad number",
                  *OUT_OF_RANGE, "cut off")
# Control characters that never occur in a text line (TAB, CR, LF and the other whitespace
# are not among them): one of them makes the line "binary data".
_CONTROL = re.compile("[\x00-\x08\x0e-\x1b\x7f]")
#: A 3-value ORI is a valid vector part only when its norm is at most 1 (+ float rounding).
ORI3_MAX_NORM = 1.0 + 1e-6


@dataclass(frozen=True)
class Limits:
    """Physical bounds a sample must respect, far beyond any phone (a phone's accelerometer
    saturates near 160 m/s^2, its gyroscope near 35 rad/s; the Earth's field is 25-65 uT).

    acc [m/s^2], gyr [rad/s], mag [uT]: bounds on the vector's norm (RAWGYR/RAWMAG: on each of
    their two vectors); floor: ACC and MAG need a norm of at least this (a zero vector has no
    direction and is no reading of a real sensor, far below any phone's resolution);
    ori_tolerance: a 4-value ORI must have every component in [-1, 1] and a norm within
    1 +- ori_tolerance (a 3-value ORI a vector part of norm <= 1).
    """

    acc: float = 2000.0
    gyr: float = 100.0
    mag: float = 10000.0
    ori_tolerance: float = 0.01
    floor: float = 1e-6

    @cached_property
    def squared(self) -> tuple[float, float, float, float, float, float]:
        """(gyr^2, acc^2, mag^2, lowest and highest squared ORI norm, floor^2): what both
        parsers compare the squared norms with (the same doubles, so they agree to the bit)."""
        return (self.gyr * self.gyr, self.acc * self.acc, self.mag * self.mag,
                (1.0 - self.ori_tolerance) ** 2, (1.0 + self.ori_tolerance) ** 2,
                self.floor * self.floor)

    def text(self) -> str:
        return (f"acc={self.acc:g},gyr={self.gyr:g},mag={self.mag:g},"
                f"ori={self.ori_tolerance:g},floor={self.floor:g}")


DEFAULT_LIMITS = Limits()


class Sample(NamedTuple):
    """One parsed line.

    t_ms: phone time in ms (after :class:`app.stream.ordering.TimeOrderer`, the aligned time).
    tag: "ACC", "GYR", ...; values: floats (ORI always 4 values w, x, y, z with w >= 0;
    empty for text tags); text: the string fields of RSSWIFI/RSSCELL/RSSBLE, else None.
    """

    t_ms: int
    tag: str
    values: tuple[float, ...]
    text: tuple[str, ...] | None = None


class ParseError(ValueError):
    """A line that is not a usable sample. ``kind`` is one of :data:`PARSE_ERROR_KINDS`;
    ``reason`` (damaged lines only) one of :data:`DAMAGE_REASONS`."""

    def __init__(self, kind: str, message: str, reason: str | None = None) -> None:
        super().__init__(message)
        self.kind = kind
        self.message = message
        self.reason = reason


def _damaged(reason: str, message: str) -> ParseError:
    return ParseError("damaged", message, reason)


def _is_tag_word(tag: str) -> bool:
    # What a future app version's tag could look like; anything else is a damaged line.
    return bool(tag) and tag.isascii() and tag.replace("_", "").isalnum() and tag.upper() == tag


def _ori_values(values: tuple[float, ...]) -> tuple[float, float, float, float]:
    if len(values) == 3:
        x, y, z = values
        w = math.sqrt(max(0.0, 1.0 - (x * x + y * y + z * z)))
        return (w, x, y, z)
    w, x, y, z = values
    if w < 0.0:  # q and -q are the same rotation; keep the house convention w >= 0
        return (-w, -x, -y, -z)
    return (w, x, y, z)


def _squared_norm(values: tuple[float, ...]) -> float:
    # Left to right, as the compiled parser adds them: the same double in both.
    total = 0.0
    for value in values:
        total = total + value * value
    return total


def check_limits(tag: str, values: tuple[float, ...], limits: Limits = DEFAULT_LIMITS) -> None:
    """ParseError("damaged", reason "<TAG> out of range") when a value is outside the physical
    bounds (values as written on the line, before the ORI w >= 0 flip)."""
    gyr2, acc2, mag2, ori_low2, ori_high2, floor2 = limits.squared
    declared = BY_NAME.get(tag)
    if declared is None or declared.bound is None:
        return
    if declared.bound != "ori":
        bound = {"gyr": gyr2, "acc": acc2, "mag": mag2}[declared.bound]
        unit = declared.unit
        vectors = [values[k:k + 3] for k in range(0, len(values), 3)]
        if not all(_squared_norm(vector) <= bound for vector in vectors):
            raise _damaged(f"{tag} out of range",
                           f"{tag} beyond the physical bound |v| <= {math.sqrt(bound):g} {unit}")
        if declared.floor and not _squared_norm(values) >= floor2:
            raise _damaged(f"{tag} out of range", f"{tag} is a zero vector (|v| < "
                           f"{math.sqrt(floor2):g} {unit}): no reading of a real sensor")
        return
    norm2 = _squared_norm(values)
    if len(values) == 3:
        if norm2 <= ORI3_MAX_NORM * ORI3_MAX_NORM:
            return
        raise _damaged(f"{tag} out of range", f"{tag} with 3 values is not a vector part "
                       "(norm > 1)")
    if all(-1.0 <= value <= 1.0 for value in values) and ori_low2 <= norm2 <= ori_high2:
        return
    raise _damaged(f"{tag} out of range", f"{tag} is not a unit quaternion")


def _preview(line: str, limit: int = 80) -> str:
    return repr(line if len(line) <= limit else line[:limit] + "...")


def parse_line(line: str, limits: Limits = DEFAULT_LIMITS) -> Sample:
    """Parse one line (without or with its LF/CRLF terminator) into a :class:`Sample`.

    Raises ParseError("empty") for a blank line, ("unknown_tag") for a well-formed line with a
    tag this program does not know, ("damaged", reason) for a control byte, a bad time, a
    wrong value count for a known tag, a value that is not a finite number or one outside the
    physical bounds of `limits`.
    """
    if line.endswith("\n"):
        line = line[:-1]
    if line.endswith("\r"):
        line = line[:-1]
    if not line.strip():
        raise ParseError("empty", "empty line")
    if _CONTROL.search(line):
        raise _damaged("binary data", f"binary data (control bytes) in {_preview(line)}")
    fields = line.split("\t")
    if len(fields) < 2:
        raise _damaged("no tag", f"no TAB-separated tag in {_preview(line)}")
    time_text, tag = fields[0], fields[1]
    if not (time_text.isascii() and time_text.isdigit()) or len(time_text) > MAX_TIME_DIGITS:
        # More than 18 digits does not fit the int64 times downstream (epoch ms has 13).
        raise _damaged("bad time", f"bad time {_preview(time_text)}")
    t_ms = int(time_text)
    count = NUMERIC_TAG_COUNTS.get(tag)
    if count is None:
        text_count = TEXT_TAG_COUNTS.get(tag)
        if text_count is None:
            if _is_tag_word(tag):
                raise ParseError("unknown_tag", f"unknown tag {_preview(tag)}")
            raise _damaged("bad tag", f"bad tag {_preview(tag)}")
        if len(fields) - 2 != text_count:
            raise _damaged("value count",
                           f"{tag} needs {text_count} fields, got {len(fields) - 2}")
        return Sample(t_ms, tag, (), tuple(fields[2:]))
    number_count = len(fields) - 2
    if number_count != count and not (tag == "ORI" and number_count == 3):
        raise _damaged("value count", f"{tag} needs {count} values, got {number_count}")
    try:
        values = tuple(_to_float(text) for text in fields[2:])
    except ValueError as error:
        raise _damaged("bad number", f"{tag}: {error}") from None
    check_limits(tag, values, limits)
    if tag == "ORI":
        values = _ori_values(values)
    return Sample(t_ms, tag, values)


def _to_float(text: str) -> float:
    # float() also accepts "1_0", " 1", "inf", "nan" and digits of other scripts ("９",
    # "٣"): Java never writes those, and a non-finite value would poison a filter.
    if not text.isascii() or "_" in text or text != text.strip():
        raise ValueError(f"bad number {_preview(text)}")
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"bad number {_preview(text)}")
    return value


def java_float_text(value: float) -> str:
    """Text for a float the way Java's Float.toString / Double.toString write it.

    The shortest digits that parse back to the same float64 (for a value parsed from the
    phone's text these are the phone's own digits: ``3.2043457E-4``). Plain notation for
    1e-3 <= |x| < 1e7, else ``d.dddE<exp>``.
    """
    if math.isnan(value):
        return "NaN"
    if math.isinf(value):
        return "Infinity" if value > 0 else "-Infinity"
    if value == 0.0:
        return "-0.0" if math.copysign(1.0, value) < 0 else "0.0"
    mantissa, exponent_text = np.format_float_scientific(
        np.float64(value), unique=True, trim="-").split("e")
    sign = "-" if mantissa.startswith("-") else ""
    digits = mantissa.lstrip("-").replace(".", "")
    exponent = int(exponent_text)
    if -3 <= exponent < 7:
        if exponent >= 0:
            integer = digits[: exponent + 1].ljust(exponent + 1, "0")
            fraction = digits[exponent + 1:] or "0"
        else:
            integer = "0"
            fraction = "0" * (-exponent - 1) + digits
        return f"{sign}{integer}.{fraction}"
    return f"{sign}{digits[0]}.{digits[1:] or '0'}E{exponent}"


def format_line(sample: Sample) -> str:
    """The protocol line for a sample, without the trailing LF. Parsing it gives the sample back."""
    if sample.text is not None:
        fields = sample.text
    else:
        fields = [java_float_text(float(v)) for v in sample.values]
    return f"{int(sample.t_ms)}\t{sample.tag}\t" + "\t".join(fields)


@dataclass
class ParseStats:
    """Counters of an incremental parse. ``lines`` counts every line seen (good or bad)."""

    lines: int = 0
    good: int = 0
    damaged: int = 0
    unknown: int = 0
    too_long: int = 0
    empty: int = 0
    bytes: int = 0
    per_tag: dict[str, int] = field(default_factory=dict)
    unknown_tags: dict[str, int] = field(default_factory=dict)   # at most 32 names kept
    first_bad_line_number: int | None = None
    first_bad_message: str | None = None
    bad_examples: list[tuple[int, str, str]] = field(default_factory=list)  # (line number, kind, msg)
    damaged_reasons: dict[str, int] = field(default_factory=dict)   # reason -> damaged lines

    def copy(self) -> ParseStats:
        return ParseStats(self.lines, self.good, self.damaged, self.unknown, self.too_long,
                          self.empty, self.bytes, dict(self.per_tag), dict(self.unknown_tags),
                          self.first_bad_line_number, self.first_bad_message,
                          list(self.bad_examples), dict(self.damaged_reasons))


def reasons_text(reasons: dict[str, int]) -> str:
    """"2 bad number, 1 ACC out of range": the damaged lines by reason, most frequent first."""
    ordered = sorted(reasons.items(), key=lambda item: (-item[1], item[0]))
    return ", ".join(f"{count} {reason}" for reason, count in ordered)


#: Example messages of bad lines a parse keeps (ParseStats.bad_examples).
MAX_BAD_EXAMPLES = 20


class LineParser:
    """Incremental parser: bytes in any chunking -> Samples, identical whatever the chunking.

    Lines split across reads are reassembled; LF or CRLF; invalid UTF-8 is tolerated (a line it
    breaks is counted as damaged); a line longer than MAX_LINE_BYTES is discarded without
    buffering more than that (counted as too_long). Values outside `limits` are damaged.

    raw_sink, when given, is called with the verbatim bytes (terminator included; LF added when
    :meth:`finish` flushes a line without one) of every line that parses to a sample, and only
    those: a recording holds no damaged line (a NUL byte makes a line damaged, never a file our
    tools refuse) and replays to the same samples.
    """

    def __init__(self, raw_sink: Callable[[bytes], None] | None = None,
                 max_line_bytes: int = MAX_LINE_BYTES, limits: Limits = DEFAULT_LIMITS) -> None:
        self.stats = ParseStats()
        self.raw_sink = raw_sink
        self.max_line_bytes = max_line_bytes
        self.limits = limits
        self._pending = b""
        self._discarding = False
        # A stream of 4-value ORI lines never sends a 3-value one: that is a torn line (its
        # vector part would always pass the norm check).
        self._ori4_seen = False

    def reset_line(self) -> None:
        """Drop a partial line (the connection it came from is gone). Not counted. The next
        stream may come from another app version: 3-value ORI lines are fine again."""
        self._pending = b""
        self._discarding = False
        self._ori4_seen = False

    def cut_off(self) -> None:
        """The stream ended inside a line (a disconnect): that line is counted (damaged, or too
        long when it was already over the limit) and dropped, as :meth:`reset_line` does."""
        if self._pending or self._discarding:
            kind = "too_long" if self._discarding else "damaged"
            self._count_bad(kind, "line cut off by the end of the connection", "cut off")
        self.reset_line()

    def count_damaged(self, message: str, reason: str | None = None) -> None:
        """A damaged line this parser did not see (a replay's torn last line)."""
        self._count_bad("damaged", message, reason)

    def line_state(self) -> tuple[bytes, bool, bool]:
        """What the parser keeps between two feeds (a partial line, discarding a long one, a
        4-value ORI seen), for :meth:`restore_line_state` (a replay's checkpoints)."""
        return self._pending, self._discarding, self._ori4_seen

    def restore_line_state(self, state: tuple[bytes, bool, bool]) -> None:
        self._pending, self._discarding, self._ori4_seen = bytes(state[0]), bool(state[1]), \
            bool(state[2])

    def feed(self, data: bytes) -> list[Sample]:
        """Parse the complete lines in pending + data; keep the unfinished tail (bounded)."""
        self.stats.bytes += len(data)
        samples: list[Sample] = []
        if not data:
            return samples
        if self._discarding:
            newline = data.find(b"\n")
            if newline < 0:
                return samples
            self._discarding = False
            self._pending = b""
            self._count_bad("too_long", "line longer than %d bytes discarded" % self.max_line_bytes)
            data = data[newline + 1:]
        buffer = self._pending + data if self._pending else data
        lines = buffer.split(b"\n")
        tail = lines.pop()
        for raw in lines:
            self._line(raw, True, samples)
        if len(tail) > self.max_line_bytes + 1:   # +1: the tail may end in the CR of a CRLF
            self._pending = b""
            self._discarding = True
        else:
            self._pending = tail
        return samples

    def finish(self) -> list[Sample]:
        """End of stream: parse a final line that has no newline; count a discarded long one."""
        samples: list[Sample] = []
        if self._discarding:
            self._discarding = False
            self._count_bad("too_long", "line longer than %d bytes discarded" % self.max_line_bytes)
        elif self._pending:
            raw, self._pending = self._pending, b""
            self._line(raw, False, samples)
        return samples

    # -- internals -------------------------------------------------------------------------

    def _count_bad(self, kind: str, message: str, reason: str | None = None) -> None:
        stats = self.stats
        stats.lines += 1
        if kind == "damaged":
            stats.damaged += 1
            reason = reason or "other"
            stats.damaged_reasons[reason] = stats.damaged_reasons.get(reason, 0) + 1
        elif kind == "unknown_tag":
            stats.unknown += 1
        elif kind == "too_long":
            stats.too_long += 1
        else:
            stats.empty += 1
        if kind == "empty":
            return
        if stats.first_bad_line_number is None:
            stats.first_bad_line_number = stats.lines
            stats.first_bad_message = f"{kind}: {message}"
        if len(stats.bad_examples) < MAX_BAD_EXAMPLES:
            stats.bad_examples.append((stats.lines, kind, message))

    def _line(self, raw: bytes, had_newline: bool, out: list[Sample],
              record: bool = True) -> bool:
        """One line; True when it gave a sample (appended to `out`, and recorded when
        `record`)."""
        # raw excludes the LF (a CR of a CRLF stays); the sink gets raw + LF either way, so a
        # final line without newline still ends a recording cleanly.
        content = raw[:-1] if raw.endswith(b"\r") else raw
        if len(content) > self.max_line_bytes:
            self._count_bad("too_long", f"line of {len(content)} bytes discarded")
            return False
        text = content.decode("utf-8", "replace")
        try:
            sample = parse_line(text, self.limits)
        except ParseError as error:
            self._count_bad(error.kind, error.message, error.reason)
            if error.kind == "unknown_tag":
                tag = text.split("\t", 2)[1]
                names = self.stats.unknown_tags
                if tag in names or len(names) < 32:
                    names[tag] = names.get(tag, 0) + 1
            return False
        if sample.tag == "ORI":
            if text.count("\t") == 4:                   # 3 values
                if self._ori4_seen:
                    self._count_bad("damaged", "ORI with 3 values in a stream of 4-value ORI "
                                    "lines (a torn line)", "value count")
                    return False
            else:
                self._ori4_seen = True
        stats = self.stats
        stats.lines += 1
        stats.good += 1
        stats.per_tag[sample.tag] = stats.per_tag.get(sample.tag, 0) + 1
        if record and self.raw_sink is not None:
            self.raw_sink(raw + b"\n")
        out.append(sample)
        return True
