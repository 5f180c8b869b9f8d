"""The phone's stream tags, declared once (see ../shared/PROTOCOL.md, "Tags").

:data:`TAGS` is the one table of every tag the app knows: its name, how many fields a line
carries, whether they are numbers or text, their unit, the physical bound a sample must respect
and whether the filters use it. Everything else is made from it: the parsers' tag codes and
value counts (:mod:`app.stream.protocol`, :mod:`app.stream.fastparse`), the damaged-line
reasons, the orderer's per-tag state (:mod:`app.stream.ordering_kernels`), the runner's rows
(:mod:`app.engine.processing.runner`) and the export columns (:mod:`app.engine.offline.export`).

The tags the filters use (``role`` "sensor" or "reference") get the codes 0, 1, ... in table
order, which is also their order at equal times: the sensors first, in the order of
:data:`ekf.estimator.SENSORS` (each row of an estimator is fed gyr, acc, mag), then the
phone's own orientation, which estimates are compared with and which no filter is fed.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

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
CODES: dict[str, int] = {name: code for code, name in enumerate(FILTER_TAGS)}
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
    raise ImportError(f"app.stream.tags: the sensor tags {[FILTER[c].name for c in SENSOR_CODES]}"
                      f" do not match ekf's sensors {SENSORS}")
if not all(len(tag.name) == 3 and tag.name.isascii() for tag in FILTER):
    raise ImportError("app.stream.tags: the compiled parser reads filter tags of 3 ASCII letters")

#: The compiled parser's view of the filter tags: their ASCII bytes (N, 3), widths, the index
#: of their bound in ``Limits.squared`` (-1: the unit quaternion), whether a floor applies.
KERNEL_NAMES = np.array([[ord(c) for c in tag.name] for tag in FILTER], np.int64)
KERNEL_WIDTHS = np.array(WIDTHS, np.int64)
_SQUARED_SLOT = {"gyr": 0, "acc": 1, "mag": 2, "ori": -1}
KERNEL_BOUND_SLOTS = np.array([_SQUARED_SLOT[tag.bound] for tag in FILTER], np.int64)
KERNEL_FLOORS = np.array([tag.floor for tag in FILTER], np.bool_)

#: A hash of this table: compiled stream kernels that read the arrays above as constants are
#: flushed from numba's cache when it changes (:func:`app.stream.kernels.check_cache`).
TABLE_KEY = int.from_bytes(hashlib.sha256(Path(__file__).read_bytes()).digest()[:7], "little")
