"""Comparison estimators behind the one Estimator protocol, the factory every caller uses, and
the batch API over arrays.

* ``gyro``: plain gyroscope integration (exact for piecewise-constant rate) from an acc+mag start.
* ``accmag``: accelerometer + magnetometer only, no dynamics: each reading gives the orientation.
* ``complementary``: gyro integration pulled towards acc+mag with a time constant (seeds/004:
  fused = c * gyro + (1 - c) * accmag, c = tau / (tau + dt)), as a quaternion slerp.

Their state is declared once, like the EKF's (:class:`SimpleState`), so snapshots, flags and
diagnostics come from :class:`ekf.estimator.EstimatorBase`.

``filter_batch``, for replays, commands and benchmarks, gives exactly what the streaming API
gives when the same samples are fed row by row in the order gyroscope, accelerometer,
magnetometer: it is the estimator's own ``run_batch`` (one compiled loop for the compiled EKF, a
loop over ``step`` for the others).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np
from numpy.typing import ArrayLike

import ekf.quaternion as quat
from ekf.estimator import SENSORS, BatchResult, Estimator, EstimatorBase, batch_rows
from ekf.diagnostics import ACC_NORM_GATE, NOT_REJECTED, Diagnostics, Flags
from ekf.reference import OrientationEKF, acc_mag_quaternion, tilt_quaternion
from ekf.settings import PRESETS, EKFSettings, resolve_settings
from ekf.state import state_field

ESTIMATORS = ("ekf", "course", "complementary", "gyro", "accmag")


def slerp(p: np.ndarray, q: np.ndarray, fraction: float) -> np.ndarray:
    """Spherical interpolation from p (fraction 0) to q (fraction 1) along the short arc."""
    d = float(p @ q)
    if d < 0:
        q, d = -q, -d
    if d > 0.9995:
        return quat.normalize(p + fraction * (q - p))
    theta = math.acos(min(d, 1.0))
    s = math.sin(theta)
    return quat.normalize((math.sin((1 - fraction) * theta) * p + math.sin(fraction * theta) * q) / s)


def _value(v: float | bool):
    return lambda settings, enabled: v


def _zeros3(settings: EKFSettings, enabled: Mapping[str, bool]) -> np.ndarray:
    return np.zeros(3)


def _diagnostics(settings: EKFSettings, enabled: Mapping[str, bool]) -> Diagnostics:
    return Diagnostics(g=settings.g, acc_gate=settings.acc_gate, mag_gate=settings.mag_gate)


@dataclass(eq=False)
class SimpleState:
    """The state of the comparison estimators."""

    t: float = state_field("time of the latest sample; NaN: none yet", _value(math.nan), unit="s")
    gyr_enabled: bool = state_field("the gyroscope is switched in",
                                    lambda settings, enabled: bool(enabled["gyr"]), kind=bool)
    acc_enabled: bool = state_field("the accelerometer is switched in",
                                    lambda settings, enabled: bool(enabled["acc"]), kind=bool)
    mag_enabled: bool = state_field("the magnetometer is switched in",
                                    lambda settings, enabled: bool(enabled["mag"]), kind=bool)
    initialised: bool = state_field("started from the first readings", _value(False), kind=bool)
    heading_from_mag: bool = state_field("the heading came from a magnetometer reading (a "
                                         "tilt-only start takes it from the next one)",
                                         _value(False), kind=bool)
    q: np.ndarray = state_field("the orientation (w first, sensor -> ENU, w >= 0)",
                                lambda settings, enabled: quat.IDENTITY.copy(), shape=(4,))
    omega: np.ndarray = state_field("latest gyroscope sample", _zeros3, unit="rad/s", shape=(3,))
    omega_valid: bool = state_field("omega holds a sample", _value(False), kind=bool)
    omega_t: float = state_field("time of omega", _value(-math.inf), unit="s")
    acc: np.ndarray = state_field("latest accepted accelerometer reading", _zeros3, unit="m/s²",
                                  shape=(3,))
    acc_valid: bool = state_field("acc holds a reading", _value(False), kind=bool)
    acc_t: float = state_field("time of acc", _value(-math.inf), unit="s")
    mag: np.ndarray = state_field("latest magnetometer reading", _zeros3, unit="µT", shape=(3,))
    mag_valid: bool = state_field("mag holds a reading", _value(False), kind=bool)
    mag_t: float = state_field("time of mag", _value(-math.inf), unit="s")
    heading_offset: float = state_field("turn about up added by align_heading", _value(0.0),
                                        unit="rad")
    last_correction_t: float = state_field("time of the complementary filter's latest "
                                           "correction; NaN: none yet", _value(math.nan), unit="s")
    flags: Flags = state_field("the lights", lambda settings, enabled: Flags(), kind=Flags)
    diagnostics: Diagnostics = state_field("the numbers behind them", _diagnostics,
                                           kind=Diagnostics)


class _SimpleEstimator(EstimatorBase):
    """Shared plumbing: time, acc/mag memory, the accelerometer gate for the light."""

    name = "simple"
    state_class = SimpleState

    def __init__(self, settings: EKFSettings | str | None = None,
                 sensors: tuple[str, ...] | list[str] = SENSORS) -> None:
        super().__init__(settings, sensors)
        self._state: SimpleState

    @property
    def quat(self) -> np.ndarray:
        return self._state.q.copy()

    @property
    def gyro_bias(self) -> np.ndarray:
        """(3,) [rad/s]: the fixed setting (subtracted before integrating)."""
        return np.asarray(self.settings.gyr_bias, float)

    def align_heading(self, q_ref: ArrayLike) -> None:
        st = self._state
        delta = quat.heading_of(quat.multiply(np.asarray(q_ref, float), quat.conjugate(st.q)))
        st.heading_offset += delta
        st.q[:] = quat.normalize(quat.multiply(quat.from_axis_angle([0, 0, 1], delta), st.q))

    def step(self, t: float, gyr: ArrayLike | None = None, acc: ArrayLike | None = None,
             mag: ArrayLike | None = None) -> None:
        """All samples that share time t, in the order gyroscope, accelerometer, magnetometer."""
        if gyr is not None:
            self.update_gyr(t, gyr)
        if acc is not None:
            self.update_acc(t, acc)
        if mag is not None:
            self.update_mag(t, mag)
        if gyr is None and acc is None and mag is None:
            self._advance(t)

    # -- helpers ------------------------------------------------------------------------------
    def _advance(self, t: float) -> None:
        st = self._state
        if math.isnan(st.t):
            st.t = t
            return
        dt = t - st.t
        if dt <= 0:
            return
        t_prev = st.t
        st.t = t
        if not st.initialised or dt > self.settings.max_dt:
            st.flags.used_gyr = False
            return
        if st.omega_valid and st.gyr_enabled and t_prev - st.omega_t <= self.settings.gyr_hold_s:
            omega = st.omega - np.asarray(self.settings.gyr_bias, float)
            st.q[:] = quat.normalize(quat.multiply(st.q, quat.from_rotation_vector(omega * dt)))
            st.flags.used_gyr = True
        else:
            st.flags.used_gyr = False

    def _acc_ok(self, y: np.ndarray) -> bool:
        s, st = self.settings, self._state
        norm = float(np.linalg.norm(y))
        st.diagnostics.acc_norm = norm
        rejected = abs(norm - s.g) > s.acc_gate
        st.flags.acc_rejected = rejected
        st.diagnostics.acc_rejected_by = ACC_NORM_GATE if rejected else NOT_REJECTED
        return not rejected

    def _absolute(self) -> np.ndarray | None:
        """Orientation from the latest accelerometer and magnetometer readings (enabled ones)."""
        st = self._state
        acc = st.acc if st.acc_enabled and st.acc_valid else None
        mag = st.mag if st.mag_enabled and st.mag_valid else None
        if (acc is not None and mag is not None and np.linalg.norm(np.cross(acc, mag))
                <= 1e-6 * np.linalg.norm(acc) * np.linalg.norm(mag)):
            mag = None       # a field along gravity (a pole, a magnet) has no heading: tilt only
        if acc is not None and mag is not None:
            q = acc_mag_quaternion(acc, mag)
        elif acc is not None:
            # Tilt only: keep the current heading.
            q = tilt_quaternion(acc)
            q = quat.normalize(quat.multiply(
                quat.from_axis_angle([0, 0, 1], quat.heading_of(st.q)), q))
            return q
        elif mag is not None:
            q = quat.from_axis_angle([0, 0, 1], math.atan2(mag[0], mag[1]))
        else:
            return None
        return quat.normalize(quat.multiply(quat.from_axis_angle([0, 0, 1], st.heading_offset), q))

    def _initialise(self, t: float) -> None:
        """Start where the EKF starts: from the first accelerometer reading and a magnetometer
        reading at most 0.1 s old (TRIAD); without one, tilt now and the heading from the next
        magnetometer reading (_take_heading)."""
        st = self._state
        recent_mag = st.mag_valid and t - st.mag_t <= 0.1
        if not recent_mag:
            st.mag_valid = False
        q = self._absolute()
        st.q[:] = quat.IDENTITY if q is None else q
        st.initialised = True
        st.heading_from_mag = st.mag_valid and st.mag_enabled

    def _take_heading(self, y: np.ndarray) -> None:
        """After a tilt-only start: keep the tilt, turn about up to the field's heading."""
        st = self._state
        up = quat.to_matrix(st.q)[2]            # world up in the sensor frame
        if np.linalg.norm(np.cross(up, y)) <= 1e-6 * np.linalg.norm(y):
            return                              # a field along up has no heading
        q = acc_mag_quaternion(up, y)
        st.q[:] = quat.normalize(quat.multiply(
            quat.from_axis_angle([0, 0, 1], st.heading_offset), q))
        st.heading_from_mag = True

    def update_gyr(self, t: float, gyr: ArrayLike) -> None:
        self._advance(t)
        st = self._state
        if st.gyr_enabled:
            st.omega[:] = np.asarray(gyr, float).reshape(3)
            st.omega_valid = True
            st.omega_t = t
            if not st.initialised and not (st.acc_enabled or st.mag_enabled):
                self._initialise(t)

    def update_acc(self, t: float, acc: ArrayLike) -> None:
        self._advance(t)
        st = self._state
        y = np.asarray(acc, float).reshape(3)
        if not st.acc_enabled:
            return
        ok = self._acc_ok(y)
        if ok or not st.acc_valid:
            st.acc[:] = y
            st.acc_valid = True
            st.acc_t = t
        if not st.initialised:
            self._initialise(t)
            return
        self._absolute_update(t, ok, "acc")

    def update_mag(self, t: float, mag: ArrayLike) -> None:
        self._advance(t)
        st = self._state
        y = np.asarray(mag, float).reshape(3)
        if not st.mag_enabled:
            return
        st.mag[:] = y
        st.mag_valid = True
        st.mag_t = t
        st.diagnostics.mag_norm = float(np.linalg.norm(y))
        if not st.initialised:
            if not st.acc_enabled:
                self._initialise(t)
            return
        if not st.heading_from_mag:
            self._take_heading(y)
            return
        self._absolute_update(t, True, "mag")

    def _absolute_update(self, t: float, ok: bool, sensor: str) -> None:
        raise NotImplementedError


class GyroIntegrator(_SimpleEstimator):
    """Gyroscope integration only, started from the first acc+mag readings."""

    name = "gyro"

    def _absolute_update(self, t: float, ok: bool, sensor: str) -> None:
        return   # absolute sensors only give the start


class AccMagEstimator(_SimpleEstimator):
    """No dynamics: every accelerometer or magnetometer reading sets the orientation."""

    name = "accmag"

    def _absolute_update(self, t: float, ok: bool, sensor: str) -> None:
        q = self._absolute()
        if q is not None and ok:
            self._state.q[:] = q


class ComplementaryFilter(_SimpleEstimator):
    """Gyro integration corrected towards acc+mag: q <- slerp(q, q_accmag, 1 - c), c = tau/(tau+dt)."""

    name = "complementary"
    time_constant_s = 1.0

    def _absolute_update(self, t: float, ok: bool, sensor: str) -> None:
        if not ok:
            return
        target = self._absolute()
        if target is None:
            return
        st = self._state
        last = st.last_correction_t
        dt = 0.01 if math.isnan(last) else max(t - last, 0.0)
        st.last_correction_t = t
        if dt == 0.0:
            return
        if not st.gyr_enabled:
            st.q[:] = target
            return
        c = self.time_constant_s / (self.time_constant_s + dt)
        st.q[:] = slerp(st.q, target, 1.0 - c)


def make_estimator(name: str = "ekf", settings: EKFSettings | str | None = None,
                   sensors: tuple[str, ...] | list[str] = SENSORS,
                   fast: bool = True) -> Estimator:
    """An estimator by name (see ESTIMATORS). "ekf" uses `settings` (default: the default preset),
    "course" the course preset. `fast` picks the compiled EKF (same estimates; numba is imported
    only then), else the readable reference."""
    if name not in ESTIMATORS:
        raise ValueError(f"unknown estimator {name!r}; choose from {', '.join(ESTIMATORS)}")
    if name in ("ekf", "course"):
        s = PRESETS["course"] if name == "course" else resolve_settings(settings)
        if fast:
            from ekf.fast import FastEKF
            return FastEKF(s, sensors)
        return OrientationEKF(s, sensors)
    cls = {"gyro": GyroIntegrator, "accmag": AccMagEstimator,
           "complementary": ComplementaryFilter}[name]
    return cls(settings, sensors)


def filter_batch(t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
                 mag: ArrayLike | None, settings: EKFSettings | str | None = None,
                 estimator: str = "ekf", sensors: tuple[str, ...] | list[str] = SENSORS,
                 fast: bool = True) -> BatchResult:
    """Run a fresh estimator (see :func:`make_estimator`) over rows of samples.

    t_s: (N,) seconds, non-decreasing. gyr [rad/s], acc [m/s^2], mag [uT]: (N, 3) each, a NaN
    row where that sensor has no sample at that time (or None: no such sensor).
    """
    t, g, a, m = batch_rows(t_s, gyr, acc, mag)
    return make_estimator(estimator, settings, sensors, fast=fast).run_batch(t, g, a, m)
