"""The readable reference EKF's measurement updates: accelerometer, magnetometer, zero rate.

A mixin of :class:`ekf.reference.OrientationEKF` (same state, same settings): the
accelerometer update with its norm gate (tasks 6 and 8), its carried low-pass, the shaking
estimate and the tilt-only projection; the magnetometer update behind its gates (tasks 9 and
11), the settling and disturbance bounds, the uneven-field noise and the heading-only update
(footnote 2); the zero-rate update at rest (model 4c); the Joseph-form update they share and
the normalisation q <- q / ‖q‖ that follows every step (the time update's too). The field
reference and its gates are in ``ekf.reference_field``. Compiled twins: ``ekf.fast.measurements``
and ``ekf.fast.algebra``.
"""

from __future__ import annotations

import math

import numpy as np

import ekf.quaternion as quat
from ekf.outputs import (ACC_NIS_GATE, ACC_NORM_GATE, MAG_NIS_GATE, MAG_SETTLING,
                         NOT_REJECTED)


class MeasurementUpdates:
    """The measurement updates of OrientationEKF."""

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
