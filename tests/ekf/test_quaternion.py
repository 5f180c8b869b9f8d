"""Every quaternion formula against an independent computation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ekf import quaternion as Q

unit_quats = st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
    lambda v: np.linalg.norm(v) > 0.1).map(lambda v: Q.normalize(np.array(v)))


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_axis_angle_matches_elementary_rotations():
    for axis, R in (([1, 0, 0], rot_x), ([0, 1, 0], rot_y), ([0, 0, 1], rot_z)):
        for a in (0.3, -1.2, 2.9):
            np.testing.assert_allclose(Q.to_matrix(Q.from_axis_angle(axis, a)), R(a), atol=1e-12)


@given(unit_quats)
def test_Q_is_orthonormal_and_matches_rotate(q):
    R = Q.to_matrix(q)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    v = np.array([0.3, -1.1, 2.0])
    np.testing.assert_allclose(R @ v, Q.rotate(q, v), atol=1e-12)
    np.testing.assert_allclose(Q.to_matrix(-q), R, atol=1e-12)


@given(unit_quats, unit_quats)
def test_product_composes_rotations(p, q):
    np.testing.assert_allclose(Q.to_matrix(Q.multiply(p, q)), Q.to_matrix(p) @ Q.to_matrix(q), atol=1e-12)
    np.testing.assert_allclose(Q.multiply(q, Q.conjugate(q)), [1, 0, 0, 0], atol=1e-12)


@given(unit_quats)
def test_from_matrix_round_trip_including_near_180(q):
    back = Q.from_matrix(Q.to_matrix(q))
    assert back[0] >= 0
    assert Q.angle_between(back, q) < 1e-6


@pytest.mark.parametrize("axis", [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]])
def test_from_matrix_stable_at_exactly_180_degrees(axis):
    q = Q.from_axis_angle(axis, np.pi)
    back = Q.from_matrix(Q.to_matrix(q))
    assert np.all(np.isfinite(back))
    np.testing.assert_allclose(Q.to_matrix(back), Q.to_matrix(q), atol=1e-12)


@given(unit_quats, st.lists(st.floats(-5, 5), min_size=3, max_size=3))
def test_S_omega_and_S_bar_identity_eq_2d_2e(q, w):
    w = np.array(w)
    np.testing.assert_allclose(Q.S_omega(w) @ q, Q.S_bar(q) @ w, atol=1e-12)


def test_S_omega_gives_the_quaternion_derivative():
    # q(t) = q0 ⊗ exp(w t): derivative at 0 by finite differences equals 1/2 S(w) q0.
    q0 = Q.normalize([0.9, 0.1, -0.3, 0.2])
    w = np.array([0.4, -1.0, 0.7])
    h = 1e-6
    dq = (Q.multiply(q0, Q.from_rotation_vector(w * h)) - Q.multiply(q0, Q.from_rotation_vector(-w * h))) / (2 * h)
    np.testing.assert_allclose(dq, 0.5 * Q.S_omega(w) @ q0, atol=1e-8)


@given(unit_quats)
@settings(max_examples=50)
def test_dQ_dq_against_finite_differences(q):
    h = 1e-6

    def Qform(v):  # the unit-norm form of eq. (2a), as the course differentiates it
        return Q.to_matrix(v)

    for i, dQi in enumerate(Q.dQ_dq(q)):
        e = np.zeros(4)
        e[i] = h
        fd = (Qform(q + e) - Qform(q - e)) / (2 * h)
        np.testing.assert_allclose(fd, dQi, atol=1e-6)


def test_angle_between_is_sign_invariant_and_correct():
    p = Q.from_axis_angle([0, 1, 0], 0.5)
    q = Q.from_axis_angle([0, 1, 0], 0.2)
    assert Q.angle_between(p, q) == pytest.approx(0.3)
    assert Q.angle_between(p, -q) == pytest.approx(0.3)
    assert Q.angle_between(p, p) == pytest.approx(0.0, abs=1e-7)


def test_normalize_forces_nonnegative_w():
    q = Q.normalize([-2.0, 0.0, 0.0, 2.0])
    assert q[0] >= 0 and np.linalg.norm(q) == pytest.approx(1)


@pytest.mark.parametrize("yaw,pitch,roll", [(0.3, 0.2, -0.5), (-2.5, -1.2, 2.8), (3.0, 0.0, 0.0),
                                            (0.0, 1.4, 0.0), (0.0, 0.0, -3.0)])
def test_euler_round_trip_and_known_rotations(yaw, pitch, roll):
    q = Q.from_euler(yaw, pitch, roll)
    np.testing.assert_allclose(Q.to_matrix(q), rot_z(yaw) @ rot_y(pitch) @ rot_x(roll), atol=1e-12)
    np.testing.assert_allclose(Q.to_euler(q), [yaw, pitch, roll], atol=1e-9)


def test_euler_meaning_on_phone_poses():
    # Phone turned 90° left about up: its x axis (right of screen) points north -> yaw +90°.
    q = Q.from_axis_angle([0, 0, 1], np.pi / 2)
    np.testing.assert_allclose(Q.rotate(q, [1, 0, 0]), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(np.rad2deg(Q.to_euler(q)), [90, 0, 0], atol=1e-9)


def test_euler_gimbal_lock_is_finite_and_consistent():
    q = Q.from_euler(0.7, np.pi / 2, 0.0)
    e = Q.to_euler(q)
    assert np.all(np.isfinite(e))
    assert Q.angle_between(Q.from_euler(*e), q) < 1e-6


def test_unwrap_continues_across_chunks():
    yaw = np.deg2rad(np.arange(0, 720, 10.0))
    wrapped = np.rad2deg(np.arctan2(np.sin(yaw), np.cos(yaw)))
    e = np.zeros((len(yaw), 3))
    e[:, 0] = wrapped
    first = Q.unwrap_deg(e[:30])
    second = Q.unwrap_deg(e[30:], previous_deg=first[-1])
    np.testing.assert_allclose(np.concatenate([first, second])[:, 0], np.arange(0, 720, 10.0), atol=1e-9)
