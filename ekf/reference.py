"""The readable reference EKF: the course's quaternion filter, line by line.

State (model 4a): x = q, the orientation sensor -> ENU, with the gyroscope as input u = w.
With ``settings.estimate_gyro_bias`` (model 4c): x = (q, b_w). Everything the filter keeps is
one :class:`ekf.state.EKFState` (declared once, in ``ekf/state.py``); ``self._x`` and
``self._P`` are views of its x[:n] and P[:n, :n].

Each sensor arrives at its own time and rate. Every ``update_*`` call first moves the state to
the sample's time with the most recent gyroscope sample (eq. 6), then uses the sample:

* time update (task 3-4):   q_k = F(w) q_{k-1} + G(q) v,  F = I + T/2 S(w),  G = T/2 S̄(q)
                            P_k = F P F^T + G R_w G^T
* without a gyroscope:      q_k = q_{k-1},  P grows by a random walk (task 12)
* accelerometer (task 6):   y_a = Q(q)^T g0,  H = [dQ/dq_i^T g0]_i,  gate |‖y_a‖ - g| (task 8)
* magnetometer (task 9):    y_m = Q(q)^T m0,  H = [dQ/dq_i^T m0]_i,  AR(1) gate on ‖y_m‖ (task 11)
* after each step:          q <- q / ‖q‖ (w >= 0),  P <- J P J^T with J the Jacobian of that map
                            (not needed after an exact time update: exp(T/2 S(w)) keeps ‖q‖)

Extensions beyond the course (each a setting, off in the "course" preset; see ekf.settings):
gyroscope bias in the state with a zero-rate update at rest (model 4c), gyroscope scale noise,
the sample convention of the gyroscope, an accelerometer low-pass that the gyroscope carries
along with the phone, a heading-only magnetometer update with strength, dip and settling gates,
re-learning of a changed field, and a cap on how often the slow updates run.

Covariance updates use the Joseph form P = (I - K H) P (I - K H)^T + K R K^T, which stays
symmetric positive semi-definite and is valid for any gain (the heading-only gain included).

This module (with its magnetic-field part, ``ekf.reference_field``) is the oracle; ``ekf.fast``
runs the same arithmetic compiled and is tested against it.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

import ekf.quaternion as quat
from ekf.estimator import SENSORS, EstimatorBase, ekf_name
from ekf.outputs import (ACC_CLIPPED, ACC_NIS_GATE, ACC_NORM_GATE, MAG_NIS_GATE, MAG_SETTLING,
                         MAG_UNCALIBRATED, NOT_REJECTED)
from ekf.settings import EKFSettings
from ekf.reference_field import MagneticField
from ekf.state import EKFState

__all__ = ["SENSORS", "OrientationEKF", "acc_mag_quaternion", "tilt_quaternion", "usable"]

# A reading is degenerate (refused, counted in Diagnostics.refused_samples) when a value is not
# finite or beyond MAX_READING (no phone sensor reads 1e6 m/s^2, rad/s or uT), or an acc/mag
# reading is shorter than MIN_NORM (no direction). Within these bounds every step stays finite.
MAX_READING = 1e6
MIN_NORM = 1e-6
# acc_range = 0: an axis within 1 % of the largest |axis| seen, once that exceeds 1.5 g, clips.
CLIP_MARGIN = 0.99
CLIP_MIN_G = 1.5


def _as3(v: ArrayLike) -> np.ndarray:
    return np.asarray(v, dtype=float).reshape(3)


def usable(t: float, v: np.ndarray | None, needs_direction: bool) -> bool:
    """False for a degenerate sample (see MAX_READING, MIN_NORM): it must not enter the filter."""
    if not math.isfinite(t):
        return False
    if v is None:
        return True
    if not all(math.isfinite(x) and abs(x) <= MAX_READING for x in v):
        return False
    return not needs_direction or math.sqrt(float(v @ v)) >= MIN_NORM


def tilt_quaternion(acc: ArrayLike) -> np.ndarray:
    """The orientation with zero heading whose Q(q)^T (0,0,1) is along `acc` (sensor frame)."""
    up = _as3(acc) / np.linalg.norm(acc)
    # Heading is arbitrary: choose the world x axis (east) as the sensor x axis projected on the
    # horizontal plane, or the sensor y axis when x points (almost) up.
    ref = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    north = np.cross(up, ref)
    north /= np.linalg.norm(north)
    east = np.cross(north, up)
    q = quat.from_matrix(np.vstack([east, north, up]))
    # Remove whatever heading that choice gave, so tilt-only starts point the same way.
    return _rotate_world_about_up(q, -quat.heading_of(q))


def acc_mag_quaternion(acc: ArrayLike, mag: ArrayLike) -> np.ndarray:
    """Orientation from one accelerometer and one magnetometer reading (TRIAD).

    Rows of Q(q) are the world axes seen in the sensor frame: up along y_a, east along
    y_m x up, north = up x east.
    """
    up = _as3(acc) / np.linalg.norm(acc)
    east = np.cross(_as3(mag), up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    return quat.from_matrix(np.vstack([east, north, up]))


def _rotate_world_about_up(q: np.ndarray, angle: float) -> np.ndarray:
    return quat.normalize(quat.multiply(quat.from_axis_angle([0, 0, 1], angle), q))


class OrientationEKF(MagneticField, EstimatorBase):
    """Quaternion EKF for asynchronous gyroscope, accelerometer and magnetometer samples.

    Parameters
    ----------
    settings:
        An :class:`EKFSettings`, or a preset name ("default", "course"). Default: "default".
        With ``PRESETS["course"]`` the estimator's :attr:`name` is "course", else "ekf".
    sensors:
        Which sensors are enabled at the start (any non-empty subset of gyr, acc, mag).

    Feed samples in time order (at equal times: gyroscope, accelerometer, magnetometer) with
    times in seconds. Read :attr:`quat` (w-first, sensor -> ENU, w >= 0), :attr:`cov`,
    :attr:`gyro_bias`, :attr:`flags` and :attr:`diagnostics`.
    """

    name = "ekf"
    state_class = EKFState
    compatible = ("ekf", "course")

    def __init__(self, settings: EKFSettings | str | None = None,
                 sensors: tuple[str, ...] | list[str] = SENSORS) -> None:
        super().__init__(settings, sensors)
        self.name = ekf_name(self.settings)
        self._state: EKFState

    # ---------------------------------------------------------------------------------------
    # public state
    @property
    def quat(self) -> np.ndarray:
        return self._state.x[:4].copy()

    @property
    def cov(self) -> np.ndarray:
        """Covariance of the full state (4x4, or 7x7 with the bias)."""
        return self._P.copy()

    @property
    def gyro_bias(self) -> np.ndarray:
        st = self._state
        return st.x[4:7].copy() if st.n == 7 else np.asarray(self.settings.gyr_bias, float)

    # views of the state's x[:n] and P[:n, :n]: the formulas below read and write through them
    @property
    def _x(self) -> np.ndarray:
        return self._state.x[:self._state.n]

    @_x.setter
    def _x(self, value: np.ndarray) -> None:
        self._state.x[:self._state.n] = value

    @property
    def _P(self) -> np.ndarray:
        n = self._state.n
        return self._state.P[:n, :n]

    @_P.setter
    def _P(self, value: np.ndarray) -> None:
        n = self._state.n
        self._state.P[:n, :n] = value

    def set_enabled(self, gyr: bool | None = None, acc: bool | None = None,
                    mag: bool | None = None) -> None:
        """Switch sensors in or out of the filter; takes effect at the next sample."""
        super().set_enabled(gyr, acc, mag)
        st = self._state
        if not st.gyr_enabled:
            st.omega_valid = False
            st.acc_carried_valid = False   # nothing carries the low-pass along without the gyro
        st.flags.at_rest = st.flags.at_rest and (st.gyr_enabled or st.acc_enabled)

    def set_settings(self, settings: EKFSettings) -> None:
        """Use new settings from the next sample on, keeping the orientation."""
        st = self._state
        self.settings = settings
        n = 7 if settings.estimate_gyro_bias else 4
        if n != st.n:
            # q and its covariance stay; the bias starts afresh (or leaves the state)
            st.x[4:] = 0.0
            st.P[:, 4:] = 0.0
            st.P[4:, :] = 0.0
            if n == 7:
                st.x[4:] = settings.gyr_bias
                st.P[4:, 4:] = np.eye(3) * settings.initial_gyro_bias_std ** 2
            st.n = n

    def align_heading(self, q_ref: ArrayLike) -> None:
        """Turn the estimate about world up so its heading matches `q_ref`'s (the phone's)."""
        st = self._state
        q = self._x[:4]
        delta = quat.heading_of(quat.multiply(np.asarray(q_ref, float), quat.conjugate(q)))
        self._x[:4] = _rotate_world_about_up(q, delta)
        if st.m0_valid:
            # Turning our world turns the Earth field in it by the same angle.
            st.m0[:] = quat.rotate(quat.from_axis_angle([0, 0, 1], delta), st.m0.copy())
            st.diagnostics.mag_reference_dip_deg = self._reference_dip_deg()

    # ---------------------------------------------------------------------------------------
    # sample entry points
    def update_gyr(self, t: float, gyr: ArrayLike) -> None:
        """A gyroscope sample [rad/s, sensor frame] at time t [s]: it drives the time update
        from t until the next sample (eq. 5: w piecewise constant), or, with
        ``gyr_rate_before_sample``, from the previous sample up to t."""
        omega = _as3(gyr)
        s, st = self.settings, self._state
        if not self._accept(t, omega, False):
            return
        t = self._not_before(t)
        if s.gyr_rate_before_sample and st.gyr_enabled:
            # The sample is the rate over the interval that ends now: it drives the state to t.
            if not st.omega_valid or t - st.omega_t <= s.gyr_hold_s:
                st.omega[:] = omega
                st.omega_valid = True
        self._advance(t)
        if not st.gyr_enabled:
            return
        st.omega[:] = omega
        st.omega_valid = True
        st.omega_t = t
        if not st.initialised and not (st.acc_enabled or st.mag_enabled):
            self._initialise(t)   # gyroscope alone: nothing absolute, start at identity (flat)
        self._detect_rest_gyr(t, omega)
        if (st.n == 7 and st.initialised and st.flags.at_rest
                and t - st.rest_updated_t >= s.update_period_s):
            st.rest_updated_t = t
            self._zero_rate_update(omega)

    def update_acc(self, t: float, acc: ArrayLike) -> None:
        """An accelerometer sample [m/s^2, sensor frame] at time t [s]."""
        y = _as3(acc)
        if not self._accept(t, y, True):
            return
        t = self._not_before(t)
        self._advance(t)
        st = self._state
        st.last_acc[:] = y
        st.last_acc_valid = True
        st.last_acc_t = t
        if not st.acc_enabled:
            st.flags.used_acc = False
            return
        if self._clipped(y):
            # A saturated axis: the reading is not the specific force; it enters no update,
            # no average, no start, and it is motion for the rest detector.
            st.flags.acc_rejected = True
            st.flags.used_acc = False
            st.diagnostics.acc_norm = float(np.linalg.norm(y))
            st.diagnostics.acc_rejected_by = ACC_CLIPPED
            if self.settings.acc_lowpass_s > 0.0:
                self._shaking(t, y)
            st.last_motion_t = t
            self._update_rest(t)
            return
        self._detect_rest_acc(t, y)
        if not st.initialised:
            self._initialise(t)
            return
        if self.settings.acc_lowpass_s > 0.0 and st.gyr_enabled and st.flags.used_gyr:
            # Only the gyroscope can carry the average along; without it (switched off, or a
            # phone that has none, or silent), the reading itself, and the average restarts.
            self._acc_lowpass_update(t, y)
        else:
            st.acc_carried_valid = False
            self._acc_update(y, self.settings.acc_gate)

    def update_mag(self, t: float, mag: ArrayLike) -> None:
        """A magnetometer sample [uT, sensor frame] at time t [s]."""
        y = _as3(mag)
        if not self._accept(t, y, True):
            return
        t = self._not_before(t)
        self._advance(t)
        st = self._state
        if self.settings.mag_hard_iron_tau_s > 0.0 and st.mag_enabled and st.initialised:
            self._fit_hard_iron(t, y)
            self._explaining_offset(y)
            y = y - st.mag_offset
            if float(np.linalg.norm(y)) < MIN_NORM:
                return
        st.last_mag[:] = y
        st.last_mag_valid = True
        st.last_mag_t = t
        if not st.mag_enabled:
            st.flags.used_mag = False
            return
        if not st.initialised:
            # Wait for the accelerometer to give tilt (when it is on); else start from mag alone.
            if not st.acc_enabled:
                self._initialise(t)
            return
        if st.mag_waiting and st.flags.used_gyr:
            # uncalibrated: its offset is being acquired (_check_uncalibrated)
            st.flags.used_mag = False
            st.flags.mag_rejected = True
            st.diagnostics.mag_rejected_by = MAG_UNCALIBRATED
            st.diagnostics.mag_norm = float(np.linalg.norm(y))
            return
        if not st.heading_from_mag:
            self._take_heading_from_mag(y)
            return
        self._mag_update(y, t)
        self._check_uncalibrated()

    def step(self, t: float, gyr: ArrayLike | None = None, acc: ArrayLike | None = None,
             mag: ArrayLike | None = None) -> None:
        """All samples that share time t, in the fixed order gyroscope, accelerometer, magnetometer."""
        if gyr is not None:
            self.update_gyr(t, gyr)
        if acc is not None:
            self.update_acc(t, acc)
        if mag is not None:
            self.update_mag(t, mag)
        if gyr is None and acc is None and mag is None and self._accept(t, None, False):
            self._advance(self._not_before(t))

    def _accept(self, t: float, v: np.ndarray | None, needs_direction: bool) -> bool:
        """A degenerate sample is refused and counted; the estimate stays as it was."""
        if usable(t, v, needs_direction):
            return True
        self._state.diagnostics.refused_samples += 1
        return False

    def _not_before(self, t: float) -> float:
        """A sample older than the latest counts as at the latest time (the state cannot go
        back; an ordered stream never has one)."""
        return t if math.isnan(self._state.t) or t >= self._state.t else self._state.t

    def _clipped(self, y: np.ndarray) -> bool:
        """Any axis at the accelerometer's range (acc_range, or the range seen in the data)."""
        s, st = self.settings, self._state
        largest = float(np.max(np.abs(y)))
        st.acc_axis_max = max(st.acc_axis_max, largest)
        if s.acc_range == 0.0:
            return (st.acc_axis_max >= CLIP_MIN_G * s.g
                    and largest >= CLIP_MARGIN * st.acc_axis_max)
        return largest >= s.acc_range

    # ---------------------------------------------------------------------------------------
    # time update
    def _advance(self, t: float) -> None:
        st = self._state
        if math.isnan(st.t):
            st.t = t
            return
        dt = t - st.t
        if dt <= 0.0:
            return   # same time (or a late sample): nothing to integrate
        t_prev = st.t
        st.t = t
        if not st.initialised:
            return
        if dt > self.settings.max_dt:
            # A pause or a new connection: keep the orientation, do not integrate the gap.
            st.flags.used_gyr = False
            st.acc_carried_valid = False
            return
        if st.omega_valid and st.gyr_enabled and t_prev - st.omega_t <= self.settings.gyr_hold_s:
            self._time_update_gyro(st.omega, dt)
            st.flags.used_gyr = True
            if not self.settings.exact_discretisation:
                self._normalise()
            elif self._x[0] < 0:
                self._flip_sign()
        else:
            self._time_update_random_walk(dt)
            st.flags.used_gyr = False
            self._normalise()

    def _time_update_gyro(self, omega_measured: np.ndarray, T: float) -> None:
        """Eq. (6): q_k = F(w) q_{k-1} + G(q) v with F = I + T/2 S(w), G = T/2 S̄(q)."""
        s = self.settings
        n = self._state.n
        q = self._x[:4]
        bias = self._x[4:7] if n == 7 else np.asarray(s.gyr_bias, float)
        omega = omega_measured - bias
        if s.exact_discretisation:
            # exp(T/2 S(w)) = cos(|w|T/2) I + sin(|w|T/2)/|w| S(w)
            rate = float(np.linalg.norm(omega))
            half = 0.5 * rate * T
            sinc = (math.sin(half) / rate) if rate > 1e-12 else 0.5 * T
            F = math.cos(half) * np.eye(4) + sinc * quat.S_omega(omega)
        else:
            F = np.eye(4) + 0.5 * T * quat.S_omega(omega)
        if self._state.acc_carried_valid:
            self._carry(omega, T)
        G = 0.5 * T * quat.S_bar(q)
        # R_w, grown in fast turns by the scale-factor uncertainty: + (k |w|)^2 I
        Rw = np.asarray(s.gyr_noise_cov, float) + np.eye(3) * (s.gyr_scale_noise ** 2
                                                               * float(omega @ omega))
        A = np.eye(n)
        A[:4, :4] = F
        Qn = np.zeros((n, n))
        Qn[:4, :4] = G @ Rw @ G.T
        if n == 7:
            A[:4, 4:7] = -G                 # d q_k / d b = -T/2 S̄(q)
            Qn[4:, 4:] = np.eye(3) * (s.gyro_bias_random_walk ** 2 * T)
        self._x[:4] = F @ q
        self._P = A @ self._P @ A.T + Qn
        if s.mag_hard_iron_tau_s > 0.0 and math.isfinite(self._state.mag_pair_t):
            # the hard-iron fit's pair: the turn since its first reading, from the gyro alone
            self._state.mag_pair_q[:] = F @ self._state.mag_pair_q

    def _carry(self, omega: np.ndarray, T: float) -> None:
        """Turn the carried specific force into the new body frame: the body turned by |w| T
        about w, so a fixed vector turns by the opposite, v <- R(w T)^T v (Rodrigues)."""
        rate = float(np.linalg.norm(omega))
        if rate < 1e-12:
            return
        k = omega / rate
        v = self._state.acc_carried
        angle = rate * T
        cs, sn = math.cos(angle), math.sin(angle)
        self._state.acc_carried[:] = v * cs - np.cross(k, v) * sn + k * float(k @ v) * (1 - cs)

    def _time_update_random_walk(self, T: float) -> None:
        """No gyroscope: q stays; P grows as if w were white noise with the given intensity."""
        s = self.settings
        q = self._x[:4]
        Sq = quat.S_bar(q)
        self._P[:4, :4] += 0.25 * T * s.no_gyro_random_walk ** 2 * (Sq @ Sq.T)
        if self._state.n == 7:
            self._P[4:, 4:] += np.eye(3) * (s.gyro_bias_random_walk ** 2 * T)

    # ---------------------------------------------------------------------------------------
    # measurement updates
    def _shaking(self, t: float, y: np.ndarray) -> None:
        """acc_noise_adapt: d² <- d² + alpha ((‖y‖ - g)² - d²), the low-pass of acc_lowpass_s."""
        s, st = self.settings, self._state
        dev = (float(np.linalg.norm(y)) - s.g) ** 2
        dt = t - st.acc_dev_t if math.isfinite(st.acc_dev_t) else math.inf
        alpha = 1.0 if not dt < math.inf else dt / (s.acc_lowpass_s + dt)
        st.acc_dev_sq += alpha * (dev - st.acc_dev_sq)
        st.acc_dev_t = t

    def _acc_update(self, y: np.ndarray, norm_gate: float, noise_scale: float = 1.0) -> None:
        """Task 6 with the task-8 gate: y_a = Q(q)^T g0 + e_a, skipped when |‖y‖ - g| > gate
        or (optionally) when the NIS exceeds acc_nis_gate."""
        s = self.settings
        flags, diag = self._state.flags, self._state.diagnostics
        norm = float(np.linalg.norm(y))
        diag.acc_norm = norm
        diag.g = s.g
        diag.acc_gate = s.acc_gate
        if abs(norm - s.g) > norm_gate:
            # Task 8: a specific force is present; the model y_a = Q^T g0 does not hold.
            flags.acc_rejected = True
            flags.used_acc = False
            diag.acc_rejected_by = ACC_NORM_GATE
            return
        q = self._x[:4]
        g0 = np.array([0.0, 0.0, s.g])
        Qm = quat.to_matrix(q)
        y_hat = Qm.T @ g0
        H = np.zeros((3, self._state.n))
        for i, dQi in enumerate(quat.dQ_dq(q)):
            H[:, i] = dQi.T @ g0
        R = np.asarray(s.acc_noise_cov, float) * noise_scale
        keep = self._tilt_only(q) if self._magnetometer_silent() else None
        nis = self._update(y - y_hat, H, R, gate=s.acc_nis_gate, keep=keep)
        diag.acc_nis = nis
        accepted = nis <= s.acc_nis_gate
        flags.acc_rejected = not accepted
        flags.used_acc = accepted
        diag.acc_rejected_by = NOT_REJECTED if accepted else ACC_NIS_GATE

    def _magnetometer_silent(self) -> bool:
        """acc_tilt_only_after_s: no magnetometer update for that long (or none ever)."""
        st, after = self._state, self.settings.acc_tilt_only_after_s
        return after < math.inf and not st.t - st.mag_updated_t < after

    def _tilt_only(self, q: np.ndarray) -> np.ndarray:
        """The projection that takes from a gain what gravity cannot observe: in q, a turn
        about world up (the direction u of (0,0,0,1) ⊗ q); in the bias, the rate about up
        (v = Q(q)^T e_z, up in the sensor frame)."""
        n = self._state.n
        u = quat.multiply(np.array([0.0, 0.0, 0.0, 1.0]), q)
        u /= np.linalg.norm(u)
        keep = np.eye(n)
        keep[:4, :4] -= np.outer(u, u)
        if n == 7:
            v = quat.to_matrix(q).T @ np.array([0.0, 0.0, 1.0])
            keep[4:, 4:] -= np.outer(v, v) / float(v @ v)
        return keep

    def _acc_lowpass_update(self, t: float, y: np.ndarray) -> None:
        """The accelerometer through a first-order low-pass (time constant acc_lowpass_s) that
        the gyroscope carries along with the phone (see _carry): gravity stays in the average,
        accelerations cancel. Every reading is averaged; at most every update_period_s the
        average is the measurement (without the norm gate). The norm gate only flags a
        disturbed reading for the user."""
        s, st = self.settings, self._state
        norm = float(np.linalg.norm(y))
        self._shaking(t, y)
        if not st.acc_carried_valid:
            st.acc_carried[:] = y
            st.acc_carried_valid = True
        else:
            dt = t - st.acc_carried_t
            alpha = dt / (s.acc_lowpass_s + dt)
            st.acc_carried[:] = st.acc_carried + alpha * (y - st.acc_carried)
        st.acc_carried_t = t
        used = True
        if t - st.acc_updated_t >= s.update_period_s:
            st.acc_updated_t = t
            scale = 1.0 + s.acc_noise_adapt * st.acc_dev_sq / (s.g * s.g)
            self._acc_update(st.acc_carried, math.inf, scale)
            used = st.flags.used_acc   # the NIS gate may still refuse the average
        st.diagnostics.acc_norm = norm
        st.diagnostics.acc_gate = s.acc_gate
        st.flags.acc_rejected = abs(norm - s.g) > s.acc_gate
        st.diagnostics.acc_rejected_by = ACC_NORM_GATE if st.flags.acc_rejected else NOT_REJECTED
        st.flags.used_acc = used

    def _mag_update(self, y: np.ndarray, t: float) -> None:
        """Task 9 behind the gates of task 11 (and the dip, settling and NIS gates), with the
        expected field learned over the first mag_reference_s and a bound on how long a
        disturbance keeps the magnetometer out."""
        s, st = self.settings, self._state
        flags, diag = st.flags, st.diagnostics
        if t < st.mag_reference_until:
            norm, dip, rejected_by = self._learn_reference(y, t), math.nan, NOT_REJECTED
        else:
            if st.mag_reference_count > 0:
                self._finish_reference()
            norm, dip, rejected_by = self._mag_gates(y)
        # After a rejection, readings must pass for mag_settle_s before they are used again.
        if rejected_by != NOT_REJECTED:
            st.mag_passing_since = math.nan
        elif math.isnan(st.mag_passing_since):
            st.mag_passing_since = t
        if rejected_by == NOT_REJECTED and t - st.mag_passing_since < s.mag_settle_s:
            rejected_by = MAG_SETTLING
        diag.mag_rejected_by = rejected_by
        R = np.asarray(s.mag_noise_cov, float) * self._uneven_field(t, norm)
        if rejected_by != NOT_REJECTED:
            if s.mag_strength_update == "accepted":
                self._track_new_field(y, t, norm, dip)
            flags.mag_rejected = True
            flags.used_mag = False
            # With the gyroscope the disturbance keeps the magnetometer out until readings
            # pass again or agree as a new field; without it (nothing else holds the heading)
            # at most mag_max_reject_no_gyro_s, then readings are used, trusted less.
            bound = math.inf if flags.used_gyr else s.mag_max_reject_no_gyro_s
            if not self._count_disturbance(t, bound) > bound:
                return
            R = R * s.mag_reject_noise_scale
        else:
            st.mag_rejected_since = math.nan
            self._count_passing(t)
            flags.mag_rejected = False
        if t - st.mag_updated_t < s.update_period_s:
            flags.used_mag = False
            return
        gain_cap = self._heading_gain_cap(t - st.mag_updated_t) if flags.used_gyr else 1.0
        st.mag_updated_t = t
        q = self._x[:4]
        if s.mag_heading_only:
            nis = self._mag_heading_update(y, R, s.mag_nis_gate, gain_cap)
        else:
            m0 = st.m0
            y_hat = quat.to_matrix(q).T @ m0
            H = np.zeros((3, st.n))
            for i, dQi in enumerate(quat.dQ_dq(q)):
                H[:, i] = dQi.T @ m0
            nis = self._update(y - y_hat, H, R, gate=s.mag_nis_gate)
        diag.mag_nis = nis
        if nis > s.mag_nis_gate:
            # An innovation the filter cannot believe: rejected, and readings must settle again.
            st.mag_passing_since = math.nan
            diag.mag_rejected_by = MAG_NIS_GATE
            flags.mag_rejected = True
            flags.used_mag = False
            return
        flags.used_mag = True


    def _count_disturbance(self, t: float, bound: float) -> float:
        """The time a disturbance has kept the magnetometer out: a rejected (or settling)
        reading adds the time since the previous reading when that was rejected too, as long as
        the count is within the bound (VQF's magRejectT). Returns the count."""
        st = self._state
        if not math.isnan(st.mag_disturbed_t) and not st.mag_disturbed_time > bound:
            st.mag_disturbed_time += t - st.mag_disturbed_t
        st.mag_disturbed_t = t
        return st.mag_disturbed_time


    def _count_passing(self, t: float) -> None:
        """A reading that passes counts towards confirming the learned field
        (``_count_confirmed``) and ends the disturbance (its count is 0)."""
        st = self._state
        self._count_confirmed(t)
        st.mag_disturbed_time = 0.0
        st.mag_disturbed_t = math.nan
        st.mag_passed_t = t

    def _uneven_field(self, t: float, norm: float) -> float:
        """mag_noise_adapt: where the field is uneven (a building's, along a walk), readings
        that pass the gates are still bent: d² <- low-pass (mag_return_s) of (‖y‖ - L_k)², the
        deviation clipped at mag_noise_adapt_clip gates, and R_m is scaled by
        1 + mag_noise_adapt d² / L_k²."""
        s, st = self.settings, self._state
        if (s.mag_noise_adapt == 0.0 or not math.isfinite(st.mag_strength)
                or not st.flags.used_gyr):
            return 1.0   # off, or no gyroscope: then the magnetometer is all the heading there is
        d = norm - st.mag_strength
        clip = s.mag_noise_adapt_clip * s.mag_gate     # a magnet counts as this much at most
        if abs(d) > clip:
            d = math.copysign(clip, d)
        alpha = 1.0
        if math.isfinite(st.mag_dev_t):
            dt = t - st.mag_dev_t
            alpha = dt / (s.mag_return_s + dt) if s.mag_return_s + dt > 0.0 else 1.0
        st.mag_dev_sq += alpha * (d * d - st.mag_dev_sq)
        st.mag_dev_t = t
        return 1.0 + s.mag_noise_adapt * st.mag_dev_sq / st.mag_strength ** 2

    def _heading_gain_cap(self, dt: float) -> float:
        """mag_return_s: the largest fraction of a heading innovation one update may correct,
        dt / (dt + tau) for dt since the previous update (1: no cap). Only while the gyroscope
        drives the filter: without it the magnetometer is all the heading there is."""
        tau = self.settings.mag_return_s
        if tau <= 0.0:
            return 1.0
        return dt / (dt + tau) if math.isfinite(dt) else 1.0

    def _mag_heading_update(self, y: np.ndarray, R: np.ndarray,
                            gate: float = math.inf, gain_cap: float = 1.0) -> float:
        """Footnote 2: use only the field's horizontal direction, and only turn about up.

        Pseudo-measurement: the heading error psi = atan2(-m_E, m_N) of the reading rotated to
        the world frame (0 when it points north). The gain is projected onto the direction in
        q-space of a rotation about world up, so tilt is never changed by the magnetometer.
        """
        n = self._state.n
        q = self._x[:4]
        m_w = quat.to_matrix(q) @ y
        horizontal_sq = m_w[0] ** 2 + m_w[1] ** 2
        if horizontal_sq < 1e-6:
            return math.nan
        psi, d_psi_d_mw = self._heading_error(m_w)
        H = np.zeros((1, n))
        for i, dQi in enumerate(quat.dQ_dq(q)):
            dm = dQi @ y
            H[0, i] = d_psi_d_mw @ dm[:2]
        # Heading noise from the field noise: sigma_psi^2 = sigma_m^2 / |m_horizontal|^2.
        r = float(np.trace(R)) / 3.0 / horizontal_sq
        P = self._P
        HPH = float((H @ P @ H.T)[0, 0])
        S = HPH + r
        nis = psi * psi / S
        if nis > gate:
            return nis
        # mag_bias_innovation_limit: the bias learns from at most limit·√S of psi
        limit = self.settings.mag_bias_innovation_limit
        bias_weight = limit * math.sqrt(S) / abs(psi) if abs(psi) > limit * math.sqrt(S) else 1.0
        if HPH * (1.0 - gain_cap) > gain_cap * r:
            # mag_return_s: a larger r, so that at most gain_cap of psi is corrected now
            if gain_cap <= 0.0:
                return nis
            r = HPH * (1.0 - gain_cap) / gain_cap
            S = HPH + r
        K = (P @ H.T) / S
        # Keep only the component of the quaternion correction along a turn about up:
        # d q / d delta = 1/2 (0,0,0,1) ⊗ q.
        u = 0.5 * quat.multiply(np.array([0.0, 0.0, 0.0, 1.0]), q)
        u /= np.linalg.norm(u)
        K[:4, :] = np.outer(u, u) @ K[:4, :]
        K[4:, :] *= bias_weight
        innovation = -psi
        self._x = self._x + (K * innovation).ravel()
        I_KH = np.eye(n) - K @ H
        self._P = I_KH @ P @ I_KH.T + r * (K @ K.T)
        self._normalise()
        return nis

    def _update(self, innovation: np.ndarray, H: np.ndarray, R: np.ndarray,
                gate: float = math.inf, keep: np.ndarray | None = None) -> float:
        """Standard EKF measurement update in Joseph form; returns the NIS. Skipped (state
        untouched) when the NIS exceeds `gate`. `keep`: a projection applied to the gain
        (K <- keep K), the directions the measurement must not move; the Joseph form holds
        for any gain, so P stays the covariance of the estimate."""
        P = self._P
        S = H @ P @ H.T + R
        S_inv = np.linalg.inv(S)
        nis = float(innovation @ S_inv @ innovation)
        if nis > gate:
            return nis
        K = P @ H.T @ S_inv
        if keep is not None:
            K = keep @ K
        self._x = self._x + K @ innovation
        I_KH = np.eye(self._state.n) - K @ H
        self._P = I_KH @ P @ I_KH.T + K @ R @ K.T
        self._normalise()
        return nis

    def _zero_rate_update(self, omega: np.ndarray) -> None:
        """Model 4c at rest: the true rate is zero, so the gyro sample measures the bias."""
        H = np.zeros((3, self._state.n))
        H[:, 4:7] = np.eye(3)
        R = np.eye(3) * self.settings.rest_rate_noise_std ** 2
        self._update(omega - self._x[4:7], H, R)

    def _flip_sign(self) -> None:
        """q <- -q: the same rotation with w >= 0; the q-bias covariance changes sign."""
        self._x[:4] = -self._x[:4]
        self._P[:4, 4:] = -self._P[:4, 4:]
        self._P[4:, :4] = -self._P[4:, :4]

    def _normalise(self) -> None:
        """q <- q/|q| with w >= 0, and P <- J P J^T with J = d(q/|q|)/dq = (I - q q^T/|q|^2)/|q|."""
        q = self._x[:4]
        norm = float(np.linalg.norm(q))
        J = np.eye(self._state.n)
        J[:4, :4] = (np.eye(4) - np.outer(q, q) / norm ** 2) / norm
        q = q / norm
        if q[0] < 0:
            q = -q
            J[:4, :4] = -J[:4, :4]
        self._x[:4] = q
        self._P = J @ self._P @ J.T
        self._P = 0.5 * (self._P + self._P.T)

    # ---------------------------------------------------------------------------------------
    # initialisation and the magnetic field reference
    def _initialise(self, t: float) -> None:
        s, st = self.settings, self._state
        acc_ok = st.acc_enabled and st.last_acc_valid
        mag_ok = st.mag_enabled and st.last_mag_valid and t - st.last_mag_t <= 0.1
        if acc_ok and mag_ok and (np.linalg.norm(np.cross(st.last_mag, st.last_acc))
                                  <= 1e-6 * np.linalg.norm(st.last_mag)
                                  * np.linalg.norm(st.last_acc)):
            mag_ok = False   # a field along gravity has no heading: tilt now, heading later
        if acc_ok and mag_ok:
            q = acc_mag_quaternion(st.last_acc, st.last_mag)
            st.heading_from_mag = True
        elif acc_ok:
            q = tilt_quaternion(st.last_acc)
        elif mag_ok:
            # Magnetometer alone: assume level, heading from the horizontal field.
            m = st.last_mag
            q = quat.from_axis_angle([0, 0, 1], math.atan2(m[0], m[1]))
            st.heading_from_mag = True
        else:
            q = quat.IDENTITY.copy()
        self._x[:4] = quat.normalize(q)
        n = st.n
        P = np.zeros((n, n))
        Sq = quat.S_bar(self._x[:4])
        P[:4, :4] = 0.25 * s.initial_attitude_std ** 2 * (Sq @ Sq.T)
        if not (acc_ok and mag_ok):
            # Heading (or everything) unknown until a magnetometer reading arrives.
            P[:4, :4] += 0.25 * (Sq @ Sq.T)
        if n == 7:
            P[4:, 4:] = np.eye(3) * s.initial_gyro_bias_std ** 2
        self._P = P
        st.initialised = True
        if st.heading_from_mag and not st.m0_valid and st.last_mag_valid:
            self._set_m0_from(st.last_mag)

    def _take_heading_from_mag(self, y: np.ndarray) -> None:
        """The first magnetometer reading after a tilt-only start sets the heading."""
        st = self._state
        q = self._x[:4]
        m_w = quat.to_matrix(q) @ y
        if m_w[0] ** 2 + m_w[1] ** 2 < 1e-6:
            return
        psi, _ = self._heading_error(m_w)
        self._x[:4] = _rotate_world_about_up(q, -psi)
        Sq = quat.S_bar(self._x[:4])
        self._P[:4, :4] = 0.25 * self.settings.initial_attitude_std ** 2 * (Sq @ Sq.T)
        self._P[:4, 4:] = 0.0   # a fresh attitude is uncorrelated with the bias estimate
        self._P[4:, :4] = 0.0
        st.heading_from_mag = True
        if not st.m0_valid:
            self._set_m0_from(y)

    def _heading_error(self, m_w: np.ndarray) -> tuple[float, np.ndarray]:
        """Angle psi [rad] from the reference field's horizontal direction (north unless the
        world was turned by align_heading) to the reading's, counter-clockwise seen from above,
        and d psi / d (m_E, m_N)."""
        st = self._state
        ref = st.m0 if st.m0_valid else np.array([0.0, 1.0, 0.0])
        rx, ry = float(ref[0]), float(ref[1])
        cross = rx * m_w[1] - ry * m_w[0]
        dot = rx * m_w[0] + ry * m_w[1]
        psi = math.atan2(cross, dot)
        # d atan2(c, d) = (d dc - c dd) / (c^2 + d^2); dc/dm = (-ry, rx), dd/dm = (rx, ry)
        denom = cross * cross + dot * dot
        grad = (dot * np.array([-ry, rx]) - cross * np.array([rx, ry])) / denom
        return psi, grad

    # ---------------------------------------------------------------------------------------
    # rest detection
    def _detect_rest_gyr(self, t: float, omega: np.ndarray) -> None:
        st = self._state
        bias = self._x[4:7] if st.n == 7 else np.asarray(self.settings.gyr_bias, float)
        if float(np.linalg.norm(omega - bias)) > self.settings.rest_gyr_threshold:
            st.last_motion_t = t
        self._update_rest(t)

    def _detect_rest_acc(self, t: float, y: np.ndarray) -> None:
        st = self._state
        if not st.acc_lowpass_valid:
            st.acc_lowpass[:] = y
            st.acc_lowpass_valid = True
        st.acc_lowpass[:] = 0.9 * st.acc_lowpass + 0.1 * y
        if float(np.linalg.norm(y - st.acc_lowpass)) > self.settings.rest_acc_threshold:
            st.last_motion_t = t
        self._update_rest(t)

    def _update_rest(self, t: float) -> None:
        st = self._state
        if not (st.gyr_enabled or st.acc_enabled):
            st.flags.at_rest = False
            return
        if st.last_motion_t == -math.inf:
            st.last_motion_t = t   # the first sample starts the clock
        st.flags.at_rest = t - st.last_motion_t >= self.settings.rest_min_duration
