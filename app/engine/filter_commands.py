"""The set-up commands (a sensor switch, the estimator, the settings, the comparisons, a reset,
a heading alignment) as changes of the configuration (:class:`~app.engine.configuration.Change`):
one maker per command type in `SETUP_CHANGES`; a maker returns None when it refuses (saying
why through `refuse`). The engine hands the change to its replay lane, which makes it an
override or a change at the current sample (:meth:`ReplayLane.change
<app.engine.replay_lane.ReplayLane.change>`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import ekf
from app.engine.commands import (AlignHeading, ResetFilter, SetComparisonsEnabled, SetEstimator,
                                 SetSensorEnabled, SetSettings)
from app.engine.configuration import Change

Refuse = Callable[[str], None]


def _sensor(command: SetSensorEnabled, refuse: Refuse) -> Change | None:
    if command.sensor not in ekf.SENSORS:
        refuse(f"unknown sensor {command.sensor!r}")
        return None
    return Change.of(command.sensor, bool(command.enabled))


def _estimator(command: SetEstimator, refuse: Refuse) -> Change | None:
    if command.name not in ekf.ESTIMATORS:
        refuse(f"unknown estimator {command.name!r}")
        return None
    return Change.of("estimator", command.name)


def _settings(command: SetSettings, refuse: Refuse) -> Change | None:
    if not isinstance(command.settings, ekf.EKFSettings):
        refuse(f"settings: expected filter settings, got {type(command.settings).__name__}")
        return None
    note: list[tuple[str, Any]] = [("source", command.source)] if command.source else []
    if command.calibration is not None:
        note.append(("profile", command.calibration.get("name")))
    return Change(0, "settings", settings=command.settings, note=tuple(note),
                  calibration=command.calibration)


def _comparisons(command: SetComparisonsEnabled, refuse: Refuse) -> Change | None:
    if command.estimator is not None and command.estimator not in ekf.ESTIMATORS:
        refuse(f"unknown estimator {command.estimator!r}")
        return None
    return Change(0, "comparisons", enabled=bool(command.enabled), name=command.estimator)


SETUP_CHANGES: dict[type, Callable[[Any, Refuse], Change | None]] = {
    SetSensorEnabled: _sensor,
    SetEstimator: _estimator,
    SetSettings: _settings,
    SetComparisonsEnabled: _comparisons,
    ResetFilter: lambda command, refuse: Change(0, "reset"),
    AlignHeading: lambda command, refuse: Change(0, "align_heading"),
}
"""Each set-up command type and the change it makes (None: refused)."""
