"""The comparison estimators start where the EKF starts: from the first accelerometer reading
and the magnetometer's heading, even when the magnetometer's first sample comes later."""

from __future__ import annotations

import numpy as np
import pytest

import ekf
from ekf import quaternion as quat


def _turned_phone_rows(yaw_deg: float, mag_delay_ms: int = 5, count: int = 50):
    """A phone at rest, lying flat and turned `yaw_deg` from north; MAG a little after ACC."""
    q = quat.from_axis_angle([0, 0, 1], np.radians(yaw_deg))
    up_sensor = quat.to_matrix(q).T @ np.array([0.0, 0.0, 9.81])
    field_sensor = quat.to_matrix(q).T @ np.array([0.0, 18.0, -45.0])
    t, gyr, acc, mag = [], [], [], []
    for k in range(count):
        base = 1.0 + 0.01 * k
        t += [base, base + mag_delay_ms / 1000.0]
        gyr += [[0.0, 0.0, 0.0], [np.nan] * 3]
        acc += [list(up_sensor), [np.nan] * 3]
        mag += [[np.nan] * 3, list(field_sensor)]
    return np.array(t), np.array(gyr), np.array(acc), np.array(mag), q


@pytest.mark.parametrize("name", ["ekf", "complementary", "gyro", "accmag"])
@pytest.mark.parametrize("yaw", [75.0, -120.0])
def test_every_estimator_starts_at_the_magnetometer_heading(name, yaw):
    t, gyr, acc, mag, truth = _turned_phone_rows(yaw)
    result = ekf.filter_batch(t, gyr, acc, mag, estimator=name)
    total, heading, inclination = ekf.error_angles_deg(result.quat[3:], np.tile(truth, (len(t) - 3, 1)))
    assert heading.max() < 1.0, (name, heading.max())
    assert inclination.max() < 1.0


def test_a_field_along_gravity_starts_tilt_only_and_stays_finite():
    t = np.arange(20) * 0.01
    acc = np.tile([0.0, 0.0, 9.81], (20, 1))
    mag = np.tile([0.0, 0.0, -50.0], (20, 1))
    for name in ekf.ESTIMATORS:
        result = ekf.filter_batch(t, np.zeros((20, 3)), acc, mag, estimator=name)
        assert np.isfinite(result.quat).all(), name
