"""Orientation estimation numerics: quaternion algebra, the course's EKF and its comparison
estimators, calibration statistics, the simulator and a batch runner.

Numerics only: this package never imports Qt, sockets or the app, and reads no files beyond
what a caller hands it.
"""

from ekf import quaternion
from ekf.batch import BatchResult, filter_batch
from ekf.estimators import (ESTIMATORS, AccMagEstimator, ComplementaryFilter, GyroIntegrator,
                            make_estimator)
from ekf.metrics import error_angles_deg, summarize
from ekf.reference import SENSORS, OrientationEKF, Status
from ekf.settings import PRESETS, EKFSettings

__all__ = [
    "quaternion", "BatchResult", "filter_batch", "ESTIMATORS", "AccMagEstimator",
    "ComplementaryFilter", "GyroIntegrator", "make_estimator", "error_angles_deg", "summarize",
    "SENSORS", "OrientationEKF", "Status", "PRESETS", "EKFSettings",
]
