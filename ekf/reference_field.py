"""The readable reference EKF, continued: the magnetic field reference it keeps.

A mixin of :class:`ekf.reference.OrientationEKF` (same state, same settings; split off only to
keep each file readable): the reference field m0 and its strength L_k (task 11), the
strength and dip gates, learning the expected field over the first readings
(``mag_reference_s``), re-learning a changed field (``mag_relearn_s``, in the world frame with
``mag_relearn_world``) and the online hard-iron fit (``mag_hard_iron_tau_s``). Compiled twin:
``ekf.fast.measurements``.
"""

from __future__ import annotations

import math

import numpy as np

import ekf.quaternion as quat
from ekf.outputs import MAG_DIP_GATE, MAG_STRENGTH_GATE, NOT_REJECTED
from ekf.state import reference_dip_deg

# The online hard-iron fit (mag_hard_iron_tau_s): a pair closes once the phone turned this far
# [rad] (a smaller turn says little about the offset), or is dropped after this long [s] (the
# gyro's relative rotation is trusted over short spans); residuals beyond this [uT] weigh less
# (w = min(1, this / |r|): a field changing in the world meanwhile).
HARD_IRON_PAIR_ANGLE = math.radians(20.0)
HARD_IRON_PAIR_MAX_S = 2.0
HARD_IRON_RESIDUAL = 5.0
# HARD_IRON_RESET_COUNT pairs in a row with residuals beyond HARD_IRON_RESET_RESIDUAL [uT]: the
# offset itself changed (a magnet was put on the phone): the fit starts again from the new pairs.
HARD_IRON_RESET_RESIDUAL = 20.0
HARD_IRON_RESET_COUNT = 5
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


def _elevation_deg(v: np.ndarray) -> float:
    """Angle of a world-frame vector above the horizontal [deg] (its dip, with the sign of up)."""
    return math.degrees(math.atan2(float(v[2]), math.hypot(float(v[0]), float(v[1]))))


class MagneticField:
    """The magnetometer's reference field and its offset, for OrientationEKF."""

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
        |e - D b|); b = (M + mag_hard_iron_prior I)^-1 v. Residuals that stay large
        (HARD_IRON_RESET_*) mean a new offset: the sums start again."""
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
        st.mag_offset_outliers = st.mag_offset_outliers + 1 if (
            residual > HARD_IRON_RESET_RESIDUAL) else 0.0
        if st.mag_acquiring:
            w, st.mag_offset_outliers = 1.0, 0.0   # large residuals: the offset is far, not new
        if st.mag_offset_outliers >= HARD_IRON_RESET_COUNT:
            forget, w, st.mag_offset_outliers = 0.0, 1.0, 0.0   # a new offset: start again
        st.mag_offset_info[:] = forget * st.mag_offset_info + w * (D.T @ D)
        st.mag_offset_rhs[:] = forget * st.mag_offset_rhs + w * (D.T @ e)
        st.mag_offset_t = t
        prior = ACQUIRING_PRIOR if st.mag_acquiring else s.mag_hard_iron_prior
        st.mag_offset_fit[:] = np.linalg.solve(st.mag_offset_info + prior * np.eye(3),
                                               st.mag_offset_rhs + prior * st.mag_offset_prior)
        self._acquisition_progress(y)
        self._open_pair(t, y)

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
