"""The readable reference EKF's time update: moving the state to a sample's time.

A mixin of :class:`ekf.reference.OrientationEKF` (same state, same settings): with a recent
gyroscope sample, eq. (6) q_k = F(w) q_{k-1} + G(q) v with F = I + T/2 S(w) or, with
``exact_discretisation``, F = exp(T/2 S(w)), and P_k = A P A^T + Q (the bias columns with
model 4c); without one, q stays and P grows by a random walk (task 12). It also turns the
accelerometer low-pass carried along with the phone and the hard-iron fit's pair by the same
turn. Compiled twin: ``ekf.fast.time_update``.
"""

from __future__ import annotations

import math

import numpy as np

import ekf.quaternion as quat


class TimeUpdate:
    """The time update of OrientationEKF."""

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
