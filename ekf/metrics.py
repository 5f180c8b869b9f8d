"""Error metrics between an estimate and a reference orientation (the BROAD definitions).

The error quaternion is e = q_est ⊗ conj(q_ref) (an error expressed in the world frame):
* total       = 2 acos |e_w|
* heading     = 2 atan |e_z / e_w|          (the part about world up)
* inclination = 2 acos sqrt(e_w^2 + e_z^2)  (the tilt part)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

import ekf.quaternion as quat


def error_angles_deg(q_est: ArrayLike, q_ref: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(total, heading, inclination) in degrees for stacks (N, 4) of estimates and references."""
    e = quat.multiply(quat.normalize(q_est), quat.conjugate(quat.normalize(q_ref)))
    w = np.abs(e[..., 0])
    z = e[..., 3]
    total = 2.0 * np.arccos(np.clip(w, 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        heading = 2.0 * np.arctan(np.abs(z) / w)
    heading = np.where(w == 0, np.pi, heading)
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(e[..., 0] ** 2 + z ** 2), 0.0, 1.0))
    return np.rad2deg(total), np.rad2deg(heading), np.rad2deg(inclination)


@dataclass
class ErrorSummary:
    total_rmse_deg: float
    heading_rmse_deg: float
    inclination_rmse_deg: float
    samples: int


def rmse(x: np.ndarray) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def summarize(q_est: ArrayLike, q_ref: ArrayLike, mask: ArrayLike | None = None) -> ErrorSummary:
    """RMSE of the three error angles over the rows where `mask` is true and both are finite."""
    q_est = np.asarray(q_est, float)
    q_ref = np.asarray(q_ref, float)
    ok = np.isfinite(q_est).all(axis=1) & np.isfinite(q_ref).all(axis=1)
    if mask is not None:
        ok &= np.asarray(mask, bool)
    total, heading, incl = error_angles_deg(q_est[ok], q_ref[ok])
    return ErrorSummary(rmse(total), rmse(heading), rmse(incl), int(ok.sum()))


def intervals_mask(t_ms: ArrayLike, intervals_ms: list[list[float]] | None) -> np.ndarray:
    """True where t lies in any [start, end] interval (all true when intervals is None)."""
    t = np.asarray(t_ms, float)
    if not intervals_ms:
        return np.ones(t.shape, bool)
    m = np.zeros(t.shape, bool)
    for start, end in intervals_ms:
        m |= (t >= start) & (t <= end)
    return m


def interpolate_quat(t_src: ArrayLike, q_src: ArrayLike, t_dst: ArrayLike) -> np.ndarray:
    """The quaternion series (t_src (N,) non-decreasing, q_src (N, 4)) at the times t_dst (M,),
    by spherical linear interpolation between the two samples around each time (slerp along
    the shorter arc; the sign of a quaternion does not matter). NaN outside [t_src[0],
    t_src[-1]] and where a neighbour is not finite; w >= 0.

    Two orientations are compared at the same instant this way: the latest sample at or before
    a time lags by up to one sample period, which in a fast turn (8 rad/s, 10 ms) is 4°.
    """
    t_src = np.asarray(t_src, float).reshape(-1)
    q_src = np.asarray(q_src, float).reshape(-1, 4)
    t_dst = np.asarray(t_dst, float).reshape(-1)
    out = np.full((t_dst.shape[0], 4), np.nan)
    if t_src.shape[0] == 0:
        return out
    inside = (t_dst >= t_src[0]) & (t_dst <= t_src[-1])
    hi = np.clip(np.searchsorted(t_src, t_dst, side="left"), 0, t_src.shape[0] - 1)
    lo = np.maximum(hi - 1, 0)
    exact = t_src[hi] == t_dst
    lo = np.where(exact, hi, lo)
    span = t_src[hi] - t_src[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(span > 0, (t_dst - t_src[lo]) / np.where(span > 0, span, 1.0), 0.0)
    a = quat.normalize(q_src[lo])
    b = quat.normalize(q_src[hi])
    dot = np.sum(a * b, axis=1)
    b = np.where(dot[:, None] < 0, -b, b)          # the shorter arc
    dot = np.clip(np.abs(dot), 0.0, 1.0)
    theta = np.arccos(dot)
    sin_theta = np.sin(theta)
    small = sin_theta < 1e-9
    with np.errstate(invalid="ignore", divide="ignore"):
        wa = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / np.where(small, 1.0, sin_theta))
        wb = np.where(small, u, np.sin(u * theta) / np.where(small, 1.0, sin_theta))
    q = wa[:, None] * a + wb[:, None] * b
    ok = inside & np.isfinite(q).all(axis=1)
    out[ok] = quat.normalize(q[ok])
    return out
