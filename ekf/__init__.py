"""Orientation estimation numerics: quaternion algebra, the course's EKF and its comparison
estimators behind one Estimator protocol, settings, state and outputs declared once,
calibration statistics, the simulator, a batch runner and an offline smoother.

Numerics only: this package never imports Qt, sockets or the app, and reads no files beyond
what a caller hands it.
"""

from ekf import quaternion
from ekf.diagnostics import Diagnostics, Flags, output_rows
from ekf.estimator import SENSORS, BatchResult, Estimator, EstimatorBase
from ekf.estimators import (ESTIMATORS, AccMagEstimator, ComplementaryFilter, GyroIntegrator,
                            filter_batch, make_estimator)
from ekf.metrics import error_angles_deg, summarize
from ekf.reference import OrientationEKF
from ekf.settings import PRESETS, EKFSettings, SettingsError, settings_rows
from ekf.smoother import smooth_batch
from ekf.state import EKFState

__all__ = [
    "quaternion", "BatchResult", "filter_batch", "SENSORS", "Estimator", "EstimatorBase",
    "ESTIMATORS", "AccMagEstimator", "ComplementaryFilter", "GyroIntegrator", "make_estimator",
    "error_angles_deg", "summarize", "Flags", "Diagnostics", "output_rows", "OrientationEKF",
    "PRESETS", "EKFSettings", "SettingsError", "settings_rows", "EKFState", "smooth_batch",
]
