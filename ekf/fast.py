"""The reference EKF compiled with numba: same estimates as :mod:`ekf.reference`, much faster.

All filter state lives in ONE float64 array (``_S_*`` offsets below) and all settings in ONE
float64 array (``_C_*``), so a sample costs one compiled call that mutates the state in place,
a snapshot is one array copy, and :meth:`FastEKF.run_batch` is a single compiled loop.

The arithmetic is the reference's; only the order of floating-point operations differs where
structure is exploited exactly:

* P is symmetric: only the upper triangle is computed, then mirrored;
* zero blocks are skipped: A = [[F, -G], [0, I]], H = [H_q 0] (acc, mag) or [0 I] (zero rate),
  J = blockdiag((I - u u^T)/|q|, I), so J P J^T = (P - u w^T - w u^T + (u.w) u u^T)/|q|^2
  with w = P_qq u (a rank-2 update instead of two 7x7 products);
* the Joseph form (I - K H) P (I - K H)^T + K R K^T = P - K B^T - B K^T + K S K^T, with
  B = P H^T and S = H P H^T + R, for any gain K: the projected heading-only gain uses this;
  for the optimal gain K = B S^-1 (K S = B) it is P - K B^T, which the 3-vector updates use;
* S^-1 (3x3) by the adjugate; divisions by |q| and S replaced by one reciprocal.

Estimates agree with the reference to ~1e-14 on the tests' data (tested to 1e-9).

Which compiled function mirrors which reference method (``OrientationEKF.<name>``):

=============================  ====================================================
fast.py                        reference.py
=============================  ====================================================
``_advance``                   ``_advance``
``_time_update_gyro``          ``_time_update_gyro`` (eq. 6, Euler or exact F)
``_time_update_random_walk``   ``_time_update_random_walk``
``_acc_update``                ``_acc_update``
``_mag_update``                ``_mag_update``
``_mag_heading_update``        ``_mag_heading_update``
``_joseph_update``             ``_update`` (B = P H^T and S given by the caller)
``_zero_rate_update``          ``_zero_rate_update``
``_normalise``                 ``_normalise``
``_initialise``                ``_initialise``
``_take_heading_from_mag``     ``_take_heading_from_mag``
``_heading_error``             ``_heading_error``
``_set_m0_from``               ``_set_m0_from``
``_relearn_field``             ``_relearn_field``
``_dip_deg``                   ``_dip_deg``
``_reference_dip_deg``         ``_reference_dip_deg``
``_detect_rest_gyr/_acc``      ``_detect_rest_gyr`` / ``_detect_rest_acc``
``_update_rest``               ``_update_rest``
``_tilt_quaternion``           ``ekf.reference.tilt_quaternion``
``_acc_mag_quaternion``        ``ekf.reference.acc_mag_quaternion``
``_update_gyr/_acc/_mag``      ``update_gyr`` / ``update_acc`` / ``update_mag``
``_step``, ``_run_batch``      ``step``; ``filter_batch``'s row loop
=============================  ====================================================

``reset``, ``set_enabled``, ``set_settings`` and ``align_heading`` are not per-sample and run in
Python on the packed array, line by line as in the reference.
"""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from ekf import quaternion as quat
from ekf.reference import SENSORS, Status
from ekf.settings import PRESETS, EKFSettings

# ---- packed state layout (offsets into the float64 state array) ----------------------------
_S_X = 0                    # x: q (4) then gyro bias (3) when n = 7
_S_P = 7                    # P, 7x7 row-major (only the leading n x n block is used)
_S_N = 56                   # n: 4 or 7
_S_T = 57                   # time of the latest sample [s]; NaN = none yet
_S_INITIALISED = 58
_S_HEADING_FROM_MAG = 59
_S_OMEGA = 60               # latest gyro sample (3) [rad/s], bias not removed
_S_OMEGA_VALID = 63
_S_OMEGA_T = 64
_S_LAST_ACC = 65            # (3) [m/s^2]
_S_LAST_ACC_VALID = 68
_S_LAST_ACC_T = 69
_S_LAST_MAG = 70            # (3) [uT]
_S_LAST_MAG_VALID = 73
_S_LAST_MAG_T = 74
_S_M0 = 75                  # Earth field in ENU (3) [uT]
_S_M0_VALID = 78
_S_MAG_STRENGTH = 79        # L_k [uT]; NaN = unknown
_S_MAG_REJECTED_SINCE = 80  # NaN = not rejecting
_S_ACC_LOWPASS = 81         # (3)
_S_ACC_LOWPASS_VALID = 84
_S_LAST_MOTION_T = 85
_S_EN_GYR = 86
_S_EN_ACC = 87
_S_EN_MAG = 88
_S_STATUS = 89              # the Status fields in declaration order (15)
_ST_ACC_REJECTED = 89
_ST_MAG_REJECTED = 90
_ST_AT_REST = 91
_ST_USED_GYR = 92
_ST_USED_ACC = 93
_ST_USED_MAG = 94
_ST_ACC_NORM = 95
_ST_G = 96
_ST_ACC_GATE = 97
_ST_ACC_NIS = 98
_ST_MAG_NORM = 99
_ST_MAG_EXPECTED = 100
_ST_MAG_GATE = 101
_ST_MAG_NIS = 102
_ST_MAG_DIP_DEG = 103
_S_ACC_CARRIED = 104        # (3) low-passed specific force, carried along by the gyro [m/s^2]
_S_ACC_CARRIED_VALID = 107
_S_ACC_CARRIED_T = 108      # time of the latest blended accelerometer sample [s]
_S_MAG_PASSING_SINCE = 109  # readings have passed the gates since this time [s]; NaN = rejecting
_S_ACC_UPDATED_T = 110      # time of the latest accelerometer update [s]
_S_MAG_UPDATED_T = 111      # time of the latest magnetometer update [s]
_S_MAG_CANDIDATE_NORM = 112 # strength of the field seen while rejecting [uT]
_S_MAG_CANDIDATE_DIP = 113  # its dip [deg]
_S_REST_UPDATED_T = 114     # time of the latest zero-rate update [s]
_S_WORK = 116               # scratch for the compiled functions (not state)
_W_A = _S_WORK              # 21: B = P H^T (7x3, or 7 for the heading update)
_W_B = _S_WORK + 32         # 28: A P rows (4x7), or K (7x3 or 7)
_W_D = _S_WORK + 88         # 9: S (3x3)
_W_E = _S_WORK + 100        # 9: S^-1 (3x3)
_STATE_SIZE = _S_WORK + 112

_STATUS_FIELDS = tuple(f.name for f in fields(Status))
assert _STATUS_FIELDS == (
    "acc_rejected", "mag_rejected", "at_rest", "used_gyr", "used_acc", "used_mag", "acc_norm",
    "g", "acc_gate", "acc_nis", "mag_norm", "mag_expected", "mag_gate", "mag_nis", "mag_dip_deg",
), "ekf.reference.Status changed: update the packed status layout in ekf.fast"
_STATUS_BOOLS = 6           # the first six status fields are flags

# ---- packed settings layout ----------------------------------------------------------------
_C_G = 0
_C_GYR_BIAS = 1             # (3)
_C_GYR_COV = 4              # R_w (3x3)
_C_ACC_COV = 13             # R_a (3x3)
_C_MAG_COV = 22             # R_m (3x3)
_C_NO_GYRO_RW = 31
_C_INITIAL_ATTITUDE_STD = 32
_C_ACC_GATE = 33
_C_MAG_GATE = 34
_C_MAG_ALPHA = 35
_C_MAG_ALWAYS = 36          # mag_strength_update == "always"
_C_MAG_ACCEPTED = 37        # mag_strength_update == "accepted"
_C_MAG_RELEARN_S = 38
_C_MAG_DIP_GATE_DEG = 39
_C_ACC_NIS_GATE = 40
_C_EXACT = 41
_C_HEADING_ONLY = 42
_C_ESTIMATE_BIAS = 43
_C_BIAS_RW = 44
_C_INITIAL_BIAS_STD = 45
_C_REST_RATE_STD = 46
_C_MAX_DT = 47
_C_GYR_HOLD_S = 48
_C_REST_GYR_THRESHOLD = 49
_C_REST_ACC_THRESHOLD = 50
_C_REST_MIN_DURATION = 51
_C_ACC_LOWPASS_S = 52
_C_MAG_SETTLE_S = 53
_C_MAG_DIP_FROM_ESTIMATE = 54
_C_GYR_SCALE_NOISE = 55
_C_UPDATE_PERIOD = 56
_C_GYR_RATE_BEFORE = 58
_C_MAG_NIS_GATE = 59
_C_GYR_COV_ISOTROPIC = 60    # R_w = r I (a shortcut for G R_w G^T)
_CFG_SIZE = 61

# sample kinds (the order of `step`)
KIND_GYR = 0
KIND_ACC = 1
KIND_MAG = 2
KIND_NONE = 3   # no sample: only move the clock (step with no sensor)

_INF = math.inf
_NAN = math.nan


def pack_settings(settings: EKFSettings) -> np.ndarray:
    """The settings as the float64 array the compiled functions read (layout ``_C_*``)."""
    s = settings
    c = np.zeros(_CFG_SIZE)
    c[_C_G] = s.g
    c[_C_GYR_BIAS:_C_GYR_BIAS + 3] = np.asarray(s.gyr_bias, float).reshape(3)
    c[_C_GYR_COV:_C_GYR_COV + 9] = np.asarray(s.gyr_noise_cov, float).reshape(9)
    c[_C_ACC_COV:_C_ACC_COV + 9] = np.asarray(s.acc_noise_cov, float).reshape(9)
    c[_C_MAG_COV:_C_MAG_COV + 9] = np.asarray(s.mag_noise_cov, float).reshape(9)
    c[_C_NO_GYRO_RW] = s.no_gyro_random_walk
    c[_C_INITIAL_ATTITUDE_STD] = s.initial_attitude_std
    c[_C_ACC_GATE] = s.acc_gate
    c[_C_MAG_GATE] = s.mag_gate
    c[_C_MAG_ALPHA] = s.mag_alpha
    c[_C_MAG_ALWAYS] = float(s.mag_strength_update == "always")
    c[_C_MAG_ACCEPTED] = float(s.mag_strength_update == "accepted")
    c[_C_MAG_RELEARN_S] = s.mag_relearn_s
    c[_C_MAG_DIP_GATE_DEG] = s.mag_dip_gate_deg
    c[_C_ACC_NIS_GATE] = s.acc_nis_gate
    c[_C_EXACT] = float(bool(s.exact_discretisation))
    c[_C_HEADING_ONLY] = float(bool(s.mag_heading_only))
    c[_C_ESTIMATE_BIAS] = float(bool(s.estimate_gyro_bias))
    c[_C_BIAS_RW] = s.gyro_bias_random_walk
    c[_C_INITIAL_BIAS_STD] = s.initial_gyro_bias_std
    c[_C_REST_RATE_STD] = s.rest_rate_noise_std
    c[_C_MAX_DT] = s.max_dt
    c[_C_GYR_HOLD_S] = s.gyr_hold_s
    c[_C_REST_GYR_THRESHOLD] = s.rest_gyr_threshold
    c[_C_REST_ACC_THRESHOLD] = s.rest_acc_threshold
    c[_C_REST_MIN_DURATION] = s.rest_min_duration
    c[_C_ACC_LOWPASS_S] = s.acc_lowpass_s
    c[_C_MAG_SETTLE_S] = s.mag_settle_s
    c[_C_GYR_SCALE_NOISE] = s.gyr_scale_noise
    c[_C_UPDATE_PERIOD] = s.update_period_s
    c[_C_GYR_RATE_BEFORE] = float(bool(s.gyr_rate_before_sample))
    c[_C_MAG_NIS_GATE] = s.mag_nis_gate
    R_w = np.asarray(s.gyr_noise_cov, float)
    c[_C_GYR_COV_ISOTROPIC] = float(np.array_equal(R_w, R_w[0, 0] * np.eye(3)))
    c[_C_MAG_DIP_FROM_ESTIMATE] = float(bool(s.mag_dip_from_estimate))
    return c


# =============================================================================================
# compiled building blocks
_jit = njit(cache=True, fastmath=False, nogil=True)
# Inlined at numba level: small helpers (no call overhead) and the n-specialised bodies, which
# their dispatchers call with n = 4 or 7 as a constant so that LLVM unrolls the fixed loops.
_jit_inline = njit(cache=True, fastmath=False, nogil=True, inline="always")


@_jit_inline
def _quat_normalize(q0, q1, q2, q3):
    """ekf.quaternion.normalize: unit, w >= 0."""
    norm = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    q0 = q0 / norm
    q1 = q1 / norm
    q2 = q2 / norm
    q3 = q3 / norm
    if q0 < 0.0:
        return -q0, -q1, -q2, -q3
    return q0, q1, q2, q3


@_jit
def _rotate_world_about_up(q0, q1, q2, q3, angle):
    """normalize(from_axis_angle(z, angle) ⊗ q)."""
    c = math.cos(angle / 2)
    sn = math.sin(angle / 2)
    return _quat_normalize(c * q0 - sn * q3, c * q1 - sn * q2, c * q2 + sn * q1, c * q3 + sn * q0)


@_jit
def _heading_of(q0, q1, q2, q3):
    """ekf.quaternion.heading_of: 2 atan2(z, w) of the normalised q."""
    w, _x, _y, z = _quat_normalize(q0, q1, q2, q3)
    return 2.0 * math.atan2(z, w)


@_jit
def _from_matrix(r00, r01, r02, r10, r11, r12, r20, r21, r22):
    """ekf.quaternion.from_matrix (Shepperd, first maximum of trace, R00, R11, R22)."""
    trace = r00 + r11 + r22
    k = 0
    best = trace
    if r00 > best:
        k = 1
        best = r00
    if r11 > best:
        k = 2
        best = r11
    if r22 > best:
        k = 3
    if k == 0:
        sv = 2.0 * math.sqrt(max(1.0 + trace, 0.0))
        q = (0.25 * sv, (r21 - r12) / sv, (r02 - r20) / sv, (r10 - r01) / sv)
    elif k == 1:
        sv = 2.0 * math.sqrt(max(1.0 + r00 - r11 - r22, 0.0))
        q = ((r21 - r12) / sv, 0.25 * sv, (r01 + r10) / sv, (r02 + r20) / sv)
    elif k == 2:
        sv = 2.0 * math.sqrt(max(1.0 - r00 + r11 - r22, 0.0))
        q = ((r02 - r20) / sv, (r01 + r10) / sv, 0.25 * sv, (r12 + r21) / sv)
    else:
        sv = 2.0 * math.sqrt(max(1.0 - r00 - r11 + r22, 0.0))
        q = ((r10 - r01) / sv, (r02 + r20) / sv, (r12 + r21) / sv, 0.25 * sv)
    return _quat_normalize(q[0], q[1], q[2], q[3])


@_jit_inline
def _to_matrix(q0, q1, q2, q3):
    """Q(q) of eq. (2a), row-major as a 9-tuple."""
    return (2 * (q0 * q0 + q1 * q1) - 1, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2),
            2 * (q1 * q2 + q0 * q3), 2 * (q0 * q0 + q2 * q2) - 1, 2 * (q2 * q3 - q0 * q1),
            2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 2 * (q0 * q0 + q3 * q3) - 1)


@_jit_inline
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@_jit
def _tilt_quaternion(a0, a1, a2):
    """ekf.reference.tilt_quaternion."""
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    u0 = a0 / na
    u1 = a1 / na
    u2 = a2 / na
    if abs(u0) < 0.9:
        n0, n1, n2 = _cross(u0, u1, u2, 1.0, 0.0, 0.0)
    else:
        n0, n1, n2 = _cross(u0, u1, u2, 0.0, 1.0, 0.0)
    nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    n0 /= nn
    n1 /= nn
    n2 /= nn
    e0, e1, e2 = _cross(n0, n1, n2, u0, u1, u2)
    q0, q1, q2, q3 = _from_matrix(e0, e1, e2, n0, n1, n2, u0, u1, u2)
    return _rotate_world_about_up(q0, q1, q2, q3, -_heading_of(q0, q1, q2, q3))


@_jit
def _acc_mag_quaternion(a0, a1, a2, m0, m1, m2):
    """ekf.reference.acc_mag_quaternion (TRIAD)."""
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    u0 = a0 / na
    u1 = a1 / na
    u2 = a2 / na
    e0, e1, e2 = _cross(m0, m1, m2, u0, u1, u2)
    ne = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    e0 /= ne
    e1 /= ne
    e2 /= ne
    n0, n1, n2 = _cross(u0, u1, u2, e0, e1, e2)
    return _from_matrix(e0, e1, e2, n0, n1, n2, u0, u1, u2)


@_jit
def _set_attitude_cov(s, scale):
    """P[:4, :4] = scale * S̄(q) S̄(q)^T (the other blocks untouched)."""
    q0 = s[0]
    q1 = s[1]
    q2 = s[2]
    q3 = s[3]
    sb = ((-q1, -q2, -q3), (q0, -q3, q2), (q3, q0, -q1), (-q2, q1, q0))
    for i in range(4):
        for j in range(i, 4):
            m = sb[i][0] * sb[j][0] + sb[i][1] * sb[j][1] + sb[i][2] * sb[j][2]
            s[_S_P + 7 * i + j] = scale * m
            s[_S_P + 7 * j + i] = scale * m


@_jit
def _add_attitude_cov(s, scale):
    """P[:4, :4] += scale * S̄(q) S̄(q)^T."""
    q0 = s[0]
    q1 = s[1]
    q2 = s[2]
    q3 = s[3]
    sb = ((-q1, -q2, -q3), (q0, -q3, q2), (q3, q0, -q1), (-q2, q1, q0))
    for i in range(4):
        for j in range(i, 4):
            m = sb[i][0] * sb[j][0] + sb[i][1] * sb[j][1] + sb[i][2] * sb[j][2]
            v = s[_S_P + 7 * i + j] + scale * m
            s[_S_P + 7 * i + j] = v
            s[_S_P + 7 * j + i] = v


@_jit_inline
def _normalise(s):
    """q <- q/|q| (w >= 0), P <- J P J^T with J = (I - u u^T)/|q| on the q block, u = q/|q|.

    J P J^T = (P - u w^T - w u^T + (u.w) u u^T)/|q|^2 with w = P_qq u; the q-bias block is
    J P_qb. The sign flip for w >= 0 multiplies J by -1 (cancels in the q block)."""
    n = int(s[_S_N])
    q0 = s[0]
    q1 = s[1]
    q2 = s[2]
    q3 = s[3]
    norm = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    inv_norm = 1.0 / norm   # one division on the critical path instead of six
    u = (q0 * inv_norm, q1 * inv_norm, q2 * inv_norm, q3 * inv_norm)
    sign = -1.0 if u[0] < 0.0 else 1.0
    for i in range(4):
        s[i] = sign * u[i]
    P = _S_P
    w0 = s[P + 0] * u[0] + s[P + 1] * u[1] + s[P + 2] * u[2] + s[P + 3] * u[3]
    w1 = s[P + 7] * u[0] + s[P + 8] * u[1] + s[P + 9] * u[2] + s[P + 10] * u[3]
    w2 = s[P + 14] * u[0] + s[P + 15] * u[1] + s[P + 16] * u[2] + s[P + 17] * u[3]
    w3 = s[P + 21] * u[0] + s[P + 22] * u[1] + s[P + 23] * u[2] + s[P + 24] * u[3]
    w = (w0, w1, w2, w3)
    a = u[0] * w0 + u[1] * w1 + u[2] * w2 + u[3] * w3
    scale = inv_norm * inv_norm
    for i in range(4):
        for j in range(i, 4):
            v = (s[P + 7 * i + j] - u[i] * w[j] - w[i] * u[j] + a * u[i] * u[j]) * scale
            s[P + 7 * i + j] = v
            s[P + 7 * j + i] = v
    if n == 7:
        f = sign * inv_norm
        for j in range(4, 7):
            z = (u[0] * s[P + j] + u[1] * s[P + 7 + j] + u[2] * s[P + 14 + j]
                 + u[3] * s[P + 21 + j])
            for i in range(4):
                v = f * (s[P + 7 * i + j] - u[i] * z)
                s[P + 7 * i + j] = v
                s[P + 7 * j + i] = v


@_jit_inline
def _flip_sign(s):
    """reference ``_flip_sign``: q <- -q (same rotation, w >= 0); P_qb changes sign."""
    for i in range(4):
        s[i] = -s[i]
    if int(s[_S_N]) == 7:
        for i in range(4):
            for j in range(4, 7):
                v = -s[_S_P + 7 * i + j]
                s[_S_P + 7 * i + j] = v
                s[_S_P + 7 * j + i] = v


@_jit_inline
def _inverse3(s, src, dst):
    """dst = src^-1 (3x3, row-major in the state's scratch) by the adjugate; returns det."""
    a = s[src + 0]
    b = s[src + 1]
    c = s[src + 2]
    d = s[src + 3]
    e = s[src + 4]
    f = s[src + 5]
    g = s[src + 6]
    h = s[src + 7]
    k = s[src + 8]
    c00 = e * k - f * h
    c01 = f * g - d * k
    c02 = d * h - e * g
    det = a * c00 + b * c01 + c * c02
    inv = 1.0 / det
    s[dst + 0] = c00 * inv
    s[dst + 1] = (c * h - b * k) * inv
    s[dst + 2] = (b * f - c * e) * inv
    s[dst + 3] = c01 * inv
    s[dst + 4] = (a * k - c * g) * inv
    s[dst + 5] = (c * d - a * f) * inv
    s[dst + 6] = c02 * inv
    s[dst + 7] = (b * g - a * h) * inv
    s[dst + 8] = (a * e - b * d) * inv
    return det


@_jit_inline
def _joseph_update_n(s, e0, e1, e2, gate, n):
    """reference ``_update`` for a 3-vector measurement, given B = P H^T (n x 3) at _W_A and
    S = H P H^T + R (3x3) at _W_D. Returns the NIS; the state is untouched when NIS > gate.

    With the optimal gain K = B S^-1 (K S = B), the Joseph form
    (I - KH) P (I - KH)^T + K R K^T = P - K B^T - B K^T + K S K^T equals P - K B^T exactly;
    that (symmetric: upper triangle, mirrored) is what is evaluated."""
    _inverse3(s, _W_D, _W_E)
    Si = _W_E
    t0 = s[Si + 0] * e0 + s[Si + 1] * e1 + s[Si + 2] * e2
    t1 = s[Si + 3] * e0 + s[Si + 4] * e1 + s[Si + 5] * e2
    t2 = s[Si + 6] * e0 + s[Si + 7] * e1 + s[Si + 8] * e2
    nis = e0 * t0 + e1 * t1 + e2 * t2
    if nis > gate:
        return nis
    B = _W_A
    K = _W_B
    for i in range(n):
        b0 = s[B + 3 * i]
        b1 = s[B + 3 * i + 1]
        b2 = s[B + 3 * i + 2]
        k0 = b0 * s[Si + 0] + b1 * s[Si + 3] + b2 * s[Si + 6]
        k1 = b0 * s[Si + 1] + b1 * s[Si + 4] + b2 * s[Si + 7]
        k2 = b0 * s[Si + 2] + b1 * s[Si + 5] + b2 * s[Si + 8]
        s[K + 3 * i] = k0
        s[K + 3 * i + 1] = k1
        s[K + 3 * i + 2] = k2
        s[_S_X + i] += k0 * e0 + k1 * e1 + k2 * e2
    for i in range(n):
        k0 = s[K + 3 * i]
        k1 = s[K + 3 * i + 1]
        k2 = s[K + 3 * i + 2]
        for j in range(i, n):
            v = s[_S_P + 7 * i + j] - (k0 * s[B + 3 * j] + k1 * s[B + 3 * j + 1]
                                       + k2 * s[B + 3 * j + 2])
            s[_S_P + 7 * i + j] = v
            s[_S_P + 7 * j + i] = v
    _normalise(s)
    return nis


@_jit
def _joseph_update(s, e0, e1, e2, gate):
    # n = 4 or 7 as a compile-time constant: fixed loops are unrolled.
    if int(s[_S_N]) == 7:
        return _joseph_update_n(s, e0, e1, e2, gate, 7)
    return _joseph_update_n(s, e0, e1, e2, gate, 4)


@_jit_inline
def _measurement_update_q_n(s, c, h, e0, e1, e2, cov, gate, n):
    """Update with a measurement whose H (3 x n) is non-zero only in the q columns:
    h = the 3x4 block (row-major 12-tuple), cov = offset of R in the settings."""
    B = _W_A
    P = _S_P
    for i in range(n):
        p0 = s[P + 7 * i]
        p1 = s[P + 7 * i + 1]
        p2 = s[P + 7 * i + 2]
        p3 = s[P + 7 * i + 3]
        for r in range(3):
            s[B + 3 * i + r] = (p0 * h[4 * r] + p1 * h[4 * r + 1] + p2 * h[4 * r + 2]
                                + p3 * h[4 * r + 3])
    for r in range(3):
        for col in range(3):
            s[_W_D + 3 * r + col] = (h[4 * r] * s[B + col] + h[4 * r + 1] * s[B + 3 + col]
                                     + h[4 * r + 2] * s[B + 6 + col]
                                     + h[4 * r + 3] * s[B + 9 + col]) + c[cov + 3 * r + col]
    return _joseph_update(s, e0, e1, e2, gate)


@_jit
def _measurement_update_q(s, c, h, e0, e1, e2, cov, gate):
    # n = 4 or 7 as a compile-time constant: fixed loops are unrolled.
    if int(s[_S_N]) == 7:
        return _measurement_update_q_n(s, c, h, e0, e1, e2, cov, gate, 7)
    return _measurement_update_q_n(s, c, h, e0, e1, e2, cov, gate, 4)


@_jit
def _zero_rate_update(s, c, w0, w1, w2):
    """reference ``_zero_rate_update``: H = [0 I], R = I std^2, innovation omega - b."""
    B = _W_A
    P = _S_P
    for i in range(7):
        for r in range(3):
            s[B + 3 * i + r] = s[P + 7 * i + 4 + r]
    var = c[_C_REST_RATE_STD] ** 2
    for r in range(3):
        for col in range(3):
            s[_W_D + 3 * r + col] = s[P + 7 * (4 + r) + 4 + col] + (var if r == col else 0.0)
    _joseph_update(s, w0 - s[4], w1 - s[5], w2 - s[6], _INF)


# ---- time update ----------------------------------------------------------------------------
@_jit_inline
def _carry(s, wx, wy, wz, rate, cs, sn):
    """reference ``_carry``: turn the carried specific force into the new body frame,
    v <- R(w T)^T v (Rodrigues; cs, sn: cosine and sine of the angle |w| T)."""
    if rate < 1e-12:
        return
    kx = wx / rate
    ky = wy / rate
    kz = wz / rate
    v0 = s[_S_ACC_CARRIED]
    v1 = s[_S_ACC_CARRIED + 1]
    v2 = s[_S_ACC_CARRIED + 2]
    kv = kx * v0 + ky * v1 + kz * v2
    # R^T v = v cos - (k x v) sin + k (k.v)(1 - cos)
    cx = ky * v2 - kz * v1
    cy = kz * v0 - kx * v2
    cz = kx * v1 - ky * v0
    s[_S_ACC_CARRIED] = v0 * cs - cx * sn + kx * kv * (1 - cs)
    s[_S_ACC_CARRIED + 1] = v1 * cs - cy * sn + ky * kv * (1 - cs)
    s[_S_ACC_CARRIED + 2] = v2 * cs - cz * sn + kz * kv * (1 - cs)


@_jit_inline
def _time_update_gyro_n(s, c, T, n):
    """reference ``_time_update_gyro``: q = F q, P = A P A^T + Q with A = [[F, -G], [0, I]]."""
    q0 = s[0]
    q1 = s[1]
    q2 = s[2]
    q3 = s[3]
    if n == 7:
        wx = s[_S_OMEGA] - s[4]
        wy = s[_S_OMEGA + 1] - s[5]
        wz = s[_S_OMEGA + 2] - s[6]
    else:
        wx = s[_S_OMEGA] - c[_C_GYR_BIAS]
        wy = s[_S_OMEGA + 1] - c[_C_GYR_BIAS + 1]
        wz = s[_S_OMEGA + 2] - c[_C_GYR_BIAS + 2]
    if c[_C_EXACT] != 0.0:
        rate = math.sqrt(wx * wx + wy * wy + wz * wz)
        half = 0.5 * rate * T
        sinc = (math.sin(half) / rate) if rate > 1e-12 else 0.5 * T
        cs = math.cos(half)
    else:
        sinc = 0.5 * T
        cs = 1.0
    ax = sinc * wx
    ay = sinc * wy
    az = sinc * wz
    if s[_S_ACC_CARRIED_VALID] != 0.0 and sinc * cs != 0.0:
        # rotation by |w| T: cos = 2 cos^2(half) - 1, sin = 2 sin(half) cos(half); with the
        # course's F (not exact) the same exact rotation is used for the carried vector
        if c[_C_EXACT] != 0.0:
            _carry(s, wx, wy, wz, rate, 2.0 * cs * cs - 1.0, 2.0 * sinc * rate * cs)
        else:
            r = math.sqrt(wx * wx + wy * wy + wz * wz)
            _carry(s, wx, wy, wz, r, math.cos(r * T), math.sin(r * T))
    F = ((cs, -ax, -ay, -az), (ax, cs, az, -ay), (ay, -az, cs, ax), (az, ay, -ax, cs))
    h = 0.5 * T
    G = ((h * -q1, h * -q2, h * -q3), (h * q0, h * -q3, h * q2),
         (h * q3, h * q0, h * -q1), (h * -q2, h * q1, h * q0))
    P = _S_P
    AP = _W_B
    # rows of A P for the q block: F P_q: - G P_b:
    for i in range(4):
        f0 = F[i][0]
        f1 = F[i][1]
        f2 = F[i][2]
        f3 = F[i][3]
        for j in range(n):
            v = (f0 * s[P + j] + f1 * s[P + 7 + j] + f2 * s[P + 14 + j] + f3 * s[P + 21 + j])
            if n == 7:
                v -= (G[i][0] * s[P + 28 + j] + G[i][1] * s[P + 35 + j]
                      + G[i][2] * s[P + 42 + j])
            s[AP + 7 * i + j] = v
    # G R_w G^T, R_w grown by the scale-factor noise (k |w|)^2 I. For R_w = r I it is
    # r (T/2)^2 S̄ S̄^T = r (T/2)^2 (|q|^2 I - q q^T), cheaper than the general product.
    R = _C_GYR_COV
    extra = c[_C_GYR_SCALE_NOISE] ** 2 * (wx * wx + wy * wy + wz * wz)
    isotropic = c[_C_GYR_COV_ISOTROPIC] != 0.0
    r = (c[R] + extra) * h * h
    qv = (q0, q1, q2, q3)
    qq = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
    for i in range(4):
        if isotropic:
            gr0 = gr1 = gr2 = 0.0
        else:
            gr0 = G[i][0] * (c[R + 0] + extra) + G[i][1] * c[R + 3] + G[i][2] * c[R + 6]
            gr1 = G[i][0] * c[R + 1] + G[i][1] * (c[R + 4] + extra) + G[i][2] * c[R + 7]
            gr2 = G[i][0] * c[R + 2] + G[i][1] * c[R + 5] + G[i][2] * (c[R + 8] + extra)
        for j in range(i, 4):
            v = (s[AP + 7 * i] * F[j][0] + s[AP + 7 * i + 1] * F[j][1]
                 + s[AP + 7 * i + 2] * F[j][2] + s[AP + 7 * i + 3] * F[j][3])
            if n == 7:
                v -= (s[AP + 7 * i + 4] * G[j][0] + s[AP + 7 * i + 5] * G[j][1]
                      + s[AP + 7 * i + 6] * G[j][2])
            if isotropic:
                v += r * ((qq if i == j else 0.0) - qv[i] * qv[j])
            else:
                v += gr0 * G[j][0] + gr1 * G[j][1] + gr2 * G[j][2]
            s[P + 7 * i + j] = v
            s[P + 7 * j + i] = v
    if n == 7:
        for i in range(4):
            for j in range(4, 7):
                v = s[AP + 7 * i + j]
                s[P + 7 * i + j] = v
                s[P + 7 * j + i] = v
        qb = c[_C_BIAS_RW] ** 2 * T
        for i in range(4, 7):
            s[P + 8 * i] += qb
    s[0] = F[0][0] * q0 + F[0][1] * q1 + F[0][2] * q2 + F[0][3] * q3
    s[1] = F[1][0] * q0 + F[1][1] * q1 + F[1][2] * q2 + F[1][3] * q3
    s[2] = F[2][0] * q0 + F[2][1] * q1 + F[2][2] * q2 + F[2][3] * q3
    s[3] = F[3][0] * q0 + F[3][1] * q1 + F[3][2] * q2 + F[3][3] * q3


@_jit
def _time_update_gyro(s, c, T):
    # n = 4 or 7 as a compile-time constant: fixed loops are unrolled.
    if int(s[_S_N]) == 7:
        return _time_update_gyro_n(s, c, T, 7)
    return _time_update_gyro_n(s, c, T, 4)


@_jit
def _time_update_random_walk(s, c, T):
    """reference ``_time_update_random_walk``: q stays, P grows."""
    _add_attitude_cov(s, 0.25 * T * c[_C_NO_GYRO_RW] ** 2)
    if int(s[_S_N]) == 7:
        qb = c[_C_BIAS_RW] ** 2 * T
        for i in range(4, 7):
            s[_S_P + 8 * i] += qb


@_jit
def _advance(s, c, t):
    """reference ``_advance``: move the state to time t with the held gyro sample."""
    if math.isnan(s[_S_T]):
        s[_S_T] = t
        return
    dt = t - s[_S_T]
    if dt <= 0.0:
        return
    t_prev = s[_S_T]
    s[_S_T] = t
    if s[_S_INITIALISED] == 0.0:
        return
    if dt > c[_C_MAX_DT]:
        s[_ST_USED_GYR] = 0.0
        s[_S_ACC_CARRIED_VALID] = 0.0
        return
    if (s[_S_OMEGA_VALID] != 0.0 and s[_S_EN_GYR] != 0.0
            and t_prev - s[_S_OMEGA_T] <= c[_C_GYR_HOLD_S]):
        _time_update_gyro(s, c, dt)
        s[_ST_USED_GYR] = 1.0
        if c[_C_EXACT] == 0.0:
            _normalise(s)
        elif s[0] < 0.0:
            _flip_sign(s)
    else:
        _time_update_random_walk(s, c, dt)
        s[_ST_USED_GYR] = 0.0
        _normalise(s)


# ---- measurement updates --------------------------------------------------------------------
@_jit
def _acc_update(s, c, y0, y1, y2, norm_gate):
    """reference ``_acc_update``: y_a = Q(q)^T g0 with the norm gate (task 8) and NIS gate;
    y is the reading, or its carried low-pass (then without the norm gate)."""
    norm = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    g = c[_C_G]
    s[_ST_ACC_NORM] = norm
    s[_ST_G] = g
    s[_ST_ACC_GATE] = c[_C_ACC_GATE]
    if abs(norm - g) > norm_gate:
        s[_ST_ACC_REJECTED] = 1.0
        s[_ST_USED_ACC] = 0.0
        return
    q0 = s[0]
    q1 = s[1]
    q2 = s[2]
    q3 = s[3]
    # y_hat = g * (third row of Q); H[:, i] = g * (third row of dQ/dq_i)
    yh0 = g * (2 * (q1 * q3 - q0 * q2))
    yh1 = g * (2 * (q2 * q3 + q0 * q1))
    yh2 = g * (2 * (q0 * q0 + q3 * q3) - 1)
    h = (g * (2 * -q2), g * (2 * q3), g * (2 * -q0), g * (2 * q1),
         g * (2 * q1), g * (2 * q0), g * (2 * q3), g * (2 * q2),
         g * (2 * (2 * q0)), 0.0, 0.0, g * (2 * (2 * q3)))
    gate = c[_C_ACC_NIS_GATE]
    nis = _measurement_update_q(s, c, h, y0 - yh0, y1 - yh1, y2 - yh2, _C_ACC_COV, gate)
    s[_ST_ACC_NIS] = nis
    accepted = nis <= gate
    s[_ST_ACC_REJECTED] = 0.0 if accepted else 1.0
    s[_ST_USED_ACC] = 1.0 if accepted else 0.0


@_jit
def _heading_error(s, m0, m1):
    """reference ``_heading_error``: psi [rad] and d psi / d (m_E, m_N)."""
    if s[_S_M0_VALID] != 0.0:
        rx = s[_S_M0]
        ry = s[_S_M0 + 1]
    else:
        rx = 0.0
        ry = 1.0
    cross = rx * m1 - ry * m0
    dot = rx * m0 + ry * m1
    psi = math.atan2(cross, dot)
    denom = cross * cross + dot * dot
    return psi, (dot * -ry - cross * rx) / denom, (dot * rx - cross * ry) / denom


@_jit_inline
def _mag_heading_update_n(s, c, y0, y1, y2, n, gate):
    """reference ``_mag_heading_update``: heading pseudo-measurement, gain projected on a turn
    about world up. Returns the NIS (NaN when the field is vertical: no update)."""
    q0 = s[0]
    q1 = s[1]
    q2 = s[2]
    q3 = s[3]
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
    R = _C_MAG_COV
    r = (c[R] + c[R + 4] + c[R + 8]) / 3.0 / horizontal_sq
    P = _S_P
    B = _W_A
    for i in range(n):
        s[B + i] = (s[P + 7 * i] * h0 + s[P + 7 * i + 1] * h1 + s[P + 7 * i + 2] * h2
                    + s[P + 7 * i + 3] * h3)
    S = h0 * s[B] + h1 * s[B + 1] + h2 * s[B + 2] + h3 * s[B + 3] + r
    if psi * psi / S > gate:
        return psi * psi / S
    K = _W_B
    inv_S = 1.0 / S
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
    innovation = -psi
    for i in range(n):
        s[_S_X + i] += s[K + i] * innovation
    for i in range(n):
        ki = s[K + i]
        bi = s[B + i]
        for j in range(i, n):
            v = s[P + 7 * i + j] - ki * s[B + j] - bi * s[K + j] + S * ki * s[K + j]
            s[P + 7 * i + j] = v
            s[P + 7 * j + i] = v
    _normalise(s)
    return innovation * innovation * inv_S


@_jit
def _mag_heading_update(s, c, y0, y1, y2, gate):
    # n = 4 or 7 as a compile-time constant: fixed loops are unrolled.
    if int(s[_S_N]) == 7:
        return _mag_heading_update_n(s, c, y0, y1, y2, 7, gate)
    return _mag_heading_update_n(s, c, y0, y1, y2, 4, gate)


@_jit
def _set_m0_from(s, y0, y1, y2):
    """reference ``_set_m0_from``: m0 = (0, horizontal, vertical) of the reading in the world."""
    Q = _to_matrix(s[0], s[1], s[2], s[3])
    mw0 = Q[0] * y0 + Q[1] * y1 + Q[2] * y2
    mw1 = Q[3] * y0 + Q[4] * y1 + Q[5] * y2
    mw2 = Q[6] * y0 + Q[7] * y1 + Q[8] * y2
    s[_S_M0] = 0.0
    s[_S_M0 + 1] = math.hypot(mw0, mw1)
    s[_S_M0 + 2] = mw2
    s[_S_M0_VALID] = 1.0
    strength = math.sqrt(s[_S_M0 + 1] ** 2 + mw2 * mw2)
    s[_S_MAG_STRENGTH] = strength
    s[_ST_MAG_EXPECTED] = strength


@_jit
def _relearn_field(s, y0, y1, y2):
    """reference ``_relearn_field``."""
    s[_S_MAG_STRENGTH] = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    if s[_S_M0_VALID] != 0.0:
        Q = _to_matrix(s[0], s[1], s[2], s[3])
        mw0 = Q[0] * y0 + Q[1] * y1 + Q[2] * y2
        mw1 = Q[3] * y0 + Q[4] * y1 + Q[5] * y2
        mw2 = Q[6] * y0 + Q[7] * y1 + Q[8] * y2
        s[_S_M0] = 0.0
        s[_S_M0 + 1] = math.hypot(mw0, mw1)
        s[_S_M0 + 2] = mw2
    s[_S_MAG_REJECTED_SINCE] = _NAN


@_jit
def _dip_deg(s, c, y0, y1, y2):
    """reference ``_dip_deg``: angle between up and the field (from the estimate, or from the
    latest accelerometer reading)."""
    if c[_C_MAG_DIP_FROM_ESTIMATE] != 0.0:
        Q = _to_matrix(s[0], s[1], s[2], s[3])
        up = Q[6] * y0 + Q[7] * y1 + Q[8] * y2
        ny = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
        return math.degrees(math.acos(max(-1.0, min(1.0, up / (ny + 1e-300)))))
    if s[_S_LAST_ACC_VALID] == 0.0 or s[_ST_ACC_REJECTED] != 0.0:
        return _NAN
    a0 = s[_S_LAST_ACC]
    a1 = s[_S_LAST_ACC + 1]
    a2 = s[_S_LAST_ACC + 2]
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    ny = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    cv = (a0 * y0 + a1 * y1 + a2 * y2) / (na * ny + 1e-300)
    return math.degrees(math.acos(max(-1.0, min(1.0, cv))))


@_jit
def _reference_dip_deg(s):
    """reference ``_reference_dip_deg``."""
    if s[_S_M0_VALID] == 0.0:
        return _NAN
    m0 = s[_S_M0]
    m1 = s[_S_M0 + 1]
    m2 = s[_S_M0 + 2]
    return math.degrees(math.acos(m2 / (math.sqrt(m0 * m0 + m1 * m1 + m2 * m2) + 1e-300)))


@_jit
def _mag_update(s, c, y0, y1, y2, t):
    """reference ``_mag_update``: norm (and dip) gate, AR(1) field strength, then the update."""
    norm = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    s[_ST_MAG_NORM] = norm
    s[_ST_MAG_GATE] = c[_C_MAG_GATE]
    if math.isnan(s[_S_MAG_STRENGTH]):
        s[_S_MAG_STRENGTH] = norm
    L_prev = s[_S_MAG_STRENGTH]
    rejected = abs(norm - L_prev) > c[_C_MAG_GATE]
    dip = _dip_deg(s, c, y0, y1, y2)
    s[_ST_MAG_DIP_DEG] = dip
    dip_gate = c[_C_MAG_DIP_GATE_DEG]
    if not rejected and math.isfinite(dip_gate) and math.isfinite(dip):
        rejected = abs(dip - _reference_dip_deg(s)) > dip_gate
    if c[_C_MAG_ALWAYS] != 0.0 or not rejected:
        alpha = c[_C_MAG_ALPHA]
        s[_S_MAG_STRENGTH] = (1 - alpha) * L_prev + alpha * norm
    s[_ST_MAG_EXPECTED] = s[_S_MAG_STRENGTH]
    if rejected:
        s[_S_MAG_PASSING_SINCE] = _NAN
    elif math.isnan(s[_S_MAG_PASSING_SINCE]):
        s[_S_MAG_PASSING_SINCE] = t
    settling = t - s[_S_MAG_PASSING_SINCE] < c[_C_MAG_SETTLE_S]
    if rejected or settling:
        if c[_C_MAG_ACCEPTED] != 0.0:
            # a new field is learned only when the rejected readings agree with each other
            # (strength and dip within the gates of their own running mean) for relearn_s
            cn = s[_S_MAG_CANDIDATE_NORM]
            cd = s[_S_MAG_CANDIDATE_DIP]
            if (math.isnan(s[_S_MAG_REJECTED_SINCE]) or abs(norm - cn) > c[_C_MAG_GATE]
                    or abs(dip - cd) > dip_gate):
                s[_S_MAG_REJECTED_SINCE] = t
                s[_S_MAG_CANDIDATE_NORM] = norm
                s[_S_MAG_CANDIDATE_DIP] = dip
            else:
                alpha = c[_C_MAG_ALPHA]
                s[_S_MAG_CANDIDATE_NORM] = cn + alpha * (norm - cn)
                s[_S_MAG_CANDIDATE_DIP] = cd + alpha * (dip - cd)
                if t - s[_S_MAG_REJECTED_SINCE] >= c[_C_MAG_RELEARN_S]:
                    _relearn_field(s, y0, y1, y2)
        s[_ST_MAG_REJECTED] = 1.0
        s[_ST_USED_MAG] = 0.0
        return
    s[_S_MAG_REJECTED_SINCE] = _NAN
    s[_ST_MAG_REJECTED] = 0.0
    if t - s[_S_MAG_UPDATED_T] < c[_C_UPDATE_PERIOD]:
        s[_ST_USED_MAG] = 0.0
        return
    s[_S_MAG_UPDATED_T] = t
    if c[_C_HEADING_ONLY] != 0.0:
        nis = _mag_heading_update(s, c, y0, y1, y2, c[_C_MAG_NIS_GATE])
    else:
        q0 = s[0]
        q1 = s[1]
        q2 = s[2]
        q3 = s[3]
        m0 = s[_S_M0]
        m1 = s[_S_M0 + 1]
        m2 = s[_S_M0 + 2]
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
        nis = _measurement_update_q(s, c, h, y0 - yh0, y1 - yh1, y2 - yh2, _C_MAG_COV,
                                    c[_C_MAG_NIS_GATE])
    s[_ST_MAG_NIS] = nis
    if nis > c[_C_MAG_NIS_GATE]:
        # an innovation the filter cannot believe: rejected, and readings must settle again
        s[_S_MAG_PASSING_SINCE] = _NAN
        s[_ST_MAG_REJECTED] = 1.0
        s[_ST_USED_MAG] = 0.0
        return
    s[_ST_MAG_REJECTED] = 0.0
    s[_ST_USED_MAG] = 1.0


# ---- initialisation -------------------------------------------------------------------------
@_jit
def _initialise(s, c, t):
    """reference ``_initialise``: orientation from the latest enabled acc/mag readings."""
    n = int(s[_S_N])
    acc_ok = s[_S_EN_ACC] != 0.0 and s[_S_LAST_ACC_VALID] != 0.0
    mag_ok = (s[_S_EN_MAG] != 0.0 and s[_S_LAST_MAG_VALID] != 0.0
              and t - s[_S_LAST_MAG_T] <= 0.1)
    a0 = s[_S_LAST_ACC]
    a1 = s[_S_LAST_ACC + 1]
    a2 = s[_S_LAST_ACC + 2]
    m0 = s[_S_LAST_MAG]
    m1 = s[_S_LAST_MAG + 1]
    m2 = s[_S_LAST_MAG + 2]
    if acc_ok and mag_ok:
        x0, x1, x2 = _cross(m0, m1, m2, a0, a1, a2)
        if (math.sqrt(x0 * x0 + x1 * x1 + x2 * x2) <= 1e-6 * math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
                * math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)):
            mag_ok = False   # a field along gravity has no heading: tilt now, heading later
    if acc_ok and mag_ok:
        q = _acc_mag_quaternion(a0, a1, a2, m0, m1, m2)
        s[_S_HEADING_FROM_MAG] = 1.0
    elif acc_ok:
        q = _tilt_quaternion(a0, a1, a2)
    elif mag_ok:
        half = math.atan2(m0, m1) / 2
        q = (math.cos(half), 0.0, 0.0, math.sin(half))
        s[_S_HEADING_FROM_MAG] = 1.0
    else:
        q = (1.0, 0.0, 0.0, 0.0)
    q = _quat_normalize(q[0], q[1], q[2], q[3])
    for i in range(4):
        s[i] = q[i]
    for i in range(49):
        s[_S_P + i] = 0.0
    _set_attitude_cov(s, 0.25 * c[_C_INITIAL_ATTITUDE_STD] ** 2)
    if not (acc_ok and mag_ok):
        _add_attitude_cov(s, 0.25)
    if n == 7:
        vb = c[_C_INITIAL_BIAS_STD] ** 2
        for i in range(4, 7):
            s[_S_P + 8 * i] = vb
    s[_S_INITIALISED] = 1.0
    if (s[_S_HEADING_FROM_MAG] != 0.0 and s[_S_M0_VALID] == 0.0
            and s[_S_LAST_MAG_VALID] != 0.0):
        _set_m0_from(s, m0, m1, m2)


@_jit
def _take_heading_from_mag(s, c, y0, y1, y2):
    """reference ``_take_heading_from_mag``."""
    Q = _to_matrix(s[0], s[1], s[2], s[3])
    mw0 = Q[0] * y0 + Q[1] * y1 + Q[2] * y2
    mw1 = Q[3] * y0 + Q[4] * y1 + Q[5] * y2
    if mw0 ** 2 + mw1 ** 2 < 1e-6:
        return
    psi, _d0, _d1 = _heading_error(s, mw0, mw1)
    q = _rotate_world_about_up(s[0], s[1], s[2], s[3], -psi)
    for i in range(4):
        s[i] = q[i]
    _set_attitude_cov(s, 0.25 * c[_C_INITIAL_ATTITUDE_STD] ** 2)
    # a fresh attitude is uncorrelated with the bias estimate (no-op when n = 4)
    for i in range(4):
        for j in range(4, 7):
            s[_S_P + 7 * i + j] = 0.0
            s[_S_P + 7 * j + i] = 0.0
    s[_S_HEADING_FROM_MAG] = 1.0
    if s[_S_M0_VALID] == 0.0:
        _set_m0_from(s, y0, y1, y2)


# ---- rest detection -------------------------------------------------------------------------
@_jit
def _update_rest(s, c, t):
    """reference ``_update_rest``."""
    if s[_S_EN_GYR] == 0.0 and s[_S_EN_ACC] == 0.0:
        s[_ST_AT_REST] = 0.0
        return
    if s[_S_LAST_MOTION_T] == -_INF:
        s[_S_LAST_MOTION_T] = t
    s[_ST_AT_REST] = 1.0 if t - s[_S_LAST_MOTION_T] >= c[_C_REST_MIN_DURATION] else 0.0


@_jit
def _detect_rest_gyr(s, c, t, w0, w1, w2):
    """reference ``_detect_rest_gyr``."""
    if int(s[_S_N]) == 7:
        d0 = w0 - s[4]
        d1 = w1 - s[5]
        d2 = w2 - s[6]
    else:
        d0 = w0 - c[_C_GYR_BIAS]
        d1 = w1 - c[_C_GYR_BIAS + 1]
        d2 = w2 - c[_C_GYR_BIAS + 2]
    if math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) > c[_C_REST_GYR_THRESHOLD]:
        s[_S_LAST_MOTION_T] = t
    _update_rest(s, c, t)


@_jit
def _detect_rest_acc(s, c, t, y0, y1, y2):
    """reference ``_detect_rest_acc``."""
    L = _S_ACC_LOWPASS
    if s[_S_ACC_LOWPASS_VALID] == 0.0:
        s[L] = y0
        s[L + 1] = y1
        s[L + 2] = y2
        s[_S_ACC_LOWPASS_VALID] = 1.0
    s[L] = 0.9 * s[L] + 0.1 * y0
    s[L + 1] = 0.9 * s[L + 1] + 0.1 * y1
    s[L + 2] = 0.9 * s[L + 2] + 0.1 * y2
    d0 = y0 - s[L]
    d1 = y1 - s[L + 1]
    d2 = y2 - s[L + 2]
    if math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) > c[_C_REST_ACC_THRESHOLD]:
        s[_S_LAST_MOTION_T] = t
    _update_rest(s, c, t)


# ---- sample entry points --------------------------------------------------------------------
@_jit
def _update_gyr(s, c, t, v0, v1, v2):
    """reference ``update_gyr``."""
    if c[_C_GYR_RATE_BEFORE] != 0.0 and s[_S_EN_GYR] != 0.0:
        # the sample is the rate over the interval ending now: it drives the state up to t
        if s[_S_OMEGA_VALID] == 0.0 or t - s[_S_OMEGA_T] <= c[_C_GYR_HOLD_S]:
            s[_S_OMEGA] = v0
            s[_S_OMEGA + 1] = v1
            s[_S_OMEGA + 2] = v2
            s[_S_OMEGA_VALID] = 1.0
        _advance(s, c, t)
    else:
        _advance(s, c, t)
    if s[_S_EN_GYR] == 0.0:
        return
    s[_S_OMEGA] = v0
    s[_S_OMEGA + 1] = v1
    s[_S_OMEGA + 2] = v2
    s[_S_OMEGA_VALID] = 1.0
    s[_S_OMEGA_T] = t
    if s[_S_INITIALISED] == 0.0 and s[_S_EN_ACC] == 0.0 and s[_S_EN_MAG] == 0.0:
        _initialise(s, c, t)   # gyroscope alone: nothing absolute, start at identity (flat)
    _detect_rest_gyr(s, c, t, v0, v1, v2)
    if (int(s[_S_N]) == 7 and s[_S_INITIALISED] != 0.0 and s[_ST_AT_REST] != 0.0
            and t - s[_S_REST_UPDATED_T] >= c[_C_UPDATE_PERIOD]):
        s[_S_REST_UPDATED_T] = t
        _zero_rate_update(s, c, v0, v1, v2)


@_jit
def _update_acc(s, c, t, v0, v1, v2):
    """reference ``update_acc``."""
    _advance(s, c, t)
    s[_S_LAST_ACC] = v0
    s[_S_LAST_ACC + 1] = v1
    s[_S_LAST_ACC + 2] = v2
    s[_S_LAST_ACC_VALID] = 1.0
    s[_S_LAST_ACC_T] = t
    if s[_S_EN_ACC] == 0.0:
        s[_ST_USED_ACC] = 0.0
        return
    _detect_rest_acc(s, c, t, v0, v1, v2)
    if s[_S_INITIALISED] == 0.0:
        _initialise(s, c, t)
        return
    tau = c[_C_ACC_LOWPASS_S]
    if tau > 0.0 and s[_S_EN_GYR] != 0.0:
        _acc_lowpass_update(s, c, t, v0, v1, v2, tau)
    else:
        _acc_update(s, c, v0, v1, v2, c[_C_ACC_GATE])


@_jit
def _acc_lowpass_update(s, c, t, v0, v1, v2, tau):
    """reference ``_acc_lowpass_update``: every reading is blended into the carried low-pass
    (first order, time constant tau: accelerations cancel in the average, so none is
    dropped); at most every update_period_s the carried vector is the measurement. The
    norm gate only flags a disturbed reading (acc_rejected) for the user."""
    norm = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    C = _S_ACC_CARRIED
    if s[_S_ACC_CARRIED_VALID] == 0.0:
        s[C] = v0
        s[C + 1] = v1
        s[C + 2] = v2
        s[_S_ACC_CARRIED_VALID] = 1.0
    else:
        dt = t - s[_S_ACC_CARRIED_T]
        alpha = dt / (tau + dt)
        s[C] += alpha * (v0 - s[C])
        s[C + 1] += alpha * (v1 - s[C + 1])
        s[C + 2] += alpha * (v2 - s[C + 2])
    s[_S_ACC_CARRIED_T] = t
    used = 1.0
    if t - s[_S_ACC_UPDATED_T] >= c[_C_UPDATE_PERIOD]:
        s[_S_ACC_UPDATED_T] = t
        _acc_update(s, c, s[C], s[C + 1], s[C + 2], _INF)
        used = s[_ST_USED_ACC]   # the NIS gate may still refuse the averaged vector
    s[_ST_ACC_NORM] = norm
    s[_ST_ACC_GATE] = c[_C_ACC_GATE]
    s[_ST_ACC_REJECTED] = 1.0 if abs(norm - c[_C_G]) > c[_C_ACC_GATE] else 0.0
    s[_ST_USED_ACC] = used


@_jit
def _update_mag(s, c, t, v0, v1, v2):
    """reference ``update_mag``."""
    _advance(s, c, t)
    s[_S_LAST_MAG] = v0
    s[_S_LAST_MAG + 1] = v1
    s[_S_LAST_MAG + 2] = v2
    s[_S_LAST_MAG_VALID] = 1.0
    s[_S_LAST_MAG_T] = t
    if s[_S_EN_MAG] == 0.0:
        s[_ST_USED_MAG] = 0.0
        return
    if s[_S_INITIALISED] == 0.0:
        if s[_S_EN_ACC] == 0.0:
            _initialise(s, c, t)
        return
    if s[_S_HEADING_FROM_MAG] == 0.0:
        _take_heading_from_mag(s, c, v0, v1, v2)
        return
    _mag_update(s, c, v0, v1, v2, t)


@_jit
def _update(s, c, kind, t, v0, v1, v2):
    """One sample of `kind` (KIND_GYR, KIND_ACC, KIND_MAG; KIND_NONE only moves the clock)."""
    if kind == KIND_GYR:
        _update_gyr(s, c, t, v0, v1, v2)
    elif kind == KIND_ACC:
        _update_acc(s, c, t, v0, v1, v2)
    elif kind == KIND_MAG:
        _update_mag(s, c, t, v0, v1, v2)
    else:
        _advance(s, c, t)


@_jit
def _step(s, c, t, present, g0, g1, g2, a0, a1, a2, m0, m1, m2):
    """reference ``step``: present is a bit mask (1 gyr, 2 acc, 4 mag)."""
    if present & 1:
        _update_gyr(s, c, t, g0, g1, g2)
    if present & 2:
        _update_acc(s, c, t, a0, a1, a2)
    if present & 4:
        _update_mag(s, c, t, m0, m1, m2)
    if present == 0:
        _advance(s, c, t)


@_jit
def _run_batch(s, c, t, gyr, acc, mag, out_q, out_flags, out_bias):
    """All rows in one loop (a row with any NaN in a sensor's columns has no such sample).
    out_flags columns: acc_rejected, mag_rejected, at_rest."""
    for k in range(t.shape[0]):
        tk = t[k]
        g0 = gyr[k, 0]
        g1 = gyr[k, 1]
        g2 = gyr[k, 2]
        a0 = acc[k, 0]
        a1 = acc[k, 1]
        a2 = acc[k, 2]
        m0 = mag[k, 0]
        m1 = mag[k, 1]
        m2 = mag[k, 2]
        has_g = not (math.isnan(g0) or math.isnan(g1) or math.isnan(g2))
        has_a = not (math.isnan(a0) or math.isnan(a1) or math.isnan(a2))
        has_m = not (math.isnan(m0) or math.isnan(m1) or math.isnan(m2))
        if has_g:
            _update_gyr(s, c, tk, g0, g1, g2)
        if has_a:
            _update_acc(s, c, tk, a0, a1, a2)
        if has_m:
            _update_mag(s, c, tk, m0, m1, m2)
        if not (has_g or has_a or has_m):
            _advance(s, c, tk)
        for i in range(4):
            out_q[k, i] = s[i]
        out_flags[k, 0] = s[_ST_ACC_REJECTED] != 0.0
        out_flags[k, 1] = s[_ST_MAG_REJECTED] != 0.0
        out_flags[k, 2] = s[_ST_AT_REST] != 0.0
        if int(s[_S_N]) == 7:
            for i in range(3):
                out_bias[k, i] = s[4 + i]
        else:
            for i in range(3):
                out_bias[k, i] = c[_C_GYR_BIAS + i]


# =============================================================================================
# the Python face
class _LiveStatus(Status):
    """An :class:`ekf.reference.Status` whose fields read (and write) the packed state.

    Like the reference, whose ``status`` is one object updated in place, this view always shows
    the filter's latest decisions; :func:`copy.copy` gives a frozen plain :class:`Status`.
    """

    def __init__(self, state: np.ndarray) -> None:   # noqa: D107 (no dataclass fields set)
        object.__setattr__(self, "_state", state)

    def frozen(self) -> Status:
        """A plain Status with the current values."""
        return _status_from(self._state)

    def __copy__(self) -> Status:
        return self.frozen()

    def __deepcopy__(self, memo) -> Status:
        return self.frozen()

    def __reduce__(self):
        return (_status_from_values, (self._state[_S_STATUS:_S_STATUS + 15].tolist(),))


def _status_property(index: int, is_flag: bool) -> property:
    if is_flag:
        def get(self) -> bool:
            return bool(self._state[index] != 0.0)
    else:
        def get(self) -> float:
            return float(self._state[index])

    def set_(self, value) -> None:
        self._state[index] = float(value)

    return property(get, set_)


for _i, _name in enumerate(_STATUS_FIELDS):
    setattr(_LiveStatus, _name, _status_property(_S_STATUS + _i, _i < _STATUS_BOOLS))


def _status_from_values(values: list[float]) -> Status:
    return Status(*[bool(v != 0.0) if i < _STATUS_BOOLS else float(v)
                    for i, v in enumerate(values)])


def _status_from(state: np.ndarray) -> Status:
    return _status_from_values(state[_S_STATUS:_S_STATUS + 15].tolist())


def _as3(v: ArrayLike) -> tuple[float, float, float]:
    if isinstance(v, np.ndarray) and v.shape == (3,):
        return float(v[0]), float(v[1]), float(v[2])
    a = np.asarray(v, dtype=float).reshape(3)
    return float(a[0]), float(a[1]), float(a[2])


class FastEKF:
    """:class:`ekf.reference.OrientationEKF` compiled: same interface, same estimates.

    Parameters
    ----------
    settings:
        An :class:`EKFSettings`, or a preset name ("default", "course"). Default: "default".
        With ``PRESETS["course"]`` the estimator's :attr:`name` is "course", else "ekf".
    sensors:
        Which sensors are enabled at the start (any non-empty subset of gyr, acc, mag).

    Feed samples in time order (at equal times: gyroscope, accelerometer, magnetometer) with
    times in seconds. Read :attr:`quat` (w-first, sensor -> ENU, w >= 0), :attr:`cov`,
    :attr:`gyro_bias` and :attr:`status`. :meth:`run_batch` filters whole arrays in one
    compiled loop.
    """

    name = "ekf"

    def __init__(self, settings: EKFSettings | str | None = None,
                 sensors: tuple[str, ...] | list[str] = SENSORS) -> None:
        if settings is None:
            settings = PRESETS["default"]
        elif isinstance(settings, str):
            settings = PRESETS[settings]
        if settings is PRESETS["course"]:
            self.name = "course"
        self.settings: EKFSettings = settings
        self._cfg = pack_settings(settings)
        self._state = np.zeros(_STATE_SIZE)
        for offset, sensor in ((_S_EN_GYR, "gyr"), (_S_EN_ACC, "acc"), (_S_EN_MAG, "mag")):
            self._state[offset] = float(sensor in sensors)
        self._status = _LiveStatus(self._state)
        self.reset()

    # ---------------------------------------------------------------------------------------
    # public state
    @property
    def enabled(self) -> dict[str, bool]:
        s = self._state
        return {"gyr": bool(s[_S_EN_GYR]), "acc": bool(s[_S_EN_ACC]), "mag": bool(s[_S_EN_MAG])}

    @property
    def quat(self) -> np.ndarray:
        """(4,) w-first, sensor -> ENU, w >= 0 (identity until initialised)."""
        return self._state[0:4].copy()

    @property
    def cov(self) -> np.ndarray:
        """Covariance of the full state (4x4, or 7x7 with the bias)."""
        n = int(self._state[_S_N])
        return self._state[_S_P:_S_P + 49].reshape(7, 7)[:n, :n].copy()

    @property
    def gyro_bias(self) -> np.ndarray:
        """(3,) [rad/s]: the estimate (model 4c) or the fixed setting."""
        if int(self._state[_S_N]) == 7:
            return self._state[4:7].copy()
        return np.asarray(self.settings.gyr_bias, float)

    @property
    def initialised(self) -> bool:
        return bool(self._state[_S_INITIALISED])

    @property
    def time(self) -> float | None:
        t = float(self._state[_S_T])
        return None if math.isnan(t) else t

    @property
    def status(self) -> Status:
        """The latest decisions (an :class:`ekf.reference.Status` reading the packed state)."""
        return self._status

    @status.setter
    def status(self, value: Status) -> None:
        for i, name in enumerate(_STATUS_FIELDS):
            self._state[_S_STATUS + i] = float(getattr(value, name))

    def set_enabled(self, gyr: bool | None = None, acc: bool | None = None,
                    mag: bool | None = None) -> None:
        """Switch sensors in or out of the filter; takes effect at the next sample."""
        s = self._state
        for offset, value in ((_S_EN_GYR, gyr), (_S_EN_ACC, acc), (_S_EN_MAG, mag)):
            if value is not None:
                s[offset] = float(bool(value))
        if not s[_S_EN_GYR]:
            s[_S_OMEGA_VALID] = 0.0
            s[_S_ACC_CARRIED_VALID] = 0.0
        s[_ST_AT_REST] = float(bool(s[_ST_AT_REST]) and bool(s[_S_EN_GYR] or s[_S_EN_ACC]))

    def set_settings(self, settings: EKFSettings) -> None:
        """Use new settings from the next sample on, keeping the orientation."""
        s = self._state
        old_n = int(s[_S_N])
        self.settings = settings
        self._cfg = pack_settings(settings)
        n = 7 if settings.estimate_gyro_bias else 4
        if n != old_n:
            P = s[_S_P:_S_P + 49].reshape(7, 7)
            P[:, 4:] = 0.0
            P[4:, :] = 0.0
            s[4:7] = 0.0
            if n == 7:
                s[4:7] = settings.gyr_bias
                P[4:, 4:] = np.eye(3) * settings.initial_gyro_bias_std ** 2
            s[_S_N] = n

    def reset(self) -> None:
        """Forget everything but settings and switches; re-initialise from the next samples."""
        st = self.settings
        s = self._state
        enabled = s[_S_EN_GYR:_S_EN_MAG + 1].copy()
        s[:] = 0.0
        s[_S_EN_GYR:_S_EN_MAG + 1] = enabled
        n = 7 if st.estimate_gyro_bias else 4
        s[_S_N] = n
        s[0] = 1.0
        if n == 7:
            s[4:7] = st.gyr_bias
        s[_S_P:_S_P + 49].reshape(7, 7)[:n, :n] = np.eye(n)
        s[_S_T] = math.nan
        s[_S_OMEGA_T] = -math.inf
        s[_S_LAST_ACC_T] = -math.inf
        s[_S_LAST_MAG_T] = -math.inf
        if st.m0 is not None:
            m0 = np.asarray(st.m0, dtype=float).reshape(3)
            s[_S_M0:_S_M0 + 3] = m0
            s[_S_M0_VALID] = 1.0
            s[_S_MAG_STRENGTH] = float(np.linalg.norm(m0))
        else:
            s[_S_MAG_STRENGTH] = math.nan
        s[_S_MAG_REJECTED_SINCE] = math.nan
        s[_S_MAG_PASSING_SINCE] = -math.inf
        s[_S_ACC_UPDATED_T] = -math.inf
        s[_S_MAG_UPDATED_T] = -math.inf
        s[_S_REST_UPDATED_T] = -math.inf
        s[_S_LAST_MOTION_T] = -math.inf
        fresh = Status(g=st.g, acc_gate=st.acc_gate, mag_gate=st.mag_gate)
        s[_S_STATUS:_S_STATUS + 15] = [float(getattr(fresh, name)) for name in _STATUS_FIELDS]

    def snapshot(self) -> tuple:
        """Everything needed to continue later from exactly here (for replay seeking):
        a copy of the packed state, with the settings in use."""
        return (self._state.copy(), self.settings, self._cfg)

    def restore(self, state: tuple) -> None:
        packed, settings, cfg = state
        self._state[:] = packed
        self.settings = settings
        self._cfg = cfg

    def align_heading(self, q_ref: ArrayLike) -> None:
        """Turn the estimate about world up so its heading matches `q_ref`'s (the phone's)."""
        s = self._state
        q = s[0:4].copy()
        delta = quat.heading_of(quat.multiply(np.asarray(q_ref, float), quat.conjugate(q)))
        s[0:4] = quat.normalize(quat.multiply(quat.from_axis_angle([0, 0, 1], delta), q))
        if s[_S_M0_VALID]:
            # Turning our world turns the Earth field in it by the same angle.
            s[_S_M0:_S_M0 + 3] = quat.rotate(quat.from_axis_angle([0, 0, 1], delta),
                                             s[_S_M0:_S_M0 + 3].copy())

    # ---------------------------------------------------------------------------------------
    # sample entry points
    def update_gyr(self, t: float, gyr: ArrayLike) -> Status:
        """A gyroscope sample [rad/s, sensor frame] at time t [s]."""
        v0, v1, v2 = _as3(gyr)
        _update(self._state, self._cfg, KIND_GYR, float(t), v0, v1, v2)
        return self._status

    def update_acc(self, t: float, acc: ArrayLike) -> Status:
        """An accelerometer sample [m/s^2, sensor frame] at time t [s]."""
        v0, v1, v2 = _as3(acc)
        _update(self._state, self._cfg, KIND_ACC, float(t), v0, v1, v2)
        return self._status

    def update_mag(self, t: float, mag: ArrayLike) -> Status:
        """A magnetometer sample [uT, sensor frame] at time t [s]."""
        v0, v1, v2 = _as3(mag)
        _update(self._state, self._cfg, KIND_MAG, float(t), v0, v1, v2)
        return self._status

    def step(self, t: float, gyr: ArrayLike | None = None, acc: ArrayLike | None = None,
             mag: ArrayLike | None = None) -> Status:
        """All samples that share time t, in the order gyroscope, accelerometer, magnetometer."""
        present = 0
        g0 = g1 = g2 = a0 = a1 = a2 = m0 = m1 = m2 = 0.0
        if gyr is not None:
            present = 1
            g0, g1, g2 = _as3(gyr)
        if acc is not None:
            present |= 2
            a0, a1, a2 = _as3(acc)
        if mag is not None:
            present |= 4
            m0, m1, m2 = _as3(mag)
        _step(self._state, self._cfg, float(t), present, g0, g1, g2, a0, a1, a2, m0, m1, m2)
        return self._status

    def run_batch(self, t_s: ArrayLike, gyr: ArrayLike, acc: ArrayLike,
                  mag: ArrayLike) -> "BatchResult":
        """Feed all rows (as `step` would, one compiled loop) and return per-row results.

        t_s: (N,) [s], non-decreasing; gyr [rad/s], acc [m/s^2], mag [uT]: (N, 3) each, a NaN
        row where that sensor has no sample. The filter continues from its current state and
        ends after the last row.
        """
        from ekf.batch import BatchResult   # ekf.batch imports the estimators, which import us

        t = np.ascontiguousarray(t_s, dtype=float).reshape(-1)
        n = t.shape[0]
        arrays = []
        for a in (gyr, acc, mag):
            a = np.ascontiguousarray(a, dtype=float)
            if a.shape != (n, 3):
                raise ValueError(f"sensor array must have shape ({n}, 3), got {a.shape}")
            arrays.append(a)
        out_q = np.empty((n, 4))
        out_flags = np.zeros((n, 3), dtype=np.bool_)
        out_bias = np.empty((n, 3))
        _run_batch(self._state, self._cfg, t, arrays[0], arrays[1], arrays[2],
                   out_q, out_flags, out_bias)
        return BatchResult(t, out_q, out_flags[:, 0].copy(), out_flags[:, 1].copy(),
                           out_flags[:, 2].copy(), gyro_bias=out_bias)


def warm_up() -> None:
    """Compile (or load from the on-disk cache) every compiled function with a tiny input."""
    t = np.array([0.0, 0.01, 0.02, 0.03])
    gyr = np.array([[0.01, 0.0, 0.0], [np.nan] * 3, [0.0, 0.01, 0.0], [0.0, 0.0, 0.01]])
    acc = np.array([[0.0, 0.0, 9.81], [0.1, 0.0, 9.8], [np.nan] * 3, [0.0, 0.1, 9.8]])
    mag = np.array([[0.0, 20.0, -40.0], [0.0, 20.0, -40.0], [0.0, 20.0, -40.0], [np.nan] * 3])
    for preset in ("default", "course"):
        est = FastEKF(preset)
        est.run_batch(t, gyr, acc, mag)
        est.step(0.04, gyr[0], acc[0], mag[0])
        est.update_gyr(0.05, gyr[0])
        est.step(0.06)
