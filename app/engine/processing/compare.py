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
    """Our estimate at each ORI sample's time, interpolated between the estimates around it.

    One or several series of estimates at the same times (the 7 comparison filters share their
    times): quaternions (n, 4), or (k, n, 4) for k series, compared in one vectorised call. The
    ORI samples waiting for our next estimate are kept in numpy arrays: no Python work per
    sample."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._last_t: int | None = None          # our latest estimate
        self._last_q: np.ndarray | None = None   # (k, 4)
        self._pending_t = np.empty(0, np.int64)
        self._pending_q = np.empty((0, 4))

    def snapshot(self) -> tuple:
        """The state (copies), for :meth:`restore`: a replay's checkpoints."""
        return (self._last_t, None if self._last_q is None else self._last_q.copy(),
                self._pending_t.copy(), self._pending_q.copy())

    def restore(self, state) -> None:
        last_t, last_q, pending_t, pending_q = state
        self._last_t = last_t
        self._last_q = None if last_q is None else np.array(last_q, float).reshape(-1, 4)
        self._pending_t = np.array(pending_t, np.int64).reshape(-1)
        self._pending_q = np.array(pending_q, float).reshape(-1, 4)

    def add_phone(self, t_ms: np.ndarray, quat: np.ndarray) -> None:
        """ORI samples (in time order) to compare once our estimates around them exist."""
        t_ms = np.asarray(t_ms, np.int64).reshape(-1)
        if not len(t_ms):
            return
        quat = np.asarray(quat, float)[:, :4]
        if len(self._pending_t):
            t_ms = np.concatenate((self._pending_t, t_ms))
            quat = np.concatenate((self._pending_q, quat))
        self._pending_t = t_ms[-MAX_PENDING:]
        self._pending_q = quat[-MAX_PENDING:]

    def add_estimates(self, t_ms: np.ndarray, quat: np.ndarray) -> ErrorRows:
        """Our estimates (distinct increasing times; quat (n, 4) or (k, n, 4)): the errors of
        the ORI samples they resolve (error_deg (m, 3), or (k, m, 3) for k series)."""
        t_ms = np.asarray(t_ms, np.int64)
        quat = np.asarray(quat, float)
        series = quat.ndim == 3
        quat3 = quat if series else quat[None]
        if len(t_ms) == 0:
            return _no_errors(len(quat3) if series else None)
        if self._last_t is not None and len(self._last_q) == len(quat3):
            times = np.concatenate(([self._last_t], t_ms))
            quats = np.concatenate([self._last_q[:, None], quat3], axis=1)
        else:
            times, quats = t_ms, quat3
        self._last_t, self._last_q = int(t_ms[-1]), quat3[:, -1].copy()
        pending = self._pending_t
        # pending ORI times never decrease: the ready ones are a prefix
        ready = int(np.searchsorted(pending, times[-1], side="right")) if len(pending) else 0
        if ready == 0:
            return _no_errors(len(quat3) if series else None)
        ori_t, ori_q = pending[:ready], self._pending_q[:ready]
        self._pending_t, self._pending_q = pending[ready:], self._pending_q[ready:]
        after = np.searchsorted(times, ori_t, side="left")
        exact = times[after] == ori_t
        before = np.maximum(after - 1, 0)
        gap = times[after] - times[before]
        usable = exact | ((after > 0) & (gap <= MAX_GAP_MS))
        if not usable.any():
            return _no_errors(len(quat3) if series else None)
        fraction = np.where(exact, 1.0, (ori_t - times[before]) / np.maximum(gap, 1))
        chosen = np.flatnonzero(usable)
        k, m = len(quat3), len(chosen)
        own = slerp_rows(quats[:, before[chosen]].reshape(k * m, 4),
                         quats[:, after[chosen]].reshape(k * m, 4), np.tile(fraction[chosen], k))
        total, heading, inclination = error_angles_deg(own, np.tile(ori_q[chosen], (k, 1)))
        errors = np.column_stack([total, heading, inclination]).reshape(k, m, 3)
        return ErrorRows(ori_t[chosen], errors if series else errors[0])


def _no_errors(series: int | None) -> ErrorRows:
    if series is None:
        return ErrorRows.empty()
    return ErrorRows(np.empty(0, np.int64), np.empty((series, 0, 3)))


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
        self.add_errors(errors.error_deg)

    def add_errors(self, error_deg: np.ndarray) -> None:
        """(m, 3) errors [deg]."""
        if len(error_deg):
            finite = np.isfinite(error_deg).all(axis=1)
            values = error_deg[finite]
            self.squared += np.sum(values * values, axis=0)
            self.count += len(values)
            self.latest = error_deg[-1].copy()

    def rmse(self) -> np.ndarray:
        """(total, heading, inclination) RMSE [deg]; NaN before the first comparison."""
        return np.sqrt(self.squared / self.count) if self.count else np.full(3, math.nan)

    def clear(self) -> None:
        self.squared = np.zeros(3)
        self.count = 0
        self.latest = np.full(3, math.nan)
