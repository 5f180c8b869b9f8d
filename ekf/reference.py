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

This module holds the sample entry points, the start and the rest detector; its parts are
mixins of :class:`OrientationEKF`: the time update (``ekf.reference_time_update``), the
measurement updates (``ekf.reference_updates``) and the magnetic field reference
(``ekf.reference_field``). Together they are the oracle; ``ekf.fast`` runs the same arithmetic
compiled and is tested against it.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

import ekf.quaternion as quat
from ekf.estimator import SENSORS, EstimatorBase, ekf_name
from ekf.outputs import ACC_CLIPPED, MAG_UNCALIBRATED
from ekf.reference_field import MagneticField
from ekf.reference_time_update import TimeUpdate
from ekf.reference_updates import MeasurementUpdates
from ekf.settings import EKFSettings
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


class OrientationEKF(TimeUpdate, MeasurementUpdates, MagneticField, EstimatorBase):
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
