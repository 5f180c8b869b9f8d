"""The compiled EKF's Python face: :class:`FastEKF` keeps the packed state and settings arrays
(``ekf.fast.layout``) and calls the one compiled dispatch ``kernels.step`` per row, or the
compiled batch loop over it (:func:`batch_loop`; :func:`batch_loop_recording` for the smoother).
``reset``, ``set_enabled``, ``set_settings`` and ``align_heading`` are not per-sample: they run
in Python on the packed array, line by line as in the reference.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from numpy.typing import ArrayLike

import ekf.quaternion as quat
from ekf.estimator import SENSORS, BatchResult, EstimatorBase, batch_rows, ekf_name
from ekf.fast.algebra import field_dip_deg
from ekf.fast.jit import CACHE_KEY, check_cache, jit
from ekf.fast.kernels import ACC, GYR, MAG, step
from ekf.fast.layout import C, S, pack_settings, pack_state, unpack_record, unpack_state
from ekf.diagnostics import Diagnostics, Flags
from ekf.settings import EKFSettings
from ekf.state import EKFState, check_state


def _as3(v: ArrayLike) -> tuple[float, float, float]:
    if isinstance(v, np.ndarray) and v.shape == (3,):
        return float(v[0]), float(v[1]), float(v[2])
    a = np.asarray(v, dtype=float).reshape(3)
    return float(a[0]), float(a[1]), float(a[2])


class FastEKF(EstimatorBase):
    """:class:`ekf.reference.OrientationEKF` compiled: same interface, same estimates.

    Parameters
    ----------
    settings:
        An :class:`EKFSettings`, or a preset name ("default", "course"). Default: "default".
        With ``PRESETS["course"]`` the estimator's :attr:`name` is "course", else "ekf".
    sensors:
        Which sensors are enabled at the start (any non-empty subset of gyr, acc, mag).

    Feed samples in time order (at equal times: gyroscope, accelerometer, magnetometer) with
    times in seconds. Read :attr:`quat` (w-first, sensor -> ENU, w >= 0), :attr:`cov`,
    :attr:`gyro_bias`, :attr:`flags` and :attr:`diagnostics`. :meth:`run_batch` filters whole
    arrays in one compiled loop. Snapshots are the reference's (either restores into the other).
    """

    name = "ekf"
    state_class = EKFState
    compatible = ("ekf", "course")

    def __init__(self, settings: EKFSettings | str | None = None,
                 sensors: tuple[str, ...] | list[str] = SENSORS) -> None:
        super().__init__(settings, sensors)
        self.name = ekf_name(self.settings)

    # ---------------------------------------------------------------------------------------
    # settings and state: the packed arrays
    @property
    def settings(self) -> EKFSettings:
        return self._settings

    @settings.setter
    def settings(self, settings: EKFSettings) -> None:
        self._settings = settings
        self._cfg = pack_settings(settings)

    def _get_state(self) -> dict[str, Any]:
        return unpack_state(self._packed)

    def _set_state(self, state: Mapping[str, Any]) -> None:
        check_state(EKFState, state)
        self._packed = pack_state(state)

    @property
    def packed_state(self) -> np.ndarray:
        """The packed state (ekf.fast.layout) the compiled kernels advance: the array itself."""
        return self._packed

    @property
    def packed_settings(self) -> np.ndarray:
        """The packed settings (ekf.fast.layout) the compiled kernels read: the array itself."""
        return self._cfg

    # ---------------------------------------------------------------------------------------
    # public state
    @property
    def quat(self) -> np.ndarray:
        """(4,) w-first, sensor -> ENU, w >= 0 (identity until initialised)."""
        return self._packed[S.x:S.x + 4].copy()

    @property
    def cov(self) -> np.ndarray:
        """Covariance of the full state (4x4, or 7x7 with the bias)."""
        n = int(self._packed[S.n])
        return self._packed[S.P:S.P + 49].reshape(7, 7)[:n, :n].copy()

    @property
    def gyro_bias(self) -> np.ndarray:
        """(3,) [rad/s]: the estimate (model 4c) or the fixed setting."""
        if int(self._packed[S.n]) == 7:
            return self._packed[S.x + 4:S.x + 7].copy()
        return np.asarray(self.settings.gyr_bias, float)

    @property
    def flags(self) -> Flags:
        return unpack_record(self._packed, "flags")

    @property
    def diagnostics(self) -> Diagnostics:
        return unpack_record(self._packed, "diagnostics")

    @property
    def enabled(self) -> dict[str, bool]:
        s = self._packed
        return {"gyr": bool(s[S.gyr_enabled]), "acc": bool(s[S.acc_enabled]),
                "mag": bool(s[S.mag_enabled])}

    @property
    def initialised(self) -> bool:
        return bool(self._packed[S.initialised])

    @property
    def time(self) -> float | None:
        t = float(self._packed[S.t])
        return None if math.isnan(t) else t

    # ---------------------------------------------------------------------------------------
    # control (reference: OrientationEKF.set_enabled, set_settings, align_heading)
    def set_enabled(self, gyr: bool | None = None, acc: bool | None = None,
                    mag: bool | None = None) -> None:
        """Switch sensors in or out of the filter; takes effect at the next sample."""
        s = self._packed
        for offset, value in ((S.gyr_enabled, gyr), (S.acc_enabled, acc), (S.mag_enabled, mag)):
            if value is not None:
                s[offset] = float(bool(value))
        if not s[S.gyr_enabled]:
            s[S.omega_valid] = 0.0
            s[S.acc_carried_valid] = 0.0
        s[S.at_rest] = float(bool(s[S.at_rest]) and bool(s[S.gyr_enabled] or s[S.acc_enabled]))

    def set_settings(self, settings: EKFSettings) -> None:
        """Use new settings from the next sample on, keeping the orientation."""
        s = self._packed
        self.settings = settings
        n = 7 if settings.estimate_gyro_bias else 4
        if n != int(s[S.n]):
            P = s[S.P:S.P + 49].reshape(7, 7)
            s[S.x + 4:S.x + 7] = 0.0
            P[:, 4:] = 0.0
            P[4:, :] = 0.0
            if n == 7:
                s[S.x + 4:S.x + 7] = settings.gyr_bias
                P[4:, 4:] = np.eye(3) * settings.initial_gyro_bias_std ** 2
            s[S.n] = n

    def align_heading(self, q_ref: ArrayLike) -> None:
        """Turn the estimate about world up so its heading matches `q_ref`'s (the phone's)."""
        s = self._packed
        q = s[S.x:S.x + 4].copy()
        delta = quat.heading_of(quat.multiply(np.asarray(q_ref, float), quat.conjugate(q)))
        s[S.x:S.x + 4] = quat.normalize(quat.multiply(quat.from_axis_angle([0, 0, 1], delta), q))
        if s[S.m0_valid]:
            # Turning our world turns the Earth field in it by the same angle.
            s[S.m0:S.m0 + 3] = quat.rotate(quat.from_axis_angle([0, 0, 1], delta),
                                           s[S.m0:S.m0 + 3].copy())
            s[S.mag_reference_dip_deg] = field_dip_deg(s[S.m0], s[S.m0 + 1], s[S.m0 + 2])

    # ---------------------------------------------------------------------------------------
    # sample entry points: all through the one compiled dispatch kernels.step
    def update_gyr(self, t: float, gyr: ArrayLike) -> None:
        """A gyroscope sample [rad/s, sensor frame] at time t [s]."""
        v0, v1, v2 = _as3(gyr)
        step(self._packed, self._cfg, float(t), GYR, v0, v1, v2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def update_acc(self, t: float, acc: ArrayLike) -> None:
        """An accelerometer sample [m/s^2, sensor frame] at time t [s]."""
        v0, v1, v2 = _as3(acc)
        step(self._packed, self._cfg, float(t), ACC, 0.0, 0.0, 0.0, v0, v1, v2, 0.0, 0.0, 0.0)

    def update_mag(self, t: float, mag: ArrayLike) -> None:
        """A magnetometer sample [uT, sensor frame] at time t [s]."""
        v0, v1, v2 = _as3(mag)
        step(self._packed, self._cfg, float(t), MAG, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, v0, v1, v2)

    def step(self, t: float, gyr: ArrayLike | None = None, acc: ArrayLike | None = None,
             mag: ArrayLike | None = None) -> None:
        """All samples that share time t, in the order gyroscope, accelerometer, magnetometer."""
        present = 0
        g0 = g1 = g2 = a0 = a1 = a2 = m0 = m1 = m2 = 0.0
        if gyr is not None:
            present = GYR
            g0, g1, g2 = _as3(gyr)
        if acc is not None:
            present |= ACC
            a0, a1, a2 = _as3(acc)
        if mag is not None:
            present |= MAG
            m0, m1, m2 = _as3(mag)
        step(self._packed, self._cfg, float(t), present, g0, g1, g2, a0, a1, a2, m0, m1, m2)

    def run_batch(self, t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
                  mag: ArrayLike | None) -> BatchResult:
        """Feed all rows (as `step` would, one compiled loop) and return per-row results.

        t_s: (N,) [s], non-decreasing; gyr [rad/s], acc [m/s^2], mag [uT]: (N, 3) each, a NaN
        row where that sensor has no sample (None: no such sensor). The filter continues from
        its current state and ends after the last row.
        """
        t, g, a, m = batch_rows(t_s, gyr, acc, mag)
        n = t.shape[0]
        out_q = np.empty((n, 4))
        out_flags = np.zeros((n, 3), dtype=np.bool_)
        out_bias = np.empty((n, 3))
        batch_loop(self._packed, self._cfg, t, g, a, m, out_q, out_flags, out_bias)
        return BatchResult(t, out_q, out_flags[:, 0].copy(), out_flags[:, 1].copy(),
                           out_flags[:, 2].copy(), gyro_bias=out_bias)


@jit
def batch_loop(s, c, t, gyr, acc, mag, out_q, out_flags, out_bias):
    """All rows through step in one loop (a row with any NaN in a sensor's columns has no such
    sample). out_flags columns: acc_rejected, mag_rejected, at_rest."""
    for k in range(t.shape[0]):
        g0 = gyr[k, 0]
        g1 = gyr[k, 1]
        g2 = gyr[k, 2]
        a0 = acc[k, 0]
        a1 = acc[k, 1]
        a2 = acc[k, 2]
        m0 = mag[k, 0]
        m1 = mag[k, 1]
        m2 = mag[k, 2]
        present = 0
        if not (math.isnan(g0) or math.isnan(g1) or math.isnan(g2)):
            present |= GYR
        if not (math.isnan(a0) or math.isnan(a1) or math.isnan(a2)):
            present |= ACC
        if not (math.isnan(m0) or math.isnan(m1) or math.isnan(m2)):
            present |= MAG
        step(s, c, t[k], present, g0, g1, g2, a0, a1, a2, m0, m1, m2)
        for i in range(4):
            out_q[k, i] = s[S.x + i]
        out_flags[k, 0] = s[S.acc_rejected] != 0.0
        out_flags[k, 1] = s[S.mag_rejected] != 0.0
        out_flags[k, 2] = s[S.at_rest] != 0.0
        if int(s[S.n]) == 7:
            for i in range(3):
                out_bias[k, i] = s[S.x + 4 + i]
        else:
            for i in range(3):
                out_bias[k, i] = c[C.gyr_bias + i]


@jit
def batch_loop_recording(s, c, t, gyr, acc, mag, out_q, out_flags, out_x, out_P, out_xp, out_Pp,
                      out_omega, out_T):
    """batch_loop for the smoother (c[C.record_prediction] = 1): per row also x and P after
    the row, x and P after the row's time update (before its measurements), the gyroscope
    sample that drove it and its T (-1: the row had no time update)."""
    for k in range(t.shape[0]):
        s[S.work_pred_T] = -1.0
        present = 0
        if not (math.isnan(gyr[k, 0]) or math.isnan(gyr[k, 1]) or math.isnan(gyr[k, 2])):
            present |= GYR
        if not (math.isnan(acc[k, 0]) or math.isnan(acc[k, 1]) or math.isnan(acc[k, 2])):
            present |= ACC
        if not (math.isnan(mag[k, 0]) or math.isnan(mag[k, 1]) or math.isnan(mag[k, 2])):
            present |= MAG
        step(s, c, t[k], present, gyr[k, 0], gyr[k, 1], gyr[k, 2], acc[k, 0], acc[k, 1],
              acc[k, 2], mag[k, 0], mag[k, 1], mag[k, 2])
        for i in range(4):
            out_q[k, i] = s[S.x + i]
        out_flags[k, 0] = s[S.acc_rejected] != 0.0
        out_flags[k, 1] = s[S.mag_rejected] != 0.0
        out_flags[k, 2] = s[S.at_rest] != 0.0
        for i in range(7):
            out_x[k, i] = s[S.x + i]
            out_xp[k, i] = s[S.work_pred_x + i]
            for j in range(7):
                out_P[k, i, j] = s[S.P + 7 * i + j]
                out_Pp[k, i, j] = s[S.work_pred_P + 7 * i + j]
        for i in range(3):
            out_omega[k, i] = s[S.work_pred_omega + i]
        out_T[k] = s[S.work_pred_T]


def warm_up() -> None:
    """Compile (or load from the on-disk cache) every compiled function with a tiny input."""
    t = np.array([0.0, 0.01, 0.02, 0.03])
    gyr = np.array([[0.01, 0.0, 0.0], [np.nan] * 3, [0.0, 0.01, 0.0], [0.0, 0.0, 0.01]])
    acc = np.array([[0.0, 0.0, 9.81], [0.1, 0.0, 9.8], [np.nan] * 3, [0.0, 0.1, 9.8]])
    mag = np.array([[0.0, 20.0, -40.0], [0.0, 20.0, -40.0], [0.0, 20.0, -40.0], [np.nan] * 3])
    for preset in ("default", "course"):
        est = FastEKF(preset)
        est.run_batch(t, gyr, acc, mag)
        est.step(0.04, gyr[0], acc[0], mag[0])
        est.update_gyr(0.05, gyr[0])
        est.step(0.06)
        est.align_heading(quat.IDENTITY)


@jit
def _compiled_cache_key():
    return CACHE_KEY


check_cache(_compiled_cache_key, globals(), CACHE_KEY)
