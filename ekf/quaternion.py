"""Quaternion algebra in the course's conventions (SSY345/TSRT14 project description, section 2.1).

Conventions
-----------
* A quaternion is ``q = (q0, q1, q2, q3) = (w, x, y, z)``: scalar first.
* ``q`` describes the orientation of the sensor (phone) frame S in the world frame W = East-North-Up:
  ``p_W = Q(q) p_S`` with ``Q(q) = R^{W/S}`` (eq. 2a).
* ``q`` and ``-q`` are the same rotation; :func:`normalize` returns the representative with ``w >= 0``.
* The product is the Hamilton product, so ``Q(p ⊗ q) = Q(p) Q(q)``.

Every function accepts a single quaternion of shape (4,) and, where noted, stacks of shape (N, 4).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def normalize(q: ArrayLike) -> np.ndarray:
    """Unit quaternion(s) with w >= 0. Shape (4,) or (N, 4)."""
    q = np.asarray(q, dtype=float)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    q = q / n
    sign = np.where(q[..., :1] < 0.0, -1.0, 1.0)
    return q * sign


def to_matrix(q: ArrayLike) -> np.ndarray:
    """Q(q) of eq. (2a): the rotation matrix R^{W/S}, so that p_W = Q(q) p_S. Shape (3, 3) or (N, 3, 3)."""
    q = np.asarray(q, dtype=float)
    q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    m = np.empty(q.shape[:-1] + (3, 3))
    m[..., 0, 0] = 2 * (q0 * q0 + q1 * q1) - 1
    m[..., 0, 1] = 2 * (q1 * q2 - q0 * q3)
    m[..., 0, 2] = 2 * (q1 * q3 + q0 * q2)
    m[..., 1, 0] = 2 * (q1 * q2 + q0 * q3)
    m[..., 1, 1] = 2 * (q0 * q0 + q2 * q2) - 1
    m[..., 1, 2] = 2 * (q2 * q3 - q0 * q1)
    m[..., 2, 0] = 2 * (q1 * q3 - q0 * q2)
    m[..., 2, 1] = 2 * (q2 * q3 + q0 * q1)
    m[..., 2, 2] = 2 * (q0 * q0 + q3 * q3) - 1
    return m


def dQ_dq(q: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The derivatives dQ(q)/dq_i, i = 0..3, of eqs. (2f)-(2i) (the course's ``dQqdq``).

    They differentiate the unit-norm form of (2a) as written in the course, so for unit q they
    agree with finite differences taken along the unit sphere's tangent and along q itself
    (the form is homogeneous of degree 2 only on the sphere; the EKF uses them there).
    """
    q0, q1, q2, q3 = np.asarray(q, dtype=float)
    d0 = 2 * np.array([[2 * q0, -q3, q2], [q3, 2 * q0, -q1], [-q2, q1, 2 * q0]])
    d1 = 2 * np.array([[2 * q1, q2, q3], [q2, 0.0, -q0], [q3, q0, 0.0]])
    d2 = 2 * np.array([[0.0, q1, q0], [q1, 2 * q2, q3], [-q0, q3, 0.0]])
    d3 = 2 * np.array([[0.0, -q0, q1], [q0, 0.0, q2], [q1, q2, 2 * q3]])
    return d0, d1, d2, d3


def S_omega(omega: ArrayLike) -> np.ndarray:
    """S(ω) of eq. (2d): q̇ = ½ S(ω) q with ω in the sensor frame, rad/s. (4, 4).

    The course's MATLAB listing has a typo in row 3 (it ends in ω_z); eq. (2d) is right: row 3 ends in ω_x.
    """
    wx, wy, wz = np.asarray(omega, dtype=float)
    return np.array([
        [0.0, -wx, -wy, -wz],
        [wx, 0.0, wz, -wy],
        [wy, -wz, 0.0, wx],
        [wz, wy, -wx, 0.0],
    ])


def S_bar(q: ArrayLike) -> np.ndarray:
    """S̄(q) of eq. (2e): S(ω) q = S̄(q) ω. (4, 3)."""
    q0, q1, q2, q3 = np.asarray(q, dtype=float)
    return np.array([
        [-q1, -q2, -q3],
        [q0, -q3, q2],
        [q3, q0, -q1],
        [-q2, q1, q0],
    ])


def multiply(p: ArrayLike, q: ArrayLike) -> np.ndarray:
    """Hamilton product p ⊗ q, with Q(p ⊗ q) = Q(p) Q(q). Broadcasts over leading axes."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    ], axis=-1)


def conjugate(q: ArrayLike) -> np.ndarray:
    """q* = (w, -x, -y, -z): the inverse rotation for a unit quaternion."""
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def rotate(q: ArrayLike, v: ArrayLike) -> np.ndarray:
    """Rotate sensor-frame vector(s) into the world frame: Q(q) v. q (4,) or (N,4); v (3,) or (N,3)."""
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    vq = np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], axis=-1)
    return multiply(multiply(q, vq), conjugate(q))[..., 1:]


def from_matrix(R: ArrayLike) -> np.ndarray:
    """Q^{-1}(R) of eq. (2b), made numerically stable (Shepperd's method).

    Eq. (2b) divides by 4 q0, which fails near 180° rotations; this picks the largest of
    q0..q3 to divide by instead. Returns a unit quaternion with w >= 0. R: (3, 3).
    """
    R = np.asarray(R, dtype=float)
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    candidates = np.array([trace, R[0, 0], R[1, 1], R[2, 2]])
    k = int(np.argmax(candidates))
    if k == 0:
        s = 2.0 * np.sqrt(max(1.0 + trace, 0.0))
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif k == 1:
        s = 2.0 * np.sqrt(max(1.0 + R[0, 0] - R[1, 1] - R[2, 2], 0.0))
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif k == 2:
        s = 2.0 * np.sqrt(max(1.0 - R[0, 0] + R[1, 1] - R[2, 2], 0.0))
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(max(1.0 - R[0, 0] - R[1, 1] + R[2, 2], 0.0))
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    return normalize(q)


def from_axis_angle(axis: ArrayLike, angle: float) -> np.ndarray:
    """Rotation by `angle` (rad) about `axis` (any non-zero length): (cos α/2, sin α/2 v̂)."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


def from_rotation_vector(rv: ArrayLike) -> np.ndarray:
    """exp of a rotation vector (rad): rotation by |rv| about rv/|rv|. Exact, well-behaved near zero."""
    rv = np.asarray(rv, dtype=float)
    angle = float(np.linalg.norm(rv))
    if angle < 1e-12:
        return normalize(np.concatenate([[1.0], 0.5 * rv]))
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * rv / angle])


def angle_between(p: ArrayLike, q: ArrayLike) -> np.ndarray:
    """Angle (rad) of the rotation that takes q to p, eq. (2c) made sign-invariant: 2 acos |p·q|.

    Works on (4,) or stacks (N, 4); inputs are normalised first.
    """
    p = normalize(p)
    q = normalize(q)
    d = np.abs(np.sum(p * q, axis=-1))
    return 2.0 * np.arccos(np.clip(d, 0.0, 1.0))


# ---- Euler angles ---------------------------------------------------------------------------
# One documented convention: intrinsic z-y'-x'' (yaw, pitch, roll), the aerospace sequence, for
# the sensor-to-ENU rotation: Q(q) = Rz(yaw) @ Ry(pitch) @ Rx(roll).
#   yaw   : rotation about world up (z), counter-clockwise seen from above, 0 when the phone's x
#           axis points east. Range (-180°, 180°].
#   pitch : rotation about the once-rotated y axis, range [-90°, 90°].
#   roll  : rotation about the phone's own x axis, range (-180°, 180°].
# (The seed's q2euler has operator-precedence bugs; this is derived from Q(q) directly.)

def to_euler(q: ArrayLike) -> np.ndarray:
    """(yaw, pitch, roll) in rad, convention above. q (4,) or (N, 4) -> (3,) or (N, 3).

    At pitch = ±90° (gimbal lock) roll is set to 0 and yaw carries the whole rotation about z.
    """
    q = normalize(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    sin_pitch = np.clip(2.0 * (w * y - z * x), -1.0, 1.0)
    pitch = np.arcsin(sin_pitch)
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    locked = np.abs(sin_pitch) > 1.0 - 1e-12
    if np.any(locked):
        # Only yaw -/+ roll is defined: put all of it in yaw.
        yaw_locked = np.where(sin_pitch > 0, -2.0, 2.0) * np.arctan2(x, w)
        yaw = np.where(locked, np.arctan2(np.sin(yaw_locked), np.cos(yaw_locked)), yaw)
        roll = np.where(locked, 0.0, roll)
    return np.stack([yaw, pitch, roll], axis=-1)


def from_euler(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Inverse of :func:`to_euler` (rad): Rz(yaw) Ry(pitch) Rx(roll)."""
    qz = from_axis_angle([0, 0, 1], yaw)
    qy = from_axis_angle([0, 1, 0], pitch)
    qx = from_axis_angle([1, 0, 0], roll)
    return normalize(multiply(multiply(qz, qy), qx))


def unwrap_deg(angles_deg: ArrayLike, previous_deg: ArrayLike | None = None) -> np.ndarray:
    """Unwrap Euler angles (N, 3) in degrees along axis 0, continuing from `previous_deg` (3,) if given,
    so a plot can be extended chunk by chunk without jumps."""
    a = np.asarray(angles_deg, dtype=float)
    if a.size == 0:
        return a.reshape(0, 3) if a.ndim == 2 else a
    if previous_deg is not None:
        prev = np.asarray(previous_deg, dtype=float)[None, :]
        stacked = np.vstack([prev, a])
        valid_prev = np.isfinite(prev).all()
        out = np.rad2deg(np.unwrap(np.deg2rad(stacked), axis=0))
        if valid_prev:
            # np.unwrap keeps the first row; shift the continuation so it starts at prev.
            return out[1:] + (prev - out[:1])
        return out[1:]
    return np.rad2deg(np.unwrap(np.deg2rad(a), axis=0))


def heading_of(q: ArrayLike) -> float:
    """Heading (rad) of the rotation about world up that best explains q: yaw of the swing-twist
    decomposition about z, 2 atan2(z, w). Used to align one estimate's world to another's."""
    w, _, _, z = normalize(q)
    return 2.0 * np.arctan2(z, w)
