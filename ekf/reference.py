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

The module is one class in sections, in the order a sample meets them: the sample entry
points, the start, rest detection, the time update, the accelerometer update, the magnetometer
update, the Joseph-form update and the normalisation, the online hard-iron fit and the magnetic
field reference. It is the oracle: ``ekf.fast.kernels`` runs the same arithmetic compiled, with
the same function names in the same order (tests/ekf/test_fast.py compares the two lists), and
is tested against it.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

import ekf.quaternion as quat
from ekf.diagnostics import (ACC_CLIPPED, ACC_NIS_GATE, ACC_NORM_GATE, MAG_DIP_GATE, MAG_NIS_GATE,
                             MAG_SETTLING, MAG_STRENGTH_GATE, MAG_UNCALIBRATED, NOT_REJECTED)
from ekf.estimator import SENSORS, EstimatorBase, ekf_name
from ekf.settings import EKFSettings
from ekf.state import EKFState, reference_dip_deg

__all__ = ["SENSORS", "OrientationEKF", "acc_mag_quaternion", "tilt_quaternion", "usable"]

# A reading is degenerate (refused, counted in Diagnostics.refused_samples) when a value is not
# finite or beyond MAX_READING (no phone sensor reads 1e6 m/s^2, rad/s or uT), or an acc/mag
# reading is shorter than MIN_NORM (no direction). Within these bounds every step stays finite.
MAX_READING = 1e6
MIN_NORM = 1e-6
# acc_range = 0: an axis within 1 % of the largest |axis| seen, once that exceeds 1.5 g, clips.
CLIP_MARGIN = 0.99
CLIP_MIN_G = 1.5

# The online hard-iron fit (mag_hard_iron_tau_s): a pair closes once the phone turned this far
# [rad] (a smaller turn says little about the offset), or is dropped after this long [s] (the
# gyro's relative rotation is trusted over short spans); residuals beyond this [uT] weigh less
# (w = min(1, this / |r|): a field changing in the world meanwhile).
HARD_IRON_PAIR_ANGLE = math.radians(20.0)
HARD_IRON_PAIR_MAX_S = 2.0
HARD_IRON_RESIDUAL = 5.0
# A new offset (a magnet put on the phone) is what rotation reveals: a pair whose residual is
# beyond HARD_IRON_RESTART_RESIDUAL [uT] opens a second fit of the recent pairs (forgotten with
# HARD_IRON_RESTART_TAU_S [s]); the fit starts again from it once that fit knows every direction
# (ACQUIRED_INFO), explains its pairs within HARD_IRON_RESIDUAL and the fit so far does not
# (beyond HARD_IRON_RESTART_RESIDUAL, RMS). A disturbance (a field moving in the world, coming
# and going) is explained by no one offset across the turns: it never restarts the fit, and the
# second fit is dropped once the fit so far explains the recent pairs again.
HARD_IRON_RESTART_RESIDUAL = 20.0
HARD_IRON_RESTART_TAU_S = 10.0
# A reading stronger than this [uT] is no Earth field (22-67 uT on the surface, up to ~100 near
# steel): where the field learned at the start is beyond it, the magnetometer is uncalibrated
# (a raw sensor: hard iron of hundreds of uT) and the offset is acquired before any use.
EARTH_FIELD_MAX = 100.0
# The acquisition's measure of "known": this much of the fit's normal matrix Σ Dᵀ D in a
# direction (a 20 deg pair adds ~0.12 across its turn's axis; 0.25: the offset's error there is
# about HARD_IRON_RESIDUAL / √0.25 = 10 uT at the fit's typical residual).
ACQUIRED_INFO = 0.25
# The acquisition's prior: numerical only (an offset of hundreds of uT must not be shrunk).
ACQUIRING_PRIOR = 1e-3


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
    up = np.asarray(acc, dtype=float).reshape(3) / np.linalg.norm(acc)
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
    up = np.asarray(acc, dtype=float).reshape(3) / np.linalg.norm(acc)
    east = np.cross(np.asarray(mag, dtype=float).reshape(3), up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    return quat.from_matrix(np.vstack([east, north, up]))


def _rotate_world_about_up(q: np.ndarray, angle: float) -> np.ndarray:
    return quat.normalize(quat.multiply(quat.from_axis_angle([0, 0, 1], angle), q))


def _elevation_deg(v: np.ndarray) -> float:
    """Angle of a world-frame vector above the horizontal [deg] (its dip, with the sign of up)."""
    return math.degrees(math.atan2(float(v[2]), math.hypot(float(v[0]), float(v[1]))))


class OrientationEKF(EstimatorBase):
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
        omega = np.asarray(gyr, dtype=float).reshape(3)
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
        y = np.asarray(acc, dtype=float).reshape(3)
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
        y = np.asarray(mag, dtype=float).reshape(3)
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
    # the start
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

    # ---------------------------------------------------------------------------------------
    # the time update (eq. 6, task 12)
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
    # the accelerometer update (tasks 6 and 8)
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

    # ---------------------------------------------------------------------------------------
    # the magnetometer update (tasks 9 and 11, footnote 2)
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

    # ---------------------------------------------------------------------------------------
    # the Joseph-form update, the zero-rate update and the normalisation
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
    # the online hard-iron fit
    def _fit_hard_iron(self, t: float, y: np.ndarray) -> None:
        """mag_hard_iron_tau_s: the sensor-frame offset b_m of the magnetometer, online.

        A field that is constant in the world, seen at two times i and j, obeys
        y_j - b = Q_j^T Q_i (y_i - b) whatever it is; with A = Q_j^T Q_i = Q(dq)^T, dq the
        turn between them integrated from the gyroscope alone (mag_pair_q, turned by every time
        update: the filter's own corrections are not a turn), that is D b = e,
        D = I - A, e = y_j - A y_i: linear in b, observable once the phone turns. A changed
        field in a building is constant in the world (it fits b = 0), a magnet on the phone is
        b. Each pair (turn >= HARD_IRON_PAIR_ANGLE within HARD_IRON_PAIR_MAX_S) adds w D^T D
        and w D^T e to sums forgotten with time constant tau, w = min(1, HARD_IRON_RESIDUAL /
        |e - D b|); b = (M + mag_hard_iron_prior I)^-1 v. A new offset restarts the sums only
        when one offset explains the recent pairs across the turns (``_restart_evidence``,
        ``_restart_due``)."""
        s, st = self.settings, self._state
        y = self._turned_to_stamp(y)
        if math.isnan(st.mag_pair_t) or t - st.mag_pair_t > HARD_IRON_PAIR_MAX_S:
            self._open_pair(t, y)
            return
        turn = st.mag_pair_q / np.linalg.norm(st.mag_pair_q)
        if 2.0 * math.acos(min(1.0, abs(float(turn[0])))) < HARD_IRON_PAIR_ANGLE:
            return
        A = quat.to_matrix(turn).T
        D = np.eye(3) - A
        e = y - A @ st.mag_pair_raw
        residual = float(np.linalg.norm(e - D @ st.mag_offset_fit))
        w = min(1.0, HARD_IRON_RESIDUAL / residual) if residual > 0.0 else 1.0
        forget = (math.exp(-(t - st.mag_offset_t) / s.mag_hard_iron_tau_s)
                  if math.isfinite(st.mag_offset_t) else 0.0)
        if st.mag_acquiring:
            w = 1.0                          # large residuals: the offset is far, not new
        elif residual > HARD_IRON_RESTART_RESIDUAL or (
                residual > HARD_IRON_RESIDUAL and math.isfinite(st.mag_restart_t)):
            self._restart_evidence(t, D, e)
        st.mag_offset_info[:] = forget * st.mag_offset_info + w * (D.T @ D)
        st.mag_offset_rhs[:] = forget * st.mag_offset_rhs + w * (D.T @ e)
        st.mag_offset_t = t
        if not st.mag_acquiring and self._restart_due():
            # a new offset: the fit starts again from the pairs that revealed it
            st.mag_offset_info[:] = st.mag_restart_info
            st.mag_offset_rhs[:] = st.mag_restart_rhs
            self._drop_restart()
        prior = ACQUIRING_PRIOR if st.mag_acquiring else s.mag_hard_iron_prior
        st.mag_offset_fit[:] = np.linalg.solve(st.mag_offset_info + prior * np.eye(3),
                                               st.mag_offset_rhs + prior * st.mag_offset_prior)
        self._acquisition_progress(y)
        self._open_pair(t, y)

    def _restart_evidence(self, t: float, D: np.ndarray, e: np.ndarray) -> None:
        """A pair the fit does not explain (beyond HARD_IRON_RESTART_RESIDUAL; once the second
        fit is open, beyond HARD_IRON_RESIDUAL) is also added, unweighted, to a second fit of
        such pairs, forgotten with HARD_IRON_RESTART_TAU_S: sums Mc = Σ Dᵀ D, vc = Σ Dᵀ e,
        ec = Σ |e|², nc = Σ 1. The first only opens it (its older reading may be from before
        the change). The fit keeps the pair with its weight w."""
        st = self._state
        if math.isnan(st.mag_restart_t):
            st.mag_restart_t = t
            return
        forget = math.exp(-(t - st.mag_restart_t) / HARD_IRON_RESTART_TAU_S)
        st.mag_restart_info[:] = forget * st.mag_restart_info + D.T @ D
        st.mag_restart_rhs[:] = forget * st.mag_restart_rhs + D.T @ e
        st.mag_restart_sq = forget * st.mag_restart_sq + float(e @ e)
        st.mag_restart_n = forget * st.mag_restart_n + 1.0
        st.mag_restart_t = t

    def _restart_due(self) -> bool:
        """The second fit's offset bc = Mc⁻¹ vc leaves the residual sum ec - bcᵀ vc, the fit's b
        leaves ec - 2 bᵀ vc + bᵀ Mc b. A new offset (True) when Mc knows every direction (its
        smallest eigenvalue >= ACQUIRED_INFO: the phone turned about more than one axis), bc
        explains the pairs (RMS <= HARD_IRON_RESIDUAL) and b does not (RMS beyond
        HARD_IRON_RESTART_RESIDUAL). Dropped when b explains them (a disturbance gone), or
        when nothing was added for HARD_IRON_RESTART_TAU_S."""
        st = self._state
        if math.isnan(st.mag_restart_t):
            return False
        M, v, n = st.mag_restart_info, st.mag_restart_rhs, st.mag_restart_n
        if st.mag_offset_t - st.mag_restart_t > HARD_IRON_RESTART_TAU_S:
            self._drop_restart()
            return False
        if n == 0.0:
            return False
        b = st.mag_offset_fit
        if (st.mag_restart_sq - 2.0 * float(b @ v) + float(b @ M @ b)) / n <= \
                HARD_IRON_RESTART_RESIDUAL ** 2:
            self._drop_restart()
            return False
        if np.linalg.eigvalsh(M)[0] < ACQUIRED_INFO:
            return False
        bc = np.linalg.solve(M, v)
        return (st.mag_restart_sq - float(bc @ v)) / n <= HARD_IRON_RESIDUAL ** 2

    def _drop_restart(self) -> None:
        """The second fit closed: its sums emptied."""
        st = self._state
        st.mag_restart_info[:] = 0.0
        st.mag_restart_rhs[:] = 0.0
        st.mag_restart_sq = 0.0
        st.mag_restart_n = 0.0
        st.mag_restart_t = math.nan

    def _explaining_offset(self, y: np.ndarray) -> None:
        """The offset applied to a reading: the fit's only where it explains what the field
        alone does not. Pairs of readings taken at two places differ by the field's change
        between them as well as by the turn, and the fit reads part of that as an offset; a
        calibrated magnetometer whose readings pass the strength gate as they come needs none.
        So the fit's offset is applied when the reading fails the gate as it is and passes it
        corrected (a magnet on the phone), and dropped when the reading passes as it is and
        fails corrected (the magnet gone); when both or neither pass, the choice stays. A raw
        magnetometer (acquiring, waiting or acquired: ``_check_uncalibrated``) always has its
        offset applied."""
        s, st = self.settings, self._state
        fit = st.mag_offset_fit
        if st.mag_acquiring or st.mag_waiting or np.any(st.mag_offset_prior != 0.0):
            st.mag_offset[:] = fit
        elif math.isfinite(st.mag_strength):
            self._choose_offset(y)
        st.diagnostics.mag_offset_norm = float(np.linalg.norm(st.mag_offset))

    def _choose_offset(self, y: np.ndarray) -> None:
        """``_explaining_offset`` for a calibrated magnetometer: the fit's offset or none."""
        s, st = self.settings, self._state
        fit, L = st.mag_offset_fit, st.mag_strength
        as_is = abs(float(np.linalg.norm(y)) - L) <= s.mag_gate
        corrected = abs(float(np.linalg.norm(y - fit)) - L) <= s.mag_gate
        applied = bool(np.any(st.mag_offset != 0.0))
        if corrected and not as_is:
            applied = True
        elif as_is and not corrected:
            applied = False
        st.mag_offset[:] = fit if applied else 0.0

    def _turned_to_stamp(self, y: np.ndarray) -> np.ndarray:
        """mag_delay_s: the reading was taken that long before its stamp; the field (y - b, b
        the offset so far) is turned on by the gyroscope's latest rate to the stamp: a field
        fixed in the world, seen from a body turning at w, turns by -w dt. Not while the offset
        is acquired (b is far from known) or without a gyroscope."""
        s, st = self.settings, self._state
        if not (s.mag_delay_s > 0.0 and st.omega_valid and st.gyr_enabled) or (
                st.mag_acquiring or st.mag_waiting):
            return y
        w = self._unbiased_rate()
        rate = float(np.linalg.norm(w))
        if rate == 0.0:
            return y
        R = quat.to_matrix(quat.from_axis_angle(w / rate, -rate * s.mag_delay_s))
        return st.mag_offset_fit + R @ (y - st.mag_offset_fit)

    def _check_uncalibrated(self) -> None:
        """The expected field, learned, is beyond any Earth field (EARTH_FIELD_MAX): the
        magnetometer is uncalibrated (a raw sensor, hundreds of uT of hard iron). Its offset is
        acquired while the phone turns (mag_acquiring: the fit unweighted, without its prior),
        and the magnetometer waits meanwhile (mag_waiting)."""
        st = self._state
        if (self.settings.mag_hard_iron_tau_s > 0.0 and not st.mag_waiting
                and st.mag_strength > EARTH_FIELD_MAX):
            st.mag_acquiring = True
            st.mag_waiting = True

    def _acquisition_progress(self, y: np.ndarray) -> None:
        """After a pair, during the acquisition: once every direction of the offset is known
        (the normal matrix's smallest eigenvalue >= ACQUIRED_INFO) the fit is weighted again
        and drawn to this offset (mag_offset_prior) instead of 0; once it is known where it
        turns the heading (the world's horizontal plane at the attitude now: the largest
        eigenvalue of H M^-1 H^T <= 1 / ACQUIRED_INFO) and the corrected reading is an Earth
        field, the magnetometer is used again (``_offset_acquired``)."""
        st = self._state
        info = st.mag_offset_info
        if st.mag_acquiring and np.linalg.eigvalsh(info)[0] >= ACQUIRED_INFO:
            st.mag_acquiring = False
            st.mag_offset_prior[:] = st.mag_offset_fit
        if st.mag_waiting and np.linalg.norm(y - st.mag_offset_fit) <= EARTH_FIELD_MAX:
            H = quat.to_matrix(self._x[:4])[:2]
            cov = H @ np.linalg.inv(info + ACQUIRING_PRIOR * np.eye(3)) @ H.T
            if np.linalg.eigvalsh(cov)[-1] * ACQUIRED_INFO <= 1.0:
                self._offset_acquired()

    def _offset_acquired(self) -> None:
        """The magnetometer is used again: the field and the heading are taken afresh from the
        next corrected reading (the heading may jump once, the learned field is young again)."""
        st = self._state
        st.mag_waiting = False
        st.heading_from_mag = False
        st.m0_valid = False
        st.mag_strength = math.nan
        st.mag_confirmed_time = 0.0
        st.mag_disturbed_time = 0.0
        st.mag_disturbed_t = math.nan
        st.mag_passing_since = math.nan
        st.mag_rejected_since = math.nan

    def _open_pair(self, t: float, y: np.ndarray) -> None:
        st = self._state
        st.mag_pair_t = t
        st.mag_pair_raw[:] = y
        st.mag_pair_q[:] = quat.IDENTITY

    # ---------------------------------------------------------------------------------------
    # the magnetic field reference
    def _learn_reference(self, y: np.ndarray, t: float) -> float:
        """mag_reference_s: add a reading to the expected field's sums (world frame, strength);
        meanwhile L_k is their mean. A reading whose strength or dip differs from the sums'
        mean by more than the gates (a disturbance fading in or out where the recording began)
        starts them again from itself, for mag_reference_s more: the expected field is learned
        from readings that agree. Returns ‖y‖."""
        s, st = self.settings, self._state
        norm = float(np.linalg.norm(y))
        m_w = quat.to_matrix(self._x[:4]) @ y
        mean = st.mag_reference_sum / st.mag_reference_count
        if (abs(norm - st.mag_reference_norm_sum / st.mag_reference_count) > s.mag_gate
                or abs(_elevation_deg(m_w) - _elevation_deg(mean)) > s.mag_dip_gate_deg):
            st.mag_reference_until = t + s.mag_reference_s
            st.mag_reference_sum[:] = 0.0
            st.mag_reference_norm_sum = 0.0
            st.mag_reference_count = 0.0
        st.mag_reference_sum[:] += m_w
        st.mag_reference_norm_sum += norm
        st.mag_reference_count += 1.0
        st.mag_strength = st.mag_reference_norm_sum / st.mag_reference_count
        st.diagnostics.mag_norm = norm
        st.diagnostics.mag_expected = st.mag_strength
        st.diagnostics.mag_gate = self.settings.mag_gate
        return norm

    def _finish_reference(self) -> None:
        """The end of mag_reference_s: L_k is the readings' mean strength, and m0 gets that
        strength and the dip of their mean world-frame vector; its horizontal direction stays
        (the heading does not move)."""
        st = self._state
        strength = st.mag_reference_norm_sum / st.mag_reference_count
        mean = st.mag_reference_sum / st.mag_reference_count
        dip = math.atan2(float(mean[2]), math.hypot(float(mean[0]), float(mean[1])))
        horizontal = math.hypot(float(st.m0[0]), float(st.m0[1]))
        if horizontal > 0.0:
            scale = strength * math.cos(dip) / horizontal
            st.m0[:] = [st.m0[0] * scale, st.m0[1] * scale, strength * math.sin(dip)]
        st.mag_strength = strength
        st.mag_reference_count = 0.0
        st.mag_reference_until = -math.inf
        st.diagnostics.mag_expected = strength
        st.diagnostics.mag_reference_dip_deg = self._reference_dip_deg()

    def _mag_gates(self, y: np.ndarray) -> tuple[float, float, int]:
        """Task 11's strength gate |‖y‖ - L_k| with the AR(1) estimate L_k, then the dip gate.
        Returns ‖y‖, the dip [deg] and which gate rejected the reading (NOT_REJECTED: none)."""
        s, st = self.settings, self._state
        diag = st.diagnostics
        norm = float(np.linalg.norm(y))
        diag.mag_norm = norm
        diag.mag_gate = s.mag_gate
        if math.isnan(st.mag_strength):
            st.mag_strength = norm
        L_prev = st.mag_strength
        rejected_by = MAG_STRENGTH_GATE if abs(norm - L_prev) > s.mag_gate else NOT_REJECTED
        dip = self._dip_deg(y)
        diag.mag_dip_deg = dip
        if (rejected_by == NOT_REJECTED and math.isfinite(s.mag_dip_gate_deg)
                and math.isfinite(dip)
                and abs(dip - self._reference_dip_deg()) > s.mag_dip_gate_deg):
            rejected_by = MAG_DIP_GATE
        # Task 11: AR(1) estimate of the field strength.
        if s.mag_strength_update == "always" or rejected_by == NOT_REJECTED:
            st.mag_strength = (1 - s.mag_alpha) * L_prev + s.mag_alpha * norm
        diag.mag_expected = st.mag_strength
        return norm, dip, rejected_by

    def _track_new_field(self, y: np.ndarray, t: float, norm: float, dip: float) -> None:
        """A new field is learned only when the rejected readings agree with each other
        (strength and dip within the gates of their running mean) for mag_relearn_s: a changed
        field, not a magnet that moves with the phone."""
        s, st = self.settings, self._state
        if s.mag_relearn_world:
            self._track_new_field_world(y, t)
            return
        cn, cd = st.mag_candidate_norm, st.mag_candidate_dip
        if (math.isnan(st.mag_rejected_since) or abs(norm - cn) > s.mag_gate
                or abs(dip - cd) > s.mag_dip_gate_deg):
            st.mag_rejected_since = t
            st.mag_candidate_norm, st.mag_candidate_dip = norm, dip
        else:
            st.mag_candidate_norm = cn + s.mag_alpha * (norm - cn)
            st.mag_candidate_dip = cd + s.mag_alpha * (dip - cd)
            if t - st.mag_rejected_since >= s.mag_relearn_s:
                self._relearn_field(y)

    def _track_new_field_world(self, y: np.ndarray, t: float) -> None:
        """mag_relearn_world: the rejected readings must agree in the world frame (strength and
        dip, measured against the estimated up, within the gates of their running mean Q(q) y)
        while the phone turns faster than mag_relearn_min_rate, for mag_relearn_s of turning: a
        field that changed in the building stays put in the world while the phone turns, a
        magnet on the phone turns with it (its strength and dip change). The time counts down
        again while readings disagree (a passing disturbance does not wipe out what was seen);
        at zero the next disagreeing reading starts a new candidate. While the expected field
        is young (mag_first_relearn_s) the candidate needs only that long (or mag_relearn_s if
        shorter), turning or not. The new m0 has their strength and dip; its north is kept."""
        s, st = self.settings, self._state
        m_w = quat.to_matrix(self._x[:4]) @ y
        cand = st.mag_candidate_world
        agrees = (abs(float(np.linalg.norm(m_w)) - float(np.linalg.norm(cand))) <= s.mag_gate
                  and abs(_elevation_deg(m_w) - _elevation_deg(cand)) <= s.mag_dip_gate_deg)
        if not math.isnan(st.mag_rejected_since) and not agrees:
            st.mag_candidate_time -= t - st.mag_candidate_t
        if math.isnan(st.mag_rejected_since) or (not agrees and st.mag_candidate_time <= 0.0):
            st.mag_rejected_since = t
            cand[:] = m_w
            st.mag_candidate_time = 0.0
        elif agrees:
            cand[:] = cand + s.mag_alpha * (m_w - cand)
            young = st.mag_confirmed_time < s.mag_first_relearn_s
            if young or self._turn_rate() >= s.mag_relearn_min_rate:
                st.mag_candidate_time += t - st.mag_candidate_t
            needed = min(s.mag_first_relearn_s, s.mag_relearn_s) if young else s.mag_relearn_s
            if st.mag_candidate_time >= needed:
                # the new field's strength and dip; north stays where it was (the heading
                # follows the new field no faster than mag_return_s)
                horizontal = math.hypot(float(st.m0[0]), float(st.m0[1]))
                if horizontal > 0.0:
                    st.m0[:2] *= math.hypot(float(cand[0]), float(cand[1])) / horizontal
                st.m0[2] = cand[2]
                st.mag_strength = float(np.linalg.norm(cand))
                st.diagnostics.mag_reference_dip_deg = self._reference_dip_deg()
                st.mag_rejected_since = math.nan
        st.mag_candidate_t = t

    def _count_confirmed(self, t: float) -> None:
        """A reading that passed the gates of the learned field (mag_first_relearn_s): the time
        since the previous one counts towards confirming the field (gaps beyond max_dt do not)."""
        st = self._state
        if st.mag_reference_count == 0.0 and t - st.mag_passed_t <= self.settings.max_dt:
            st.mag_confirmed_time += t - st.mag_passed_t

    def _turn_rate(self) -> float:
        """‖ω − b‖ of the latest gyroscope sample driving the filter (0: none)."""
        st = self._state
        if not (st.omega_valid and st.gyr_enabled):
            return 0.0
        return float(np.linalg.norm(self._unbiased_rate()))

    def _unbiased_rate(self) -> np.ndarray:
        """ω − b of the latest gyroscope sample (b the estimate, or the setting gyr_bias
        without the bias in the state)."""
        st = self._state
        bias = self._x[4:7] if st.n == 7 else np.asarray(self.settings.gyr_bias, float)
        return st.omega - bias

    def _set_m0_from(self, y: np.ndarray) -> None:
        """m0 = (0, sqrt(mx^2 + my^2), mz) of the reading expressed in the (level) world frame."""
        st = self._state
        m_w = quat.to_matrix(self._x[:4]) @ y
        st.m0[:] = [0.0, math.hypot(m_w[0], m_w[1]), m_w[2]]
        st.m0_valid = True
        st.mag_strength = float(np.linalg.norm(st.m0))
        st.diagnostics.mag_expected = st.mag_strength
        st.diagnostics.mag_reference_dip_deg = self._reference_dip_deg()
        if self.settings.mag_reference_s > 0.0:
            # mag_reference_s: this reading starts the mean that becomes the expected field
            st.mag_reference_until = st.t + self.settings.mag_reference_s
            st.mag_reference_sum[:] = st.m0
            st.mag_reference_norm_sum = st.mag_strength
            st.mag_reference_count = 1.0

    def _relearn_field(self, y: np.ndarray) -> None:
        st = self._state
        st.mag_strength = float(np.linalg.norm(y))
        if st.m0_valid:
            m_w = quat.to_matrix(self._x[:4]) @ y
            st.m0[:] = [0.0, math.hypot(m_w[0], m_w[1]), m_w[2]]
            st.diagnostics.mag_reference_dip_deg = self._reference_dip_deg()
        st.mag_rejected_since = math.nan

    def _dip_deg(self, y: np.ndarray) -> float:
        """Angle between up and the field [deg]: up from the estimate, or from the latest
        accelerometer reading (NaN when there is none or it was disturbed)."""
        st = self._state
        if self.settings.mag_dip_from_estimate:
            up = float(quat.to_matrix(self._x[:4])[2] @ y)
            c = up / (np.linalg.norm(y) + 1e-300)
            return math.degrees(math.acos(max(-1.0, min(1.0, c))))
        a = st.last_acc
        if not st.last_acc_valid or st.flags.acc_rejected:
            return math.nan
        c = float(a @ y) / (np.linalg.norm(a) * np.linalg.norm(y) + 1e-300)
        return math.degrees(math.acos(max(-1.0, min(1.0, c))))

    def _reference_dip_deg(self) -> float:
        return reference_dip_deg(self._state.m0) if self._state.m0_valid else math.nan
