"""The covariance-to-rings helper: quaternion covariance -> attitude covariance -> tip ellipses."""

from __future__ import annotations

import numpy as np

from app.ui.scene import (attitude_covariance, axis_tip_ellipses, ellipse_points,
                          quat_to_matrix, s_bar)


def _multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    p0, pv = p[0], p[1:]
    q0, qv = q[0], q[1:]
    return np.concatenate([[p0 * q0 - pv @ qv], p0 * qv + q0 * pv + np.cross(pv, qv)])


def test_quat_to_matrix_turns_x_into_y_for_90_degrees_about_up():
    q = np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    np.testing.assert_allclose(quat_to_matrix(q) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(q) @ [0, 0, 1], [0, 0, 1], atol=1e-12)


def test_s_bar_gives_the_quaternion_derivative_of_a_body_rate():
    q = np.array([0.8, 0.2, -0.3, 0.469041575982343])
    omega = np.array([0.3, -0.2, 0.5])
    expected = 0.5 * _multiply(q, np.concatenate([[0.0], omega]))
    np.testing.assert_allclose(0.5 * s_bar(q) @ omega, expected, atol=1e-12)


def test_identity_attitude_covariance_is_four_times_the_vector_part():
    cov = np.diag([1e-6, 1e-4, 4e-4, 9e-4])
    theta = attitude_covariance(np.array([1.0, 0, 0, 0]), cov)
    np.testing.assert_allclose(theta, 4 * np.diag([1e-4, 4e-4, 9e-4]), atol=1e-12)


def test_attitude_covariance_recovers_sampled_body_errors_at_a_tilted_attitude():
    rng = np.random.default_rng(3)
    q = np.array([0.7, 0.3, -0.5, 0.4])
    q /= np.linalg.norm(q)
    sigma = np.array([[4e-4, 1e-4, 0], [1e-4, 1e-4, 0], [0, 0, 2.5e-3]])
    dtheta = rng.multivariate_normal(np.zeros(3), sigma, size=20000)
    angle = np.linalg.norm(dtheta, axis=1)
    # q ⊗ exp(dtheta / 2), vectorised: the error is in the body frame.
    delta = np.column_stack([np.cos(angle / 2), (np.sinc(angle / 2 / np.pi) / 2)[:, None] * dtheta])
    samples = np.column_stack([
        q[0] * delta[:, 0] - delta[:, 1:] @ q[1:],
        q[0] * delta[:, 1:] + delta[:, :1] * q[1:] + np.cross(q[1:], delta[:, 1:]),
    ])
    quat_cov = np.cov(samples.T)
    theta = attitude_covariance(q, quat_cov)
    np.testing.assert_allclose(theta, sigma, atol=1.5e-4, rtol=0.05)


def test_tip_ellipses_follow_the_std_about_the_other_two_axes():
    sx, sy, sz = np.radians([1.0, 3.0, 10.0])
    ellipses = axis_tip_ellipses(np.diag([sx, sy, sz]) ** 2, axis_length=1.0, n_sigma=2.0)
    # The x axis tip moves when the phone turns about y or z.
    semi_axes, directions = ellipses[0]
    np.testing.assert_allclose(semi_axes, np.tan([2 * sz, 2 * sy]), rtol=1e-9)
    assert abs(directions[0] @ [0, 1, 0]) > 0.999      # turning about z moves x along y
    assert abs(directions[1] @ [0, 0, 1]) > 0.999
    # The z axis tip: about x (1°) and y (3°), never the 10° about z itself.
    semi_axes_z, _ = ellipses[2]
    np.testing.assert_allclose(semi_axes_z, np.tan([2 * sy, 2 * sx]), rtol=1e-9)


def test_tip_ellipses_are_capped_for_a_diverged_covariance():
    ellipses = axis_tip_ellipses(np.eye(3) * 100.0, axis_length=1.0)
    for semi_axes, _ in ellipses:
        assert np.all(np.isfinite(semi_axes)) and np.all(semi_axes <= np.tan(np.radians(35)) + 1e-9)


def test_ellipse_points_lie_in_the_plane_perpendicular_to_the_axis():
    semi_axes, directions = axis_tip_ellipses(np.diag([1e-3, 2e-3, 3e-3]))[1]
    points = ellipse_points(np.array([0, 1.0, 0]), semi_axes, directions, segments=16)
    assert points.shape == (17, 3)
    np.testing.assert_allclose(points[:, 1], 1.0, atol=1e-12)
    np.testing.assert_allclose(points[0], points[-1], atol=1e-12)
