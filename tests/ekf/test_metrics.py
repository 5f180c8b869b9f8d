"""ekf.metrics: the error angles and the slerp interpolation that compares two orientation
series at the same instant."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

import ekf.quaternion as quat
from ekf.metrics import error_angles_deg, interpolate_quat


def _turn(angle_rad: np.ndarray) -> np.ndarray:
    return np.array([quat.from_axis_angle([0.3, -0.5, 0.8], a) for a in angle_rad])


def test_interpolation_follows_a_constant_rate_turn_exactly():
    t = np.arange(0.0, 1.0, 0.01)
    q = _turn(8.0 * t)                       # 8 rad/s, samples every 10 ms
    t_mid = t[:-1] + 0.004
    got = interpolate_quat(t, q, t_mid)
    total, _, _ = error_angles_deg(got, _turn(8.0 * t_mid))
    assert total.max() < 1e-4   # degrees (arccos near 1 limits the precision)
    # the latest sample at or before the time is up to 8 rad/s x 10 ms = 4.6 deg behind
    held, _, _ = error_angles_deg(q[:-1], _turn(8.0 * t_mid))
    assert held.max() > 1.5


def test_interpolation_outside_the_series_or_next_to_nan_is_nan():
    t = np.array([0.0, 1.0, 2.0])
    q = np.array([[1.0, 0, 0, 0], [np.nan] * 4, [1.0, 0, 0, 0]])
    got = interpolate_quat(t, q, [-0.5, 0.0, 0.5, 1.5, 2.0, 2.5])
    assert np.isnan(got[[0, 2, 3, 5]]).all()
    np.testing.assert_allclose(got[[1, 4]], [[1, 0, 0, 0]] * 2)


def test_interpolation_takes_the_short_arc_whatever_the_sign():
    a = quat.from_axis_angle([0, 0, 1], 0.2)
    b = -quat.from_axis_angle([0, 0, 1], 0.4)     # the same rotation as +b
    got = interpolate_quat([0.0, 1.0], np.array([a, b]), [0.5])[0]
    np.testing.assert_allclose(got, quat.from_axis_angle([0, 0, 1], 0.3), atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1),
                          st.floats(-1, 1)), min_size=2, max_size=8),
       st.floats(0.0, 1.0))
def test_interpolated_quaternions_are_unit_and_between_their_neighbours(raw, u):
    q = np.array(raw, float)
    q[np.linalg.norm(q, axis=1) < 1e-3] = [1.0, 0, 0, 0]
    t = np.arange(len(q), dtype=float)
    k = min(int(u * (len(q) - 1)), len(q) - 2)
    got = interpolate_quat(t, q, [k + u])[0]
    assert abs(np.linalg.norm(got) - 1.0) < 1e-9 and got[0] >= 0
    span = quat.angle_between(q[k], q[k + 1])
    assert quat.angle_between(got, q[k]) <= span + 1e-6
    assert quat.angle_between(got, q[k + 1]) <= span + 1e-6
