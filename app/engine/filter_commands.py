"""The set-up commands (a sensor switch, the estimator, the settings, the comparisons) applied
to the runner, each with its timeline entry for a recording."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import ekf
from app.engine.commands import (SetComparisonsEnabled, SetEstimator, SetSensorEnabled,
                                 SetSettings)

SETUP_COMMANDS = (SetSensorEnabled, SetEstimator, SetSettings, SetComparisonsEnabled)


def apply_setup(runner: Any, command: Any, record: Callable[..., None],
                refuse: Callable[[str], None], recording: Any, fed: int) -> bool:
    """Apply one set-up command to `runner`; record(kind, **data) the timeline entry;
    refuse(text) says why a command is refused (then False). recording: the recording in
    progress (or None), which starts with new settings given before its first sample; fed:
    the samples fed so far."""
    if isinstance(command, SetSensorEnabled):
        runner.set_sensor_enabled(command.sensor, command.enabled)
        record("sensor", sensor=command.sensor, enabled=command.enabled)
    elif isinstance(command, SetEstimator):
        if command.name not in ekf.ESTIMATORS:
            refuse(f"unknown estimator {command.name!r}")
            return False
        runner.set_estimator(command.name)
        record("estimator", name=command.name)
    elif isinstance(command, SetSettings):
        runner.set_settings(command.settings)
        details = {"source": command.source} if command.source else {}
        if command.calibration is not None:
            details["profile"] = command.calibration.get("name")
        if recording is not None and recording.active:
            recording.set_settings(command.settings, command.calibration, fed)
        record("settings", settings=command.settings.to_dict()
               if hasattr(command.settings, "to_dict") else None, **details)
    elif isinstance(command, SetComparisonsEnabled):
        if command.estimator is not None and command.estimator not in ekf.ESTIMATORS:
            refuse(f"unknown estimator {command.estimator!r}")
            return False
        runner.set_comparisons_enabled(command.enabled, command.estimator)
        record("comparisons", enabled=command.enabled, estimator=runner.comparison_estimator)
    return True
