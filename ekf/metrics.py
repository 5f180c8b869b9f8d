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
