"""Comparison estimators with the EKF's interface, and the factory every caller uses.

* ``gyro``: plain gyroscope integration (exact for piecewise-constant rate) from an acc+mag start.
* ``accmag``: accelerometer + magnetometer only, no dynamics: each reading gives the orientation.
* ``complementary``: gyro integration pulled towards acc+mag with a time constant (seeds/004:
  fused = c * gyro + (1 - c) * accmag, c = tau / (tau + dt)), as a quaternion slerp.
"""

from __future__ import annotations

import copy
import math

import numpy as np
from numpy.typing import ArrayLike

from ekf import quaternion as quat
from ekf.reference import (SENSORS, OrientationEKF, Status, acc_mag_quaternion,
                           tilt_quaternion)
from ekf.settings import PRESETS, EKFSettings

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


class _SimpleEstimator:
    """Shared plumbing: switches, time, acc/mag memory, gates for the lights, snapshots."""

    name = "simple"

    def __init__(self, settings: EKFSettings | str | None = None,
                 sensors: tuple[str, ...] | list[str] = SENSORS) -> None:
        if settings is None:
            settings = PRESETS["default"]
        elif isinstance(settings, str):
            settings = PRESETS[settings]
        self.settings = settings
        self._enabled = {s: (s in sensors) for s in SENSORS}
        self.reset()

    def reset(self) -> None:
        s = self.settings
        self._q = quat.IDENTITY.copy()
        self._t: float | None = None
        self._initialised = False
        self._omega: np.ndarray | None = None
        self._omega_t = -math.inf
        self._acc: np.ndarray | None = None
        self._acc_t = -math.inf
        self._mag: np.ndarray | None = None
        self._mag_t = -math.inf
        self._heading_offset = 0.0
        self.status = Status(g=s.g, acc_gate=s.acc_gate, mag_gate=s.mag_gate)

    @property
    def quat(self) -> np.ndarray:
        return self._q.copy()

    @property
    def cov(self) -> None:
        return None

    @property
    def initialised(self) -> bool:
        return self._initialised

    @property
    def enabled(self) -> dict[str, bool]:
        return dict(self._enabled)

    def set_enabled(self, gyr: bool | None = None, acc: bool | None = None,
                    mag: bool | None = None) -> None:
        for name, value in (("gyr", gyr), ("acc", acc), ("mag", mag)):
            if value is not None:
                self._enabled[name] = bool(value)

    def set_settings(self, settings: EKFSettings) -> None:
        self.settings = settings

    def snapshot(self) -> dict:
        return copy.deepcopy(self.__dict__)

    def restore(self, state: dict) -> None:
        self.__dict__.update(copy.deepcopy(state))

    def align_heading(self, q_ref: ArrayLike) -> None:
        delta = quat.heading_of(quat.multiply(np.asarray(q_ref, float), quat.conjugate(self._q)))
        self._heading_offset += delta
        self._q = quat.normalize(quat.multiply(quat.from_axis_angle([0, 0, 1], delta), self._q))

    def step(self, t: float, gyr=None, acc=None, mag=None) -> Status:
        if gyr is not None:
            self.update_gyr(t, gyr)
        if acc is not None:
            self.update_acc(t, acc)
        if mag is not None:
            self.update_mag(t, mag)
        if gyr is None and acc is None and mag is None:
            self._advance(t)
        return self.status

    # -- helpers ------------------------------------------------------------------------------
    def _advance(self, t: float) -> None:
        if self._t is None:
            self._t = t
            return
        dt = t - self._t
        if dt <= 0:
            return
        t_prev = self._t
        self._t = t
        if not self._initialised or dt > self.settings.max_dt:
            self.status.used_gyr = False
            return
        if (self._omega is not None and self._enabled["gyr"]
                and t_prev - self._omega_t <= self.settings.gyr_hold_s):
            omega = self._omega - np.asarray(self.settings.gyr_bias, float)
            self._q = quat.normalize(quat.multiply(self._q, quat.from_rotation_vector(omega * dt)))
            self.status.used_gyr = True
        else:
            self.status.used_gyr = False

    def _acc_ok(self, y: np.ndarray) -> bool:
        s = self.settings
        norm = float(np.linalg.norm(y))
        self.status.acc_norm = norm
        rejected = abs(norm - s.g) > s.acc_gate
        self.status.acc_rejected = rejected
        return not rejected

    def _absolute(self) -> np.ndarray | None:
        """Orientation from the latest accelerometer and magnetometer readings (enabled ones)."""
        acc = self._acc if self._enabled["acc"] else None
        mag = self._mag if self._enabled["mag"] else None
        if acc is not None and mag is not None:
            q = acc_mag_quaternion(acc, mag)
        elif acc is not None:
            # Tilt only: keep the current heading.
            q = tilt_quaternion(acc)
            q = quat.normalize(quat.multiply(
                quat.from_axis_angle([0, 0, 1], quat.heading_of(self._q)), q))
            return q
        elif mag is not None:
            q = quat.from_axis_angle([0, 0, 1], math.atan2(mag[0], mag[1]))
        else:
            return None
        return quat.normalize(quat.multiply(quat.from_axis_angle([0, 0, 1], self._heading_offset), q))

    def _initialise(self) -> None:
        q = self._absolute()
        self._q = quat.IDENTITY.copy() if q is None else q
        self._initialised = True

    def update_gyr(self, t: float, gyr: ArrayLike) -> Status:
        self._advance(t)
        if self._enabled["gyr"]:
            self._omega = np.asarray(gyr, float).reshape(3)
            self._omega_t = t
            if not self._initialised and not (self._enabled["acc"] or self._enabled["mag"]):
                self._initialise()
        return self.status

    def update_acc(self, t: float, acc: ArrayLike) -> Status:
        self._advance(t)
        y = np.asarray(acc, float).reshape(3)
        if not self._enabled["acc"]:
            return self.status
        ok = self._acc_ok(y)
        if ok or self._acc is None:
            self._acc, self._acc_t = y, t
        if not self._initialised:
            self._initialise()
            return self.status
        self._absolute_update(t, ok, "acc")
        return self.status

    def update_mag(self, t: float, mag: ArrayLike) -> Status:
        self._advance(t)
        y = np.asarray(mag, float).reshape(3)
        if not self._enabled["mag"]:
            return self.status
        self._mag, self._mag_t = y, t
        self.status.mag_norm = float(np.linalg.norm(y))
        if not self._initialised and not self._enabled["acc"]:
            self._initialise()
            return self.status
        if self._initialised:
            self._absolute_update(t, True, "mag")
        return self.status

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
            self._q = q


class ComplementaryFilter(_SimpleEstimator):
    """Gyro integration corrected towards acc+mag: q <- slerp(q, q_accmag, 1 - c), c = tau/(tau+dt)."""

    name = "complementary"
    time_constant_s = 1.0

    def reset(self) -> None:
        super().reset()
        self._last_correction_t: float | None = None

    def _absolute_update(self, t: float, ok: bool, sensor: str) -> None:
        if not ok:
            return
        target = self._absolute()
        if target is None:
            return
        dt = 0.01 if self._last_correction_t is None else max(t - self._last_correction_t, 0.0)
        self._last_correction_t = t
        if dt == 0.0:
            return
        if not self._enabled["gyr"]:
            self._q = target
            return
        c = self.time_constant_s / (self.time_constant_s + dt)
        self._q = slerp(self._q, target, 1.0 - c)


def make_estimator(name: str = "ekf", settings: EKFSettings | None = None,
                   sensors: tuple[str, ...] | list[str] = SENSORS, fast: bool = True):
    """An estimator by name (see ESTIMATORS). "ekf" uses `settings` (default: the default preset),
    "course" the course preset. `fast` picks the compiled EKF when available (same estimates)."""
    if name not in ESTIMATORS:
        raise ValueError(f"unknown estimator {name!r}; choose from {', '.join(ESTIMATORS)}")
    if name in ("ekf", "course"):
        s = PRESETS["course"] if name == "course" else (settings or PRESETS["default"])
        if fast:
            try:
                from ekf.fast import FastEKF
            except ImportError:
                FastEKF = None
            if FastEKF is not None:
                return FastEKF(s, sensors)
        est = OrientationEKF(s, sensors)
        if name == "course":
            est.name = "course"
        return est
    cls = {"gyro": GyroIntegrator, "accmag": AccMagEstimator,
           "complementary": ComplementaryFilter}[name]
    return cls(settings, sensors)
