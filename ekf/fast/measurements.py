"""Compiled measurement updates: the accelerometer (task 6 with the task-8 norm gate, or its
gyro-carried low-pass), and the magnetometer (task 9 behind the task-11 strength gate and the
dip, settling and NIS gates; the full update or the heading-only one of footnote 2). The field
reference m0 and its re-learning are in ``ekf.fast.field``, the online hard-iron fit in
``ekf.fast.hard_iron``. Gate decisions are recorded as the reference records them: flags, and
which gate fired (``ekf.outputs``).
"""

from __future__ import annotations

import math

from ekf.fast._jit import CACHE_KEY, check_cache, jit
from ekf.fast.algebra import _measurement_update_q, _normalise, _to_matrix
from ekf.fast.field import (_dip_deg, _finish_reference, _learn_reference, _reference_dip_deg,
                            _track_new_field)
from ekf.fast.layout import C, S
from ekf.outputs import (ACC_NIS_GATE, ACC_NORM_GATE, MAG_DIP_GATE, MAG_NIS_GATE, MAG_SETTLING,
                         MAG_STRENGTH_GATE, NOT_REJECTED)

_INF = math.inf
_NAN = math.nan


@jit
def _shaking(s, c, t, y0, y1, y2):
    """reference ``_shaking``: the low-pass d² of (‖y‖ - g)² (acc_noise_adapt)."""
    d = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2) - c[C.g]
    alpha = 1.0
    if math.isfinite(s[S.acc_dev_t]):
        dt = t - s[S.acc_dev_t]
        alpha = dt / (c[C.acc_lowpass_s] + dt)
    s[S.acc_dev_sq] += alpha * (d * d - s[S.acc_dev_sq])
    s[S.acc_dev_t] = t


@jit
def _acc_update(s, c, y0, y1, y2, norm_gate, noise_scale=1.0):
    """reference ``_acc_update``: y_a = Q(q)^T g0 with the norm gate (task 8) and NIS gate;
    y is the reading, or its carried low-pass (then without the norm gate)."""
    norm = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    g = c[C.g]
    s[S.acc_norm] = norm
    s[S.g] = g
    s[S.acc_gate] = c[C.acc_gate]
    if abs(norm - g) > norm_gate:
        s[S.acc_rejected] = 1.0
        s[S.used_acc] = 0.0
        s[S.acc_rejected_by] = ACC_NORM_GATE
        return
    q0 = s[S.x]
    q1 = s[S.x + 1]
    q2 = s[S.x + 2]
    q3 = s[S.x + 3]
    # y_hat = g * (third row of Q); H[:, i] = g * (third row of dQ/dq_i)
    yh0 = g * (2 * (q1 * q3 - q0 * q2))
    yh1 = g * (2 * (q2 * q3 + q0 * q1))
    yh2 = g * (2 * (q0 * q0 + q3 * q3) - 1)
    h = (g * (2 * -q2), g * (2 * q3), g * (2 * -q0), g * (2 * q1),
         g * (2 * q1), g * (2 * q0), g * (2 * q3), g * (2 * q2),
         g * (2 * (2 * q0)), 0.0, 0.0, g * (2 * (2 * q3)))
    gate = c[C.acc_nis_gate]
    after = c[C.acc_tilt_only_after_s]   # reference ``_magnetometer_silent``
    silent = after < _INF and not s[S.t] - s[S.mag_updated_t] < after
    nis = _measurement_update_q(s, c, h, y0 - yh0, y1 - yh1, y2 - yh2, C.acc_noise_cov, gate,
                                noise_scale, silent)
    s[S.acc_nis] = nis
    accepted = nis <= gate
    s[S.acc_rejected] = 0.0 if accepted else 1.0
    s[S.used_acc] = 1.0 if accepted else 0.0
    s[S.acc_rejected_by] = NOT_REJECTED if accepted else ACC_NIS_GATE


@jit
def _acc_lowpass_update(s, c, t, v0, v1, v2, tau):
    """reference ``_acc_lowpass_update``: every reading is blended into the carried low-pass
    (first order, time constant tau: accelerations cancel in the average, so none is
    dropped); at most every update_period_s the carried vector is the measurement. The
    norm gate only flags a disturbed reading (acc_rejected) for the user."""
    norm = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    _shaking(s, c, t, v0, v1, v2)
    A = S.acc_carried
    if s[S.acc_carried_valid] == 0.0:
        s[A] = v0
        s[A + 1] = v1
        s[A + 2] = v2
        s[S.acc_carried_valid] = 1.0
    else:
        dt = t - s[S.acc_carried_t]
        alpha = dt / (tau + dt)
        s[A] += alpha * (v0 - s[A])
        s[A + 1] += alpha * (v1 - s[A + 1])
        s[A + 2] += alpha * (v2 - s[A + 2])
    s[S.acc_carried_t] = t
    used = 1.0
    if t - s[S.acc_updated_t] >= c[C.update_period_s]:
        s[S.acc_updated_t] = t
        scale = 1.0 + c[C.acc_noise_adapt] * s[S.acc_dev_sq] / (c[C.g] * c[C.g])
        _acc_update(s, c, s[A], s[A + 1], s[A + 2], _INF, scale)
        used = s[S.used_acc]   # the NIS gate may still refuse the averaged vector
    s[S.acc_norm] = norm
    s[S.acc_gate] = c[C.acc_gate]
    rejected = abs(norm - c[C.g]) > c[C.acc_gate]
    s[S.acc_rejected] = 1.0 if rejected else 0.0
    s[S.acc_rejected_by] = ACC_NORM_GATE if rejected else NOT_REJECTED
    s[S.used_acc] = used


@jit
def _heading_error(s, m0, m1):
    """reference ``_heading_error``: psi [rad] and d psi / d (m_E, m_N)."""
    if s[S.m0_valid] != 0.0:
        rx = s[S.m0]
        ry = s[S.m0 + 1]
    else:
        rx = 0.0
        ry = 1.0
    cross = rx * m1 - ry * m0
    dot = rx * m0 + ry * m1
    psi = math.atan2(cross, dot)
    denom = cross * cross + dot * dot
    return psi, (dot * -ry - cross * rx) / denom, (dot * rx - cross * ry) / denom


@jit
def _mag_heading_update_n(s, c, y0, y1, y2, n, gate, noise_scale, gain_cap):
    """reference ``_mag_heading_update``: heading pseudo-measurement, gain projected on a turn
    about world up, at most `gain_cap` of the innovation corrected (mag_return_s). Returns the
    NIS (NaN when the field is vertical: no update)."""
    q0 = s[S.x]
    q1 = s[S.x + 1]
    q2 = s[S.x + 2]
    q3 = s[S.x + 3]
    Q = _to_matrix(q0, q1, q2, q3)
    mw0 = Q[0] * y0 + Q[1] * y1 + Q[2] * y2
    mw1 = Q[3] * y0 + Q[4] * y1 + Q[5] * y2
    horizontal_sq = mw0 ** 2 + mw1 ** 2
    if horizontal_sq < 1e-6:
        return _NAN
    psi, d0, d1 = _heading_error(s, mw0, mw1)
    # rows 0 and 1 of dQ/dq_i @ y
    h0 = (d0 * (4 * q0 * y0 - 2 * q3 * y1 + 2 * q2 * y2)
          + d1 * (2 * q3 * y0 + 4 * q0 * y1 - 2 * q1 * y2))
    h1 = d0 * (4 * q1 * y0 + 2 * q2 * y1 + 2 * q3 * y2) + d1 * (2 * q2 * y0 - 2 * q0 * y2)
    h2 = d0 * (2 * q1 * y1 + 2 * q0 * y2) + d1 * (2 * q1 * y0 + 4 * q2 * y1 + 2 * q3 * y2)
    h3 = d0 * (-2 * q0 * y1 + 2 * q1 * y2) + d1 * (2 * q0 * y0 + 2 * q2 * y2)
    R = C.mag_noise_cov
    r = (c[R] * noise_scale + c[R + 4] * noise_scale + c[R + 8] * noise_scale) / 3.0 \
        / horizontal_sq
    P = S.P
    B = S.work_pht
    for i in range(n):
        s[B + i] = (s[P + 7 * i] * h0 + s[P + 7 * i + 1] * h1 + s[P + 7 * i + 2] * h2
                    + s[P + 7 * i + 3] * h3)
    HPH = h0 * s[B] + h1 * s[B + 1] + h2 * s[B + 2] + h3 * s[B + 3]
    S_psi = HPH + r
    nis = psi * psi / S_psi
    if nis > gate:
        return nis
    # mag_bias_innovation_limit: the bias learns from at most limit·√S of psi
    limit = c[C.mag_bias_innovation_limit] * math.sqrt(S_psi)
    bias_weight = limit / abs(psi) if abs(psi) > limit else 1.0
    if HPH * (1.0 - gain_cap) > gain_cap * r:
        # mag_return_s: a larger r, so that at most gain_cap of psi is corrected now
        if gain_cap <= 0.0:
            return nis
        r = HPH * (1.0 - gain_cap) / gain_cap
        S_psi = HPH + r
    K = S.work_gain
    inv_S = 1.0 / S_psi
    for i in range(n):
        s[K + i] = s[B + i] * inv_S
    # u = direction of (0,0,0,1) ⊗ q in q-space: a turn about world up
    u0 = 0.5 * -q3
    u1 = 0.5 * -q2
    u2 = 0.5 * q1
    u3 = 0.5 * q0
    inv_nu = 1.0 / math.sqrt(u0 * u0 + u1 * u1 + u2 * u2 + u3 * u3)
    u0 *= inv_nu
    u1 *= inv_nu
    u2 *= inv_nu
    u3 *= inv_nu
    uk = u0 * s[K] + u1 * s[K + 1] + u2 * s[K + 2] + u3 * s[K + 3]
    s[K] = u0 * uk
    s[K + 1] = u1 * uk
    s[K + 2] = u2 * uk
    s[K + 3] = u3 * uk
    for i in range(4, n):
        s[K + i] *= bias_weight
    innovation = -psi
    for i in range(n):
        s[S.x + i] += s[K + i] * innovation
    for i in range(n):
        ki = s[K + i]
        bi = s[B + i]
        for j in range(i, n):
            v = s[P + 7 * i + j] - ki * s[B + j] - bi * s[K + j] + S_psi * ki * s[K + j]
            s[P + 7 * i + j] = v
            s[P + 7 * j + i] = v
    _normalise(s)
    return nis


@jit
def _mag_heading_update(s, c, y0, y1, y2, gate, noise_scale, gain_cap):
    # n = 4 or 7 as a compile-time constant: fixed loops are unrolled.
    if int(s[S.n]) == 7:
        return _mag_heading_update_n(s, c, y0, y1, y2, 7, gate, noise_scale, gain_cap)
    return _mag_heading_update_n(s, c, y0, y1, y2, 4, gate, noise_scale, gain_cap)


@jit
def _mag_gates(s, c, y0, y1, y2):
    """reference ``_mag_gates``: the strength gate |‖y‖ - L_k| with the AR(1) estimate L_k
    (task 11), then the dip gate. Returns ‖y‖, the dip and which gate rejected the reading."""
    norm = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    s[S.mag_norm] = norm
    s[S.mag_gate] = c[C.mag_gate]
    if math.isnan(s[S.mag_strength]):
        s[S.mag_strength] = norm
    L_prev = s[S.mag_strength]
    rejected_by = MAG_STRENGTH_GATE if abs(norm - L_prev) > c[C.mag_gate] else NOT_REJECTED
    dip = _dip_deg(s, c, y0, y1, y2)
    s[S.mag_dip_deg] = dip
    dip_gate = c[C.mag_dip_gate_deg]
    if (rejected_by == NOT_REJECTED and math.isfinite(dip_gate) and math.isfinite(dip)
            and abs(dip - _reference_dip_deg(s)) > dip_gate):
        rejected_by = MAG_DIP_GATE
    if c[C.mag_strength_always] != 0.0 or rejected_by == NOT_REJECTED:
        alpha = c[C.mag_alpha]
        s[S.mag_strength] = (1 - alpha) * L_prev + alpha * norm
    s[S.mag_expected] = s[S.mag_strength]
    return norm, dip, rejected_by


@jit
def _uneven_field(s, c, t, norm):
    """reference ``_uneven_field``: d² <- low-pass of (‖y‖ - L_k)² (the deviation clipped at
    mag_noise_adapt_clip gates); returns 1 + k d² / L_k²."""
    if (c[C.mag_noise_adapt] == 0.0 or not math.isfinite(s[S.mag_strength])
            or s[S.used_gyr] == 0.0):
        return 1.0
    d = norm - s[S.mag_strength]
    clip = c[C.mag_noise_adapt_clip] * c[C.mag_gate]
    if abs(d) > clip:
        d = math.copysign(clip, d)
    alpha = 1.0
    if math.isfinite(s[S.mag_dev_t]):
        dt = t - s[S.mag_dev_t]
        alpha = dt / (c[C.mag_return_s] + dt) if c[C.mag_return_s] + dt > 0.0 else 1.0
    s[S.mag_dev_sq] += alpha * (d * d - s[S.mag_dev_sq])
    s[S.mag_dev_t] = t
    return 1.0 + c[C.mag_noise_adapt] * s[S.mag_dev_sq] / (s[S.mag_strength] ** 2)


@jit
def _heading_gain_cap(s, c, dt):
    """reference ``_heading_gain_cap``: at most dt / (dt + mag_return_s) of a heading
    innovation, while the gyroscope drives the filter (1: no cap)."""
    tau = c[C.mag_return_s]
    if tau > 0.0 and math.isfinite(dt) and s[S.used_gyr] != 0.0:
        return dt / (dt + tau)
    return 1.0


@jit
def _count_disturbance(s, c, t, bound):
    """reference ``_count_disturbance``: a rejected reading adds the time since the previous
    one when that was rejected too (while the count is within the bound); returns the count."""
    if not math.isnan(s[S.mag_disturbed_t]) and not s[S.mag_disturbed_time] > bound:
        s[S.mag_disturbed_time] += t - s[S.mag_disturbed_t]
    s[S.mag_disturbed_t] = t
    return s[S.mag_disturbed_time]


@jit
def _count_passing(s, c, t):
    """reference ``_count_passing``: a reading that passes counts towards confirming the
    learned field (``_count_confirmed``) and ends the disturbance."""
    if s[S.mag_reference_count] == 0.0 and t - s[S.mag_passed_t] <= c[C.max_dt]:
        s[S.mag_confirmed_time] += t - s[S.mag_passed_t]   # reference ``_count_confirmed``
    s[S.mag_disturbed_time] = 0.0
    s[S.mag_disturbed_t] = _NAN
    s[S.mag_passed_t] = t


@jit
def _mag_update(s, c, y0, y1, y2, t):
    """reference ``_mag_update``: the expected field learned first (mag_reference_s), the gates
    (``_mag_gates``), settling, the bound on a disturbance's length, then the update (heading
    only, or the full one of task 9) behind the NIS gate."""
    if t < s[S.mag_reference_until]:
        norm = _learn_reference(s, c, y0, y1, y2, t)
        dip = _NAN
        rejected_by = NOT_REJECTED
    else:
        if s[S.mag_reference_count] > 0.0:
            _finish_reference(s)
        norm, dip, rejected_by = _mag_gates(s, c, y0, y1, y2)
    # after a rejection, readings must pass for mag_settle_s before they are used again
    if rejected_by != NOT_REJECTED:
        s[S.mag_passing_since] = _NAN
    elif math.isnan(s[S.mag_passing_since]):
        s[S.mag_passing_since] = t
    if rejected_by == NOT_REJECTED and t - s[S.mag_passing_since] < c[C.mag_settle_s]:
        rejected_by = MAG_SETTLING
    s[S.mag_rejected_by] = rejected_by
    noise_scale = _uneven_field(s, c, t, norm)
    if rejected_by != NOT_REJECTED:
        if c[C.mag_strength_accepted] != 0.0:
            _track_new_field(s, c, y0, y1, y2, t, norm, dip)
        s[S.mag_rejected] = 1.0
        s[S.used_mag] = 0.0
        # with the gyroscope out until readings pass or agree as a new field; without it at
        # most mag_max_reject_no_gyro_s, then used, trusted less
        bound = math.inf if s[S.used_gyr] != 0.0 else c[C.mag_max_reject_no_gyro_s]
        if not _count_disturbance(s, c, t, bound) > bound:
            return
        noise_scale *= c[C.mag_reject_noise_scale]
    else:
        s[S.mag_rejected_since] = _NAN
        _count_passing(s, c, t)
        s[S.mag_rejected] = 0.0
    if t - s[S.mag_updated_t] < c[C.update_period_s]:
        s[S.used_mag] = 0.0
        return
    gain_cap = _heading_gain_cap(s, c, t - s[S.mag_updated_t])
    s[S.mag_updated_t] = t
    if c[C.mag_heading_only] != 0.0:
        nis = _mag_heading_update(s, c, y0, y1, y2, c[C.mag_nis_gate], noise_scale, gain_cap)
    else:
        q0, q1, q2, q3 = s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3]
        m0, m1, m2 = s[S.m0], s[S.m0 + 1], s[S.m0 + 2]
        Q = _to_matrix(q0, q1, q2, q3)
        yh0 = Q[0] * m0 + Q[3] * m1 + Q[6] * m2
        yh1 = Q[1] * m0 + Q[4] * m1 + Q[7] * m2
        yh2 = Q[2] * m0 + Q[5] * m1 + Q[8] * m2
        # H[r, i] = (dQ_i^T m0)_r = sum_k dQ_i[k, r] m0_k
        h = (4 * q0 * m0 + 2 * q3 * m1 - 2 * q2 * m2,
             4 * q1 * m0 + 2 * q2 * m1 + 2 * q3 * m2,
             2 * q1 * m1 - 2 * q0 * m2,
             2 * q0 * m1 + 2 * q1 * m2,
             -2 * q3 * m0 + 4 * q0 * m1 + 2 * q1 * m2,
             2 * q2 * m0 + 2 * q0 * m2,
             2 * q1 * m0 + 4 * q2 * m1 + 2 * q3 * m2,
             -2 * q0 * m0 + 2 * q2 * m2,
             2 * q2 * m0 - 2 * q1 * m1 + 4 * q0 * m2,
             2 * q3 * m0 - 2 * q0 * m1,
             2 * q0 * m0 + 2 * q3 * m1,
             2 * q1 * m0 + 2 * q2 * m1 + 4 * q3 * m2)
        nis = _measurement_update_q(s, c, h, y0 - yh0, y1 - yh1, y2 - yh2, C.mag_noise_cov,
                                    c[C.mag_nis_gate], noise_scale)
    s[S.mag_nis] = nis
    if nis > c[C.mag_nis_gate]:
        # an innovation the filter cannot believe: rejected, and readings must settle again
        s[S.mag_passing_since] = _NAN
        s[S.mag_rejected_by] = MAG_NIS_GATE
        s[S.mag_rejected] = 1.0
        s[S.used_mag] = 0.0
        return
    s[S.used_mag] = 1.0


@jit
def _compiled_cache_key():
    return CACHE_KEY


check_cache(_compiled_cache_key, globals())
