"""Commands: user intent (from the window or a command) that the engine applies between two
batches of samples, in the order they were sent. Plain frozen dataclasses, no Qt.

:class:`ReplayControl` and the connection commands (:class:`AcceptConnection`,
:class:`IgnoreConnection`, :class:`SetAllowedNetworks`) are the stream layer's (the sources apply
them); they are re-exported here so that every command comes from one module.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from app.stream.events import (AcceptConnection, IgnoreConnection, ReplayControl,
                               SetAllowedNetworks)

__all__ = ["SetSensorEnabled", "SetEstimator", "SetSettings", "ResetFilter", "AlignHeading",
           "SetComparisonsEnabled", "ReplayControl", "AcceptConnection", "IgnoreConnection",
           "SetAllowedNetworks", "LoadUserFilter", "UnloadUserFilter", "SetConsistencyEnabled",
           "StartRecording", "StopRecording", "AddMarker", "SetMarkerLabel", "SetFollowTimeline",
           "SetForward"]


@dataclass(frozen=True)
class SetSensorEnabled:
    sensor: str        # "gyr" | "acc" | "mag"
    enabled: bool


@dataclass(frozen=True)
class SetEstimator:
    name: str          # "ekf" | "course" | "complementary" | "gyro" | "accmag" (see ekf.ESTIMATORS)


@dataclass(frozen=True)
class SetSettings:
    """New filter settings from the next sample on, recorded in the session (settings and a
    "settings" timeline entry). calibration: the profile they came from (Profile.to_dict()),
    kept in session.json's "calibration"; source: a word for the timeline ("panel", "reset to
    default", "profile", "tuned", ...)."""

    settings: Any      # ekf.EKFSettings
    calibration: Any = None
    source: str | None = None


@dataclass(frozen=True)
class ResetFilter:
    pass


@dataclass(frozen=True)
class AlignHeading:
    """Turn OWN's world about up so its heading matches PHONE's."""


@dataclass(frozen=True)
class SetComparisonsEnabled:
    """Run (or stop) the 7 sensor combinations side by side; `estimator` (a name from
    ekf.ESTIMATORS) chooses which estimator they run, None keeps the current one."""

    enabled: bool
    estimator: str | None = None


@dataclass(frozen=True)
class LoadUserFilter:
    """Run your filter file (a .py with class Filter) beside ours as YOURS; replaces a loaded
    one. File -> Load filter... sends it."""

    path: str


@dataclass(frozen=True)
class UnloadUserFilter:
    """Stop running your filter."""


@dataclass(frozen=True)
class SetForward:
    """Forward every line from the phone, verbatim and in order, to target ("HOST:PORT", e.g.
    the course kit's StreamSensorDataReader in MATLAB), as ``--forward`` does; None: stop.
    Replaces a running forward. The connection panel's "Forward to" sends it."""

    target: str | None


@dataclass(frozen=True)
class SetConsistencyEnabled:
    """Publish our EKF's innovations for the consistency view (costs a little per sample, so
    only while the view is open). Your filter's innovations are published whenever it returns
    them."""

    enabled: bool


@dataclass(frozen=True)
class StartRecording:
    """Record from now on into `folder` (None: a new folder named by date and time in the
    user's data folder, sessions/); a folder that holds a session already: DIR-2, ...
    max_mb / min_free_mb: the recorder's limits (None: its defaults; 0: no limit)."""

    folder: str | None = None
    max_mb: float | None = None
    min_free_mb: float | None = None


@dataclass(frozen=True)
class StopRecording:
    pass


@dataclass(frozen=True)
class AddMarker:
    """A marker at the latest sample (saved in the recording's, or the replayed session's,
    session.json)."""

    label: str = ""


@dataclass(frozen=True)
class SetMarkerLabel:
    id: int
    label: str


@dataclass(frozen=True)
class SetFollowTimeline:
    """Replaying a recorded session: back to the recording (True: its recorded set-up and
    timeline, none of your overrides and changes), or every kind of its configuration yours, at
    the values running now, for the whole replay (False). See
    app.engine.processing.configuration."""

    enabled: bool
