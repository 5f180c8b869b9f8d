"""Presentation helpers: turn the filter's quaternion covariance into shapes the 3D view draws.

Pure numpy, no Qt, so it is easy to test. This is drawing geometry, not filtering: it only
re-expresses the covariance the engine already computed.

Convention (the course's): q = (q0, q1, q2, q3), w first, sensor -> ENU. A small rotation
error dtheta (rad, in the sensor/body frame) changes the quaternion by dq = 1/2 S̄(q) dtheta,
so on the unit sphere dtheta ≈ 2 S̄(q)^T dq and P_theta = 4 S̄(q)^T P_q S̄(q).
"""

from __future__ import annotations

import numpy as np


def s_bar(quat: np.ndarray) -> np.ndarray:
    """The course's S̄(q), shape (4, 3): dq/dt = 1/2 S̄(q) omega for a body-frame rate omega."""
    q0, q1, q2, q3 = (float(v) for v in quat)
    return np.array([
        [-q1, -q2, -q3],
        [q0, -q3, q2],
        [q3, q0, -q1],
        [-q2, q1, q0],
    ])


def attitude_covariance(quat: np.ndarray, quat_cov: np.ndarray) -> np.ndarray:
    """Map a 4x4 quaternion covariance to the 3x3 covariance of the body-frame rotation error.

    Args:
        quat: (4,) unit quaternion, w first.
        quat_cov: (4, 4) covariance of the quaternion state (only the top-left 4x4 block is
            used when a larger state covariance is given, e.g. with gyro bias).
    Returns:
        (3, 3) symmetric covariance of dtheta in rad^2, body frame.
    """
    quat = np.asarray(quat, dtype=float)
    quat = quat / np.linalg.norm(quat)
    cov = np.asarray(quat_cov, dtype=float)[:4, :4]
    jac = 2.0 * s_bar(quat).T          # dtheta = jac @ dq
    theta_cov = jac @ cov @ jac.T
    return 0.5 * (theta_cov + theta_cov.T)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def axis_tip_ellipses(theta_cov: np.ndarray, axis_length: float = 1.0, n_sigma: float = 1.0,
                      max_angle_rad: float = np.radians(35.0)) -> list[tuple[np.ndarray, np.ndarray]]:
    """Where each body axis tip may be: one ellipse per axis, in the body frame.

    A rotation error dtheta moves the tip of body axis e_i by dtheta x (L e_i) = -L [e_i]x dtheta,
    so the tip displacement covariance is L^2 [e_i]x P_theta [e_i]x^T (rank 2, perpendicular to e_i).

    Args:
        theta_cov: (3, 3) attitude-error covariance, rad^2, body frame.
        axis_length: length L of the drawn axes (scene units).
        n_sigma: how many standard deviations the ellipse shows.
        max_angle_rad: cap on the drawn half-angle so a diverged filter stays drawable.
    Returns:
        For axes x, y, z: (semi_axes (2,), directions (2, 3)) with semi-axis lengths in scene
        units and unit directions (body frame) perpendicular to that axis.
    """
    theta_cov = np.asarray(theta_cov, dtype=float)
    result = []
    for i in range(3):
        axis = np.zeros(3)
        axis[i] = 1.0
        skew = _skew(axis)
        tip_cov = skew @ theta_cov @ skew.T
        eigenvalues, eigenvectors = np.linalg.eigh(0.5 * (tip_cov + tip_cov.T))
        # The largest two eigenvalues span the plane perpendicular to the axis.
        order = np.argsort(eigenvalues)[::-1][:2]
        std = np.sqrt(np.clip(eigenvalues[order], 0.0, None))
        angles = np.minimum(n_sigma * std, max_angle_rad)
        semi_axes = axis_length * np.tan(np.minimum(angles, np.radians(80.0)))
        result.append((semi_axes, eigenvectors[:, order].T))
    return result


def ellipse_points(center: np.ndarray, semi_axes: np.ndarray, directions: np.ndarray,
                   segments: int = 32) -> np.ndarray:
    """Closed polyline (segments + 1, 3) of an ellipse in 3D."""
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    return (np.asarray(center, dtype=float)[None, :]
            + np.cos(phi)[:, None] * semi_axes[0] * directions[0][None, :]
            + np.sin(phi)[:, None] * semi_axes[1] * directions[1][None, :])


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """Q(q), (3, 3): p_world = Q(q) p_sensor, for a w-first quaternion (normalised here)."""
    q = np.asarray(quat, dtype=float)
    q0, q1, q2, q3 = q / np.linalg.norm(q)
    return np.array([
        [q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
        [2 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2 * (q2 * q3 - q0 * q1)],
        [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3],
    ])
