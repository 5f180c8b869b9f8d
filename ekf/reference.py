"""The readable reference EKF: the course's quaternion filter, line by line.

State (model 4a): x = q, the orientation sensor -> ENU, with the gyroscope as input u = w.
With ``settings.estimate_gyro_bias`` (model 4c): x = (q, b_w).

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

This module is the oracle; ``ekf.fast`` runs the same arithmetic compiled and is tested
against it.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ekf import quaternion as quat
from ekf.settings import EKFSettings, PRESETS

SENSORS = ("gyr", "acc", "mag")


@dataclass
class Status:
    """What the filter did with its latest samples: the lights and their reasons.

    Flags keep the decision of the latest sample of their sensor. With the accelerometer
    low-pass (``acc_lowpass_s`` > 0) every reading is averaged, and ``acc_rejected`` only says
    that the latest reading was outside the norm gate (disturbed).
    """

    acc_rejected: bool = False
    mag_rejected: bool = False
    at_rest: bool = False
    used_gyr: bool = False     # the latest time update was driven by a gyroscope sample
    used_acc: bool = False     # the latest accelerometer sample was used in an update
    used_mag: bool = False     # the latest magnetometer sample was used in an update
    acc_norm: float = math.nan   # ||y_a|| [m/s^2]
    g: float = math.nan          # expected ||y_a|| [m/s^2]
    acc_gate: float = math.nan   # [m/s^2]
    acc_nis: float = math.nan    # normalised innovation squared of the latest acc update
    mag_norm: float = math.nan   # ||y_m|| [uT]
    mag_expected: float = math.nan  # L_k [uT]
    mag_gate: float = math.nan   # [uT]
    mag_nis: float = math.nan
    mag_dip_deg: float = math.nan   # measured angle between field and up [deg]


def _as3(v: ArrayLike) -> np.ndarray:
    return np.asarray(v, dtype=float).reshape(3)


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


def chi2_3dof_quantile(p: float) -> float:
    """Wilson-Hilferty approximation of the chi-square quantile with 3 degrees of freedom."""
    from statistics import NormalDist
    z = NormalDist().inv_cdf(p)
    k = 3.0
    return k * (1 - 2 / (9 * k) + z * math.sqrt(2 / (9 * k))) ** 3


class OrientationEKF:
    """Quaternion EKF for asynchronous gyroscope, accelerometer and magnetometer samples.

    Parameters
    ----------
    settings:
        An :class:`EKFSettings`, or a preset name ("default", "course"). Default: "default".
    sensors:
        Which sensors are enabled at the start (any non-empty subset of gyr, acc, mag).

    Feed samples in time order (at equal times: gyroscope, accelerometer, magnetometer) with
    times in seconds. Read :attr:`quat` (w-first, sensor -> ENU, w >= 0), :attr:`cov`,
    :attr:`gyro_bias` and :attr:`status`.
    """

    name = "ekf"

    def __init__(self, settings: EKFSettings | str | None = None,
                 sensors: tuple[str, ...] | list[str] = SENSORS) -> None:
        if settings is None:
            settings = PRESETS["default"]
        elif isinstance(settings, str):
            settings = PRESETS[settings]
        self.settings: EKFSettings = settings
        self._enabled = {s: (s in sensors) for s in SENSORS}
        self.reset()

    # ---------------------------------------------------------------------------------------
    # public state
    @property
    def enabled(self) -> dict[str, bool]:
        return dict(self._enabled)

    @property
    def quat(self) -> np.ndarray:
        return self._x[:4].copy()

    @property
    def cov(self) -> np.ndarray:
        """Covariance of the full state (4x4, or 7x7 with the bias)."""
        return self._P.copy()

    @property
    def gyro_bias(self) -> np.ndarray:
        return self._x[4:7].copy() if self._n == 7 else np.asarray(self.settings.gyr_bias, float)

    @property
    def initialised(self) -> bool:
        return self._initialised

    @property
    def time(self) -> float | None:
        return self._t

    def set_enabled(self, gyr: bool | None = None, acc: bool | None = None,
                    mag: bool | None = None) -> None:
        """Switch sensors in or out of the filter; takes effect at the next sample."""
        for name, value in (("gyr", gyr), ("acc", acc), ("mag", mag)):
            if value is not None:
                self._enabled[name] = bool(value)
        if not self._enabled["gyr"]:
            self._omega = None
            self._acc_carried = None   # nothing carries the low-pass along without the gyro
        self.status.at_rest = self.status.at_rest and (self._enabled["gyr"] or self._enabled["acc"])

    def set_settings(self, settings: EKFSettings) -> None:
        """Use new settings from the next sample on, keeping the orientation."""
        old_n = self._n
        self.settings = settings
        n = 7 if settings.estimate_gyro_bias else 4
        if n != old_n:
            x = np.zeros(n)
            P = np.zeros((n, n))
            x[:4] = self._x[:4]
            P[:4, :4] = self._P[:4, :4]
            if n == 7:
                x[4:] = settings.gyr_bias
                P[4:, 4:] = np.eye(3) * settings.initial_gyro_bias_std ** 2
            self._x, self._P, self._n = x, P, n

    def reset(self) -> None:
        """Forget everything but settings and switches; re-initialise from the next samples."""
        s = self.settings
        self._n = 7 if s.estimate_gyro_bias else 4
        self._x = np.zeros(self._n)
        self._x[0] = 1.0
        if self._n == 7:
            self._x[4:] = s.gyr_bias
        self._P = np.eye(self._n) * 1.0
        self._t: float | None = None
        self._initialised = False
        self._heading_from_mag = False
        self._omega: np.ndarray | None = None     # latest gyro sample (bias not removed)
        self._omega_t = -math.inf
        self._last_acc: np.ndarray | None = None
        self._last_acc_t = -math.inf
        self._last_mag: np.ndarray | None = None
        self._last_mag_t = -math.inf
        self._m0 = None if s.m0 is None else np.asarray(s.m0, dtype=float)
        self._mag_strength = math.nan if self._m0 is None else float(np.linalg.norm(self._m0))
        self._mag_rejected_since = math.nan      # rejected readings agree since then
        self._mag_candidate_norm = math.nan      # their running strength [uT] ...
        self._mag_candidate_dip = math.nan       # ... and dip [deg]
        self._mag_passing_since = -math.inf      # readings pass the gates since then
        self._acc_carried: np.ndarray | None = None   # low-passed specific force [m/s^2]
        self._acc_carried_t = math.nan
        self._acc_updated_t = -math.inf          # latest update times (update_period_s)
        self._mag_updated_t = -math.inf
        self._rest_updated_t = -math.inf
        self._acc_lowpass: np.ndarray | None = None
        self._last_motion_t = -math.inf
        self._still_since_t = math.inf
        self.status = Status(g=s.g, acc_gate=s.acc_gate, mag_gate=s.mag_gate)

    def snapshot(self) -> dict:
        """Everything needed to continue later from exactly here (for replay seeking)."""
        return copy.deepcopy({k: v for k, v in self.__dict__.items()})

    def restore(self, state: dict) -> None:
        self.__dict__.update(copy.deepcopy(state))

    def align_heading(self, q_ref: ArrayLike) -> None:
        """Turn the estimate about world up so its heading matches `q_ref`'s (the phone's)."""
        q = self._x[:4]
        delta = quat.heading_of(quat.multiply(np.asarray(q_ref, float), quat.conjugate(q)))
        self._x[:4] = _rotate_world_about_up(q, delta)
        if self._m0 is not None:
            # Turning our world turns the Earth field in it by the same angle.
            self._m0 = quat.rotate(quat.from_axis_angle([0, 0, 1], delta), self._m0)

    # ---------------------------------------------------------------------------------------
    # sample entry points
    def update_gyr(self, t: float, gyr: ArrayLike) -> Status:
        """A gyroscope sample [rad/s, sensor frame] at time t [s]: it drives the time update
        from t until the next sample (eq. 5: w piecewise constant), or, with
        ``gyr_rate_before_sample``, from the previous sample up to t."""
        omega = _as3(gyr)
        s = self.settings
        if s.gyr_rate_before_sample and self._enabled["gyr"]:
            # The sample is the rate over the interval that ends now: it drives the state to t.
            if self._omega is None or t - self._omega_t <= s.gyr_hold_s:
                self._omega = omega
        self._advance(t)
        if not self._enabled["gyr"]:
            return self.status
        self._omega = omega
        self._omega_t = t
        if not self._initialised and not (self._enabled["acc"] or self._enabled["mag"]):
            self._initialise(t)   # gyroscope alone: nothing absolute, start at identity (flat)
        self._detect_rest_gyr(t, omega)
        if (self._n == 7 and self._initialised and self.status.at_rest
                and t - self._rest_updated_t >= s.update_period_s):
            self._rest_updated_t = t
            self._zero_rate_update(omega)
        return self.status

    def update_acc(self, t: float, acc: ArrayLike) -> Status:
        """An accelerometer sample [m/s^2, sensor frame] at time t [s]."""
        self._advance(t)
        y = _as3(acc)
        self._last_acc, self._last_acc_t = y, t
        if not self._enabled["acc"]:
            self.status.used_acc = False
            return self.status
        self._detect_rest_acc(t, y)
        if not self._initialised:
            self._initialise(t)
            return self.status
        if self.settings.acc_lowpass_s > 0.0 and self._enabled["gyr"]:
            # Only the gyroscope can carry the average along; without it, the reading itself.
            self._acc_lowpass_update(t, y)
        else:
            self._acc_update(y, self.settings.acc_gate)
        return self.status

    def update_mag(self, t: float, mag: ArrayLike) -> Status:
        """A magnetometer sample [uT, sensor frame] at time t [s]."""
        self._advance(t)
        y = _as3(mag)
        self._last_mag, self._last_mag_t = y, t
        if not self._enabled["mag"]:
            self.status.used_mag = False
            return self.status
        if not self._initialised:
            # Wait for the accelerometer to give tilt (when it is on); else start from mag alone.
            if not self._enabled["acc"]:
                self._initialise(t)
            return self.status
        if not self._heading_from_mag:
            self._take_heading_from_mag(y)
            return self.status
        self._mag_update(y, t)
        return self.status

    def step(self, t: float, gyr: ArrayLike | None = None, acc: ArrayLike | None = None,
             mag: ArrayLike | None = None) -> Status:
        """All samples that share time t, in the fixed order gyroscope, accelerometer, magnetometer."""
        if gyr is not None:
            self.update_gyr(t, gyr)
        if acc is not None:
            self.update_acc(t, acc)
        if mag is not None:
            self.update_mag(t, mag)
        if gyr is None and acc is None and mag is None:
            self._advance(t)
        return self.status

    # ---------------------------------------------------------------------------------------
    # time update
    def _advance(self, t: float) -> None:
        if self._t is None:
            self._t = t
            return
        dt = t - self._t
        if dt <= 0.0:
            return   # same time (or a late sample): nothing to integrate
        t_prev = self._t
        self._t = t
        if not self._initialised:
            return
        if dt > self.settings.max_dt:
            # A pause or a new connection: keep the orientation, do not integrate the gap.
            self.status.used_gyr = False
            self._acc_carried = None
            return
        omega = self._omega
        if omega is not None and self._enabled["gyr"] and t_prev - self._omega_t <= self.settings.gyr_hold_s:
            self._time_update_gyro(omega, dt)
            self.status.used_gyr = True
            if not self.settings.exact_discretisation:
                self._normalise()
            elif self._x[0] < 0:
                self._flip_sign()
        else:
            self._time_update_random_walk(dt)
            self.status.used_gyr = False
            self._normalise()

    def _time_update_gyro(self, omega_measured: np.ndarray, T: float) -> None:
        """Eq. (6): q_k = F(w) q_{k-1} + G(q) v with F = I + T/2 S(w), G = T/2 S̄(q)."""
        s = self.settings
        n = self._n
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
        if self._acc_carried is not None:
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

    def _carry(self, omega: np.ndarray, T: float) -> None:
        """Turn the carried specific force into the new body frame: the body turned by |w| T
        about w, so a fixed vector turns by the opposite, v <- R(w T)^T v (Rodrigues)."""
        rate = float(np.linalg.norm(omega))
        if rate < 1e-12:
            return
        k = omega / rate
        v = self._acc_carried
        angle = rate * T
        cs, sn = math.cos(angle), math.sin(angle)
        self._acc_carried = v * cs - np.cross(k, v) * sn + k * float(k @ v) * (1 - cs)

    def _time_update_random_walk(self, T: float) -> None:
        """No gyroscope: q stays; P grows as if w were white noise with the given intensity."""
        s = self.settings
        q = self._x[:4]
        Sq = quat.S_bar(q)
        self._P[:4, :4] += 0.25 * T * s.no_gyro_random_walk ** 2 * (Sq @ Sq.T)
        if self._n == 7:
            self._P[4:, 4:] += np.eye(3) * (s.gyro_bias_random_walk ** 2 * T)

    # ---------------------------------------------------------------------------------------
    # measurement updates
    def _acc_update(self, y: np.ndarray, norm_gate: float) -> None:
        """Task 6 with the task-8 gate: y_a = Q(q)^T g0 + e_a, skipped when |‖y‖ - g| > gate
        or (optionally) when the NIS exceeds acc_nis_gate."""
        s = self.settings
        norm = float(np.linalg.norm(y))
        self.status.acc_norm = norm
        self.status.g = s.g
        self.status.acc_gate = s.acc_gate
        if abs(norm - s.g) > norm_gate:
            # Task 8: a specific force is present; the model y_a = Q^T g0 does not hold.
            self.status.acc_rejected = True
            self.status.used_acc = False
            return
        q = self._x[:4]
        g0 = np.array([0.0, 0.0, s.g])
        Qm = quat.to_matrix(q)
        y_hat = Qm.T @ g0
        H = np.zeros((3, self._n))
        for i, dQi in enumerate(quat.dQ_dq(q)):
            H[:, i] = dQi.T @ g0
        R = np.asarray(s.acc_noise_cov, float)
        nis = self._update(y - y_hat, H, R, gate=s.acc_nis_gate)
        self.status.acc_nis = nis
        accepted = nis <= s.acc_nis_gate
        self.status.acc_rejected = not accepted
        self.status.used_acc = accepted

    def _acc_lowpass_update(self, t: float, y: np.ndarray) -> None:
        """The accelerometer through a first-order low-pass (time constant acc_lowpass_s) that
        the gyroscope carries along with the phone (see _carry): gravity stays in the average,
        accelerations cancel. Every reading is averaged; at most every update_period_s the
        average is the measurement (without the norm gate). The norm gate only flags a
        disturbed reading for the user."""
        s = self.settings
        norm = float(np.linalg.norm(y))
        if self._acc_carried is None:
            self._acc_carried = y.copy()
        else:
            dt = t - self._acc_carried_t
            alpha = dt / (s.acc_lowpass_s + dt)
            self._acc_carried = self._acc_carried + alpha * (y - self._acc_carried)
        self._acc_carried_t = t
        used = True
        if t - self._acc_updated_t >= s.update_period_s:
            self._acc_updated_t = t
            self._acc_update(self._acc_carried, math.inf)
            used = self.status.used_acc   # the NIS gate may still refuse the average
        self.status.acc_norm = norm
        self.status.acc_gate = s.acc_gate
        self.status.acc_rejected = abs(norm - s.g) > s.acc_gate
        self.status.used_acc = used

    def _mag_update(self, y: np.ndarray, t: float) -> None:
        s = self.settings
        norm = float(np.linalg.norm(y))
        self.status.mag_norm = norm
        self.status.mag_gate = s.mag_gate
        if math.isnan(self._mag_strength):
            self._mag_strength = norm
        L_prev = self._mag_strength
        rejected = abs(norm - L_prev) > s.mag_gate
        dip = self._dip_deg(y)
        self.status.mag_dip_deg = dip
        if not rejected and math.isfinite(s.mag_dip_gate_deg) and math.isfinite(dip):
            rejected = abs(dip - self._reference_dip_deg()) > s.mag_dip_gate_deg
        # Task 11: AR(1) estimate of the field strength.
        if s.mag_strength_update == "always" or not rejected:
            self._mag_strength = (1 - s.mag_alpha) * L_prev + s.mag_alpha * norm
        self.status.mag_expected = self._mag_strength
        # After a rejection, readings must pass for mag_settle_s before they are used again.
        if rejected:
            self._mag_passing_since = math.nan
        elif math.isnan(self._mag_passing_since):
            self._mag_passing_since = t
        settling = t - self._mag_passing_since < s.mag_settle_s
        if rejected or settling:
            if s.mag_strength_update == "accepted":
                # A new field is learned only when the rejected readings agree with each
                # other (strength and dip within the gates of their running mean) for
                # mag_relearn_s: a changed field, not a magnet that moves with the phone.
                cn, cd = self._mag_candidate_norm, self._mag_candidate_dip
                if (math.isnan(self._mag_rejected_since) or abs(norm - cn) > s.mag_gate
                        or abs(dip - cd) > s.mag_dip_gate_deg):
                    self._mag_rejected_since = t
                    self._mag_candidate_norm, self._mag_candidate_dip = norm, dip
                else:
                    self._mag_candidate_norm = cn + s.mag_alpha * (norm - cn)
                    self._mag_candidate_dip = cd + s.mag_alpha * (dip - cd)
                    if t - self._mag_rejected_since >= s.mag_relearn_s:
                        self._relearn_field(y)
            self.status.mag_rejected = True
            self.status.used_mag = False
            return
        self._mag_rejected_since = math.nan
        self.status.mag_rejected = False
        if t - self._mag_updated_t < s.update_period_s:
            self.status.used_mag = False
            return
        self._mag_updated_t = t
        q = self._x[:4]
        R = np.asarray(s.mag_noise_cov, float)
        if s.mag_heading_only:
            nis = self._mag_heading_update(y, R, s.mag_nis_gate)
        else:
            m0 = self._m0
            y_hat = quat.to_matrix(q).T @ m0
            H = np.zeros((3, self._n))
            for i, dQi in enumerate(quat.dQ_dq(q)):
                H[:, i] = dQi.T @ m0
            nis = self._update(y - y_hat, H, R, gate=s.mag_nis_gate)
        self.status.mag_nis = nis
        if nis > s.mag_nis_gate:
            # An innovation the filter cannot believe: rejected, and readings must settle again.
            self._mag_passing_since = math.nan
            self.status.mag_rejected = True
            self.status.used_mag = False
            return
        self.status.mag_rejected = False
        self.status.used_mag = True

    def _mag_heading_update(self, y: np.ndarray, R: np.ndarray,
                            gate: float = math.inf) -> float:
        """Footnote 2: use only the field's horizontal direction, and only turn about up.

        Pseudo-measurement: the heading error psi = atan2(-m_E, m_N) of the reading rotated to
        the world frame (0 when it points north). The gain is projected onto the direction in
        q-space of a rotation about world up, so tilt is never changed by the magnetometer.
        """
        q = self._x[:4]
        m_w = quat.to_matrix(q) @ y
        horizontal_sq = m_w[0] ** 2 + m_w[1] ** 2
        if horizontal_sq < 1e-6:
            return math.nan
        psi, d_psi_d_mw = self._heading_error(m_w)
        H = np.zeros((1, self._n))
        for i, dQi in enumerate(quat.dQ_dq(q)):
            dm = dQi @ y
            H[0, i] = d_psi_d_mw @ dm[:2]
        # Heading noise from the field noise: sigma_psi^2 = sigma_m^2 / |m_horizontal|^2.
        r = float(np.trace(R)) / 3.0 / horizontal_sq
        P = self._P
        S = float((H @ P @ H.T)[0, 0]) + r
        if psi * psi / S > gate:
            return psi * psi / S
        K = (P @ H.T) / S
        # Keep only the component of the quaternion correction along a turn about up:
        # d q / d delta = 1/2 (0,0,0,1) ⊗ q.
        u = 0.5 * quat.multiply(np.array([0.0, 0.0, 0.0, 1.0]), q)
        u /= np.linalg.norm(u)
        K[:4, :] = np.outer(u, u) @ K[:4, :]
        innovation = -psi
        self._x = self._x + (K * innovation).ravel()
        I_KH = np.eye(self._n) - K @ H
        self._P = I_KH @ P @ I_KH.T + r * (K @ K.T)
        self._normalise()
        return innovation * innovation / S

    def _update(self, innovation: np.ndarray, H: np.ndarray, R: np.ndarray,
                gate: float = math.inf) -> float:
        """Standard EKF measurement update in Joseph form; returns the NIS. Skipped (state
        untouched) when the NIS exceeds `gate`."""
        P = self._P
        S = H @ P @ H.T + R
        S_inv = np.linalg.inv(S)
        nis = float(innovation @ S_inv @ innovation)
        if nis > gate:
            return nis
        K = P @ H.T @ S_inv
        self._x = self._x + K @ innovation
        I_KH = np.eye(self._n) - K @ H
        self._P = I_KH @ P @ I_KH.T + K @ R @ K.T
        self._normalise()
        return nis

    def _zero_rate_update(self, omega: np.ndarray) -> None:
        """Model 4c at rest: the true rate is zero, so the gyro sample measures the bias."""
        H = np.zeros((3, self._n))
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
        J = np.eye(self._n)
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
        s = self.settings
        acc_ok = self._enabled["acc"] and self._last_acc is not None
        mag_ok = (self._enabled["mag"] and self._last_mag is not None
                  and t - self._last_mag_t <= 0.1)
        if acc_ok and mag_ok and (np.linalg.norm(np.cross(self._last_mag, self._last_acc))
                                  <= 1e-6 * np.linalg.norm(self._last_mag)
                                  * np.linalg.norm(self._last_acc)):
            mag_ok = False   # a field along gravity has no heading: tilt now, heading later
        if acc_ok and mag_ok:
            q = acc_mag_quaternion(self._last_acc, self._last_mag)
            self._heading_from_mag = True
        elif acc_ok:
            q = tilt_quaternion(self._last_acc)
        elif mag_ok:
            # Magnetometer alone: assume level, heading from the horizontal field.
            m = self._last_mag
            q = quat.from_axis_angle([0, 0, 1], math.atan2(m[0], m[1]))
            self._heading_from_mag = True
        else:
            q = quat.IDENTITY.copy()
        self._x[:4] = quat.normalize(q)
        P = np.zeros((self._n, self._n))
        Sq = quat.S_bar(self._x[:4])
        P[:4, :4] = 0.25 * s.initial_attitude_std ** 2 * (Sq @ Sq.T)
        if not (acc_ok and mag_ok):
            # Heading (or everything) unknown until a magnetometer reading arrives.
            P[:4, :4] += 0.25 * (Sq @ Sq.T)
        if self._n == 7:
            P[4:, 4:] = np.eye(3) * s.initial_gyro_bias_std ** 2
        self._P = P
        self._initialised = True
        if self._heading_from_mag and self._m0 is None and self._last_mag is not None:
            self._set_m0_from(self._last_mag)

    def _take_heading_from_mag(self, y: np.ndarray) -> None:
        """The first magnetometer reading after a tilt-only start sets the heading."""
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
        self._heading_from_mag = True
        if self._m0 is None:
            self._set_m0_from(y)

    def _heading_error(self, m_w: np.ndarray) -> tuple[float, np.ndarray]:
        """Angle psi [rad] from the reference field's horizontal direction (north unless the
        world was turned by align_heading) to the reading's, counter-clockwise seen from above,
        and d psi / d (m_E, m_N)."""
        ref = self._m0 if self._m0 is not None else np.array([0.0, 1.0, 0.0])
        rx, ry = float(ref[0]), float(ref[1])
        cross = rx * m_w[1] - ry * m_w[0]
        dot = rx * m_w[0] + ry * m_w[1]
        psi = math.atan2(cross, dot)
        # d atan2(c, d) = (d dc - c dd) / (c^2 + d^2); dc/dm = (-ry, rx), dd/dm = (rx, ry)
        denom = cross * cross + dot * dot
        grad = (dot * np.array([-ry, rx]) - cross * np.array([rx, ry])) / denom
        return psi, grad

    def _set_m0_from(self, y: np.ndarray) -> None:
        """m0 = (0, sqrt(mx^2 + my^2), mz) of the reading expressed in the (level) world frame."""
        m_w = quat.to_matrix(self._x[:4]) @ y
        self._m0 = np.array([0.0, math.hypot(m_w[0], m_w[1]), m_w[2]])
        self._mag_strength = float(np.linalg.norm(self._m0))
        self.status.mag_expected = self._mag_strength

    def _relearn_field(self, y: np.ndarray) -> None:
        self._mag_strength = float(np.linalg.norm(y))
        if self._m0 is not None:
            m_w = quat.to_matrix(self._x[:4]) @ y
            self._m0 = np.array([0.0, math.hypot(m_w[0], m_w[1]), m_w[2]])
        self._mag_rejected_since = math.nan

    def _dip_deg(self, y: np.ndarray) -> float:
        """Angle between up and the field [deg]: up from the estimate, or from the latest
        accelerometer reading (NaN when there is none or it was disturbed)."""
        if self.settings.mag_dip_from_estimate:
            up = float(quat.to_matrix(self._x[:4])[2] @ y)
            c = up / (np.linalg.norm(y) + 1e-300)
            return math.degrees(math.acos(max(-1.0, min(1.0, c))))
        a = self._last_acc
        if a is None or self.status.acc_rejected:
            return math.nan
        c = float(a @ y) / (np.linalg.norm(a) * np.linalg.norm(y) + 1e-300)
        return math.degrees(math.acos(max(-1.0, min(1.0, c))))

    def _reference_dip_deg(self) -> float:
        m0 = self._m0
        if m0 is None:
            return math.nan
        return math.degrees(math.acos(m0[2] / (np.linalg.norm(m0) + 1e-300)))

    # ---------------------------------------------------------------------------------------
    # rest detection
    def _detect_rest_gyr(self, t: float, omega: np.ndarray) -> None:
        bias = self._x[4:7] if self._n == 7 else np.asarray(self.settings.gyr_bias, float)
        if float(np.linalg.norm(omega - bias)) > self.settings.rest_gyr_threshold:
            self._last_motion_t = t
        self._update_rest(t)

    def _detect_rest_acc(self, t: float, y: np.ndarray) -> None:
        if self._acc_lowpass is None:
            self._acc_lowpass = y.copy()
        self._acc_lowpass = 0.9 * self._acc_lowpass + 0.1 * y
        if float(np.linalg.norm(y - self._acc_lowpass)) > self.settings.rest_acc_threshold:
            self._last_motion_t = t
        self._update_rest(t)

    def _update_rest(self, t: float) -> None:
        if not (self._enabled["gyr"] or self._enabled["acc"]):
            self.status.at_rest = False
            return
        if self._last_motion_t == -math.inf:
            self._last_motion_t = t   # the first sample starts the clock
        self.status.at_rest = t - self._last_motion_t >= self.settings.rest_min_duration
