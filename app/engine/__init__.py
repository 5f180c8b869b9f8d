"""The engine, Qt-free: ordered samples -> estimates (one runner for live and offline), the
background thread, commands, snapshots and the one configuration module shared by the command
line and the window.

Submodules import each other directly (never this package), so this file only gathers names.
"""

from app.engine.commands import (AlignHeading, ReplayControl, ResetFilter, SetComparisonsEnabled,
                                 SetEstimator, SetSensorEnabled, SetSettings)
from app.engine.config import ConfigError, SourceOptions, load_settings, make_source
from app.engine.offline import evaluate_log, filter_log, run_offline
from app.engine.runner import EstimatorRunner, Rows
from app.engine.snapshot import Snapshot
from app.engine.worker import Engine

__all__ = ["Engine", "EstimatorRunner", "Rows", "Snapshot", "ConfigError", "SourceOptions",
           "load_settings", "make_source", "run_offline", "filter_log", "evaluate_log",
           "AlignHeading", "ReplayControl", "ResetFilter", "SetComparisonsEnabled", "SetEstimator",
           "SetSensorEnabled", "SetSettings"]
