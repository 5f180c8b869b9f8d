"""Comparing two orientation series at the same instant.

Our estimates come at our sensor times, the phone's own estimate (ORI) at its times. Taking the
latest ORI at or before each estimate draws a sawtooth of up to |w| x (ORI period) that is not
there (8 rad/s x 10 ms = 4.6° in a fast turn). Here every ORI sample is compared with our
estimate slerped to its time stamp, as soon as our first estimate after it exists (one row of
delay); across a gap in our estimates (longer than MAX_GAP_MS) nothing is interpolated.

The error is the one the benchmarks use (ekf.metrics): e = q_own ⊗ conj(q_phone), total angle,
heading (about world up) and inclination (tilt), in degrees.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ekf.metrics import error_angles_deg

MAX_GAP_MS = 250            # do not interpolate our estimate across a longer gap
MAX_PENDING = 4096          # ORI samples waiting for our next estimate (bounded)


def slerp_rows(p: np.ndarray, q: np.ndarray, fraction: np.ndarray) -> np.ndarray:
    """Row-wise spherical interpolation from p (fraction 0) to q (1) on the short arc; (N, 4)."""
    p = np.asarray(p, float)
    q = np.array(q, float, copy=True)
    dot = np.sum(p * q, axis=1)
    q[dot < 0] *= -1.0
    dot = np.abs(dot)
    fraction = np.asarray(fraction, float)[:, None]
    theta = np.arccos(np.clip(dot, -1.0, 1.0))[:, None]
    sin_theta = np.sin(theta)
    close = (sin_theta < 1e-9).ravel()
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (np.sin((1.0 - fraction) * theta) * p + np.sin(fraction * theta) * q) / sin_theta
    if close.any():   # (almost) the same rotation: linear is exact enough
        out[close] = p[close] + fraction[close] * (q[close] - p[close])
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    out[out[:, 0] < 0] *= -1.0
    return out


@dataclass
class ErrorRows:
    """Per ORI sample: t_ms (N,) its time; error_deg (N, 3) total, heading, inclination."""

    t_ms: np.ndarray
    error_deg: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ms)

    @staticmethod
    def empty() -> ErrorRows:
        return ErrorRows(np.empty(0, np.int64), np.empty((0, 3)))


class SameInstant:
    """Our estimate at each ORI sample's time, interpolated between the estimates around it."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._last_t: int | None = None          # our latest estimate
        self._last_q: np.ndarray | None = None
        self._pending_t: deque[int] = deque()
        self._pending_q: deque[np.ndarray] = deque()

    def add_phone(self, t_ms: np.ndarray, quat: np.ndarray) -> None:
        """ORI samples (in time order) to compare once our estimates around them exist."""
        for t, q in zip(np.asarray(t_ms).tolist(), np.asarray(quat, float)):
            self._pending_t.append(int(t))
            self._pending_q.append(q)
        while len(self._pending_t) > MAX_PENDING:
            self._pending_t.popleft()
            self._pending_q.popleft()

    def add_estimates(self, t_ms: np.ndarray, quat: np.ndarray) -> ErrorRows:
        """Our estimates (distinct increasing times): the errors of the ORI samples they resolve."""
        t_ms = np.asarray(t_ms, np.int64)
        if len(t_ms) == 0:
            return ErrorRows.empty()
        quat = np.asarray(quat, float)
        if self._last_t is not None:
            times = np.concatenate(([self._last_t], t_ms))
            quats = np.vstack([self._last_q[None], quat])
        else:
            times, quats = t_ms, quat
        self._last_t, self._last_q = int(t_ms[-1]), quat[-1].copy()
        ready = 0
        while ready < len(self._pending_t) and self._pending_t[ready] <= times[-1]:
            ready += 1
        if ready == 0:
            return ErrorRows.empty()
        ori_t = np.array([self._pending_t.popleft() for _ in range(ready)], np.int64)
        ori_q = np.array([self._pending_q.popleft() for _ in range(ready)])
        after = np.searchsorted(times, ori_t, side="left")
        exact = times[after] == ori_t
        before = np.maximum(after - 1, 0)
        gap = times[after] - times[before]
        usable = exact | ((after > 0) & (gap <= MAX_GAP_MS))
        if not usable.any():
            return ErrorRows.empty()
        fraction = np.where(exact, 1.0, (ori_t - times[before]) / np.maximum(gap, 1))
        own = slerp_rows(quats[before], quats[after], fraction)
        chosen = np.flatnonzero(usable)
        total, heading, inclination = error_angles_deg(own[chosen], ori_q[chosen])
        return ErrorRows(ori_t[chosen], np.column_stack([total, heading, inclination]))


@dataclass
class ErrorSums:
    """Running RMSE of the three error angles."""

    squared: np.ndarray = None     # (3,)
    count: int = 0
    latest: np.ndarray = None      # (3,) the latest errors [deg]

    def __post_init__(self) -> None:
        self.squared = np.zeros(3) if self.squared is None else self.squared
        self.latest = np.full(3, math.nan) if self.latest is None else self.latest

    def add(self, errors: ErrorRows) -> None:
        if len(errors):
            finite = np.isfinite(errors.error_deg).all(axis=1)
            values = errors.error_deg[finite]
            self.squared += np.sum(values * values, axis=0)
            self.count += len(values)
            self.latest = errors.error_deg[-1].copy()

    def rmse(self) -> np.ndarray:
        """(total, heading, inclination) RMSE [deg]; NaN before the first comparison."""
        return np.sqrt(self.squared / self.count) if self.count else np.full(3, math.nan)

    def clear(self) -> None:
        self.squared = np.zeros(3)
        self.count = 0
        self.latest = np.full(3, math.nan)
