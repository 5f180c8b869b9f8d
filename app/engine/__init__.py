"""The engine, Qt-free: ordered samples -> estimates (one runner for live and offline), the
background thread, commands, snapshots and the one configuration module shared by the command
line and the window.

Its rooms: :mod:`~app.engine.processing` (bytes -> estimates, shared by every path),
:mod:`~app.engine.live` (the engine thread, its parts, its output), :mod:`~app.engine.sessions`
(recording, replaying and indexing sessions), :mod:`~app.engine.offline` (whole logs: filter,
evaluate, re-filter, export), :mod:`~app.engine.tuning` (calibration, profiles, auto-tune) and
:mod:`~app.engine.userfilter` (your filter in its own process); beside them the engine's inputs
and outputs: :mod:`~app.engine.config` (what a user names by text), :mod:`~app.engine.commands`
(what a user asks while it runs), :mod:`~app.engine.snapshot` (what it hands the window),
:mod:`~app.engine.errors` (what goes wrong) and :mod:`~app.engine.warmup` (compiling the kernels).

Submodules import each other directly (never this package), so this file only gathers names,
and it imports a submodule only when one of its names is asked for: importing one small module
of the engine (your filter's process imports only ``app.engine.userfilter``'s lean modules)
does not load the whole engine.
"""

from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "AlignHeading": "commands", "ReplayControl": "commands", "ResetFilter": "commands",
    "SetComparisonsEnabled": "commands", "SetEstimator": "commands",
    "SetSensorEnabled": "commands", "SetSettings": "commands",
    "ConfigError": "config", "SourceOptions": "config", "load_settings": "config",
    "make_source": "config",
    "evaluate_log": "offline.filtering", "filter_log": "offline.filtering",
    "run_offline": "offline.filtering",
    "EstimatorRunner": "processing.runner", "Rows": "processing.runner",
    "Snapshot": "snapshot",
    "Engine": "live.worker",
}

__all__ = ["Engine", "EstimatorRunner", "Rows", "Snapshot", "ConfigError", "SourceOptions",
           "load_settings", "make_source", "run_offline", "filter_log", "evaluate_log",
           "AlignHeading", "ReplayControl", "ResetFilter", "SetComparisonsEnabled", "SetEstimator",
           "SetSensorEnabled", "SetSettings"]


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
