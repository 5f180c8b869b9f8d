"""Commands: user intent (from the window or a command) that the engine applies between two
batches of samples, in the order they were sent. Plain frozen dataclasses, no Qt.

:class:`ReplayControl` is the stream layer's (replay sources apply it); it is re-exported here so
that every command comes from one module.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from app.stream.events import ReplayControl

__all__ = ["SetSensorEnabled", "SetEstimator", "SetSettings", "ResetFilter", "AlignHeading",
           "SetComparisonsEnabled", "ReplayControl", "LoadUserFilter", "UnloadUserFilter",
           "SetConsistencyEnabled"]


@dataclass(frozen=True)
class SetSensorEnabled:
    sensor: str        # "gyr" | "acc" | "mag"
    enabled: bool


@dataclass(frozen=True)
class SetEstimator:
    name: str          # "ekf" | "course" | "complementary" | "gyro" | "accmag" (see ekf.ESTIMATORS)


@dataclass(frozen=True)
class SetSettings:
    settings: Any      # ekf.EKFSettings


@dataclass(frozen=True)
class ResetFilter:
    pass


@dataclass(frozen=True)
class AlignHeading:
    """Turn OWN's world about up so its heading matches PHONE's."""


@dataclass(frozen=True)
class SetComparisonsEnabled:
    enabled: bool


@dataclass(frozen=True)
class LoadUserFilter:
    """Run your filter file (a .py with class Filter) beside ours as YOURS; replaces a loaded
    one. File -> Load filter... sends it."""

    path: str


@dataclass(frozen=True)
class UnloadUserFilter:
    """Stop running your filter."""


@dataclass(frozen=True)
class SetConsistencyEnabled:
    """Publish our EKF's innovations for the consistency view (costs a little per sample, so
    only while the view is open). Your filter's innovations are published whenever it returns
    them."""

    enabled: bool
