"""Compiled time update (eq. 6 and task 12): the gyroscope drives q and P (the covariance
hand-unrolled: the q rows of A P, then the symmetric q block with the process noise), or, without
a gyroscope sample, P grows by a random walk; the carried accelerometer low-pass turns along.
"""

from __future__ import annotations

import math

from ekf.fast._jit import CACHE_KEY, check_cache, jit
from ekf.fast.algebra import _add_attitude_cov, _flip_sign, _normalise
from ekf.fast.layout import C, S


@jit
def _carry(s, wx, wy, wz, rate, cs, sn):
    """reference ``_carry``: turn the carried specific force into the new body frame,
    v <- R(w T)^T v (Rodrigues; cs, sn: cosine and sine of the angle |w| T)."""
    if rate < 1e-12:
        return
    kx = wx / rate
    ky = wy / rate
    kz = wz / rate
    v0 = s[S.acc_carried]
    v1 = s[S.acc_carried + 1]
    v2 = s[S.acc_carried + 2]
    kv = kx * v0 + ky * v1 + kz * v2
    # R^T v = v cos - (k x v) sin + k (k.v)(1 - cos)
    cx = ky * v2 - kz * v1
    cy = kz * v0 - kx * v2
    cz = kx * v1 - ky * v0
    s[S.acc_carried] = v0 * cs - cx * sn + kx * kv * (1 - cs)
    s[S.acc_carried + 1] = v1 * cs - cy * sn + ky * kv * (1 - cs)
    s[S.acc_carried + 2] = v2 * cs - cz * sn + kz * kv * (1 - cs)


@jit
def _carry_along(s, c, T, wx, wy, wz, rate, sinc, cs):
    """Turn the carried low-pass by the rotation |w| T of this time update: with the exact F,
    cos = 2 cos^2(half) - 1 and sin = 2 sin(half) cos(half) from F's entries; with the course's
    F the same exact rotation from |w| T."""
    if c[C.exact_discretisation] != 0.0:
        _carry(s, wx, wy, wz, rate, 2.0 * cs * cs - 1.0, 2.0 * sinc * rate * cs)
    else:
        r = math.sqrt(wx * wx + wy * wy + wz * wz)
        _carry(s, wx, wy, wz, r, math.cos(r * T), math.sin(r * T))


@jit
def _turn_pair(s, F):
    """The hard-iron fit's open pair: its turn since the first reading, from the gyro alone
    (mag_pair_q <- F mag_pair_q, the reference's _time_update_gyro)."""
    M = S.mag_pair_q
    p0, p1, p2, p3 = s[M], s[M + 1], s[M + 2], s[M + 3]
    for i in range(4):
        s[M + i] = F[i][0] * p0 + F[i][1] * p1 + F[i][2] * p2 + F[i][3] * p3


@jit
def _time_update_gyro_n(s, c, T, n):
    """reference ``_time_update_gyro``: q = F q, P = A P A^T + Q with A = [[F, -G], [0, I]]."""
    q0, q1, q2, q3 = s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3]
    if n == 7:   # w = sample - bias
        wx, wy, wz = (s[S.omega] - s[S.x + 4], s[S.omega + 1] - s[S.x + 5],
                      s[S.omega + 2] - s[S.x + 6])
    else:
        wx, wy, wz = (s[S.omega] - c[C.gyr_bias], s[S.omega + 1] - c[C.gyr_bias + 1],
                      s[S.omega + 2] - c[C.gyr_bias + 2])
    if c[C.exact_discretisation] != 0.0:
        rate = math.sqrt(wx * wx + wy * wy + wz * wz)
        half = 0.5 * rate * T
        sinc = (math.sin(half) / rate) if rate > 1e-12 else 0.5 * T
        cs = math.cos(half)
    else:
        rate = 0.0   # not used: the carried vector turns by the exact rotation below
        sinc = 0.5 * T
        cs = 1.0
    ax, ay, az = sinc * wx, sinc * wy, sinc * wz
    if s[S.acc_carried_valid] != 0.0 and sinc * cs != 0.0:
        _carry_along(s, c, T, wx, wy, wz, rate, sinc, cs)
    F = ((cs, -ax, -ay, -az), (ax, cs, az, -ay), (ay, -az, cs, ax), (az, ay, -ax, cs))
    h = 0.5 * T
    G = ((h * -q1, h * -q2, h * -q3), (h * q0, h * -q3, h * q2),
         (h * q3, h * q0, h * -q1), (h * -q2, h * q1, h * q0))
    P = S.P
    AP = S.work_gain
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
    R = C.gyr_noise_cov
    extra = c[C.gyr_scale_noise] ** 2 * (wx * wx + wy * wy + wz * wz)
    isotropic = c[C.gyr_noise_isotropic] != 0.0
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
        qb = c[C.gyro_bias_random_walk] ** 2 * T
        for i in range(4, 7):
            s[P + 8 * i] += qb
    for i in range(4):
        s[S.x + i] = F[i][0] * q0 + F[i][1] * q1 + F[i][2] * q2 + F[i][3] * q3
    if c[C.mag_hard_iron_tau_s] > 0.0 and not math.isnan(s[S.mag_pair_t]):
        _turn_pair(s, F)


@jit
def _time_update_gyro(s, c, T):
    # n = 4 or 7 as a compile-time constant: fixed loops are unrolled.
    if int(s[S.n]) == 7:
        return _time_update_gyro_n(s, c, T, 7)
    return _time_update_gyro_n(s, c, T, 4)


@jit
def _time_update_random_walk(s, c, T):
    """reference ``_time_update_random_walk``: q stays, P grows."""
    _add_attitude_cov(s, 0.25 * T * c[C.no_gyro_random_walk] ** 2)
    if int(s[S.n]) == 7:
        qb = c[C.gyro_bias_random_walk] ** 2 * T
        for i in range(4, 7):
            s[S.P + 8 * i] += qb


@jit
def _record_prediction(s, T):
    """For the smoother (c[C.record_prediction]): x, P and T right after a time update."""
    for i in range(7):
        s[S.work_pred_x + i] = s[S.x + i]
    for i in range(49):
        s[S.work_pred_P + i] = s[S.P + i]
    s[S.work_pred_T] = T
    for i in range(3):
        s[S.work_pred_omega + i] = s[S.omega + i]


@jit
def _advance(s, c, t):
    """reference ``_advance``: move the state to time t with the held gyro sample."""
    if math.isnan(s[S.t]):
        s[S.t] = t
        return
    dt = t - s[S.t]
    if dt <= 0.0:
        return
    t_prev = s[S.t]
    s[S.t] = t
    if s[S.initialised] == 0.0:
        return
    if dt > c[C.max_dt]:
        s[S.used_gyr] = 0.0
        s[S.acc_carried_valid] = 0.0
        return
    if (s[S.omega_valid] != 0.0 and s[S.gyr_enabled] != 0.0
            and t_prev - s[S.omega_t] <= c[C.gyr_hold_s]):
        _time_update_gyro(s, c, dt)
        s[S.used_gyr] = 1.0
        if c[C.exact_discretisation] == 0.0:
            _normalise(s)
        elif s[S.x] < 0.0:
            _flip_sign(s)
        if c[C.record_prediction] != 0.0:
            _record_prediction(s, dt)
    else:
        _time_update_random_walk(s, c, dt)
        s[S.used_gyr] = 0.0
        _normalise(s)
        if c[C.record_prediction] != 0.0:
            _record_prediction(s, 0.0)


@jit
def _compiled_cache_key():
    return CACHE_KEY


check_cache(_compiled_cache_key, globals())
