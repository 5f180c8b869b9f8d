"""The set-up commands (a sensor switch, the estimator, the settings, the comparisons) applied
to the runner, each with its timeline entry for a recording: one handler per command type in
`SETUP_HANDLERS`."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import ekf
from app.engine.commands import (SetComparisonsEnabled, SetEstimator, SetSensorEnabled,
                                 SetSettings)


@dataclass(frozen=True)
class SetupContext:
    """What a set-up handler works on. record(kind, **data) writes the timeline entry;
    refuse(text) says why a command is refused; recording: the recording in progress (or
    None), which starts with new settings given before its first sample; fed: the samples fed
    so far."""

    runner: Any
    record: Callable[..., None]
    refuse: Callable[[str], None]
    recording: Any
    fed: int


def _sensor(context: SetupContext, command: SetSensorEnabled) -> bool:
    context.runner.set_sensor_enabled(command.sensor, command.enabled)
    context.record("sensor", sensor=command.sensor, enabled=command.enabled)
    return True


def _estimator(context: SetupContext, command: SetEstimator) -> bool:
    if command.name not in ekf.ESTIMATORS:
        context.refuse(f"unknown estimator {command.name!r}")
        return False
    context.runner.set_estimator(command.name)
    context.record("estimator", name=command.name)
    return True


def _settings(context: SetupContext, command: SetSettings) -> bool:
    context.runner.set_settings(command.settings)
    details = {"source": command.source} if command.source else {}
    if command.calibration is not None:
        details["profile"] = command.calibration.get("name")
    recording = context.recording
    if recording is not None and recording.active:
        recording.set_settings(command.settings, command.calibration, context.fed)
    context.record("settings", settings=command.settings.to_dict()
                   if hasattr(command.settings, "to_dict") else None, **details)
    return True


def _comparisons(context: SetupContext, command: SetComparisonsEnabled) -> bool:
    if command.estimator is not None and command.estimator not in ekf.ESTIMATORS:
        context.refuse(f"unknown estimator {command.estimator!r}")
        return False
    runner = context.runner
    runner.set_comparisons_enabled(command.enabled, command.estimator)
    context.record("comparisons", enabled=command.enabled,
                   estimator=runner.comparison_estimator)
    return True


SETUP_HANDLERS: dict[type, Callable[[SetupContext, Any], bool]] = {
    SetSensorEnabled: _sensor,
    SetEstimator: _estimator,
    SetSettings: _settings,
    SetComparisonsEnabled: _comparisons,
}
"""Each set-up command type and its handler; a handler returns False when it refuses."""
