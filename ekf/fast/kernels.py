"""The reference EKF compiled with numba: :mod:`ekf.reference`'s functions, one for one, with
the same names in the same order and in the same sections, so each line maps to a formula of
the course and then to its compiled twin (tests/ekf/test_fast.py derives both lists of names
from the code and compares them; a name ending in ``_n`` is the n-specialised body of the
function before it, compiled once for n = 4 and once for n = 7 so that fixed loops unroll).

A twin takes the packed state ``s`` (layout ``S``) and settings ``c`` (layout ``C``) instead of
``self``, and vectors as their three components. The arithmetic is the reference's; only the
order of floating-point operations differs where structure is exploited exactly (the
hand-unrolled hot spots: time-update covariance, Joseph update, normalisation; see
``ekf.fast``). What numpy, ``ekf.quaternion`` and the generic Joseph form do for the reference
are the building blocks of :mod:`ekf.fast.algebra`, which have no twin.
"""

from __future__ import annotations

import math

from ekf.diagnostics import (ACC_CLIPPED, ACC_NIS_GATE, ACC_NORM_GATE, MAG_DIP_GATE, MAG_NIS_GATE,
                             MAG_SETTLING, MAG_STRENGTH_GATE, MAG_UNCALIBRATED, NOT_REJECTED)
from ekf.fast.algebra import (add_attitude_cov, add_pair, correct_state, cross, field_dip_deg,
                              from_matrix, heading_of, inverse_plus, joseph_any_gain,
                              joseph_optimal_gain, known_everywhere, level_m0,
                              measurement_blocks, optimal_gain, quat_normalize,
                              record_prediction, set_attitude_cov, to_matrix, turn_pair)
from ekf.fast.jit import CACHE_KEY, check_cache, jit
from ekf.fast.layout import C, S
from ekf.reference import (ACQUIRED_INFO, ACQUIRING_PRIOR, CLIP_MARGIN, CLIP_MIN_G,
                           EARTH_FIELD_MAX, HARD_IRON_PAIR_ANGLE, HARD_IRON_PAIR_MAX_S,
                           HARD_IRON_RESIDUAL, HARD_IRON_RESTART_RESIDUAL,
                           HARD_IRON_RESTART_TAU_S, MAX_READING, MIN_NORM)

# bits of step's `present` mask
GYR = 1
ACC = 2
MAG = 4

_INF = math.inf
_NAN = math.nan


# ---- start quaternions and degenerate samples (module functions of ekf.reference) ---------

@jit
def usable(t, v0, v1, v2, needs_direction):
    """ekf.reference.usable: finite time and values within MAX_READING, and (acc, mag) a
    direction."""
    if not (math.isfinite(t) and math.isfinite(v0) and math.isfinite(v1)
            and math.isfinite(v2)):
        return False
    if abs(v0) > MAX_READING or abs(v1) > MAX_READING or abs(v2) > MAX_READING:
        return False
    return not needs_direction or math.sqrt(v0 * v0 + v1 * v1 + v2 * v2) >= MIN_NORM


@jit
def tilt_quaternion(a0, a1, a2):
    """ekf.reference.tilt_quaternion."""
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    u0 = a0 / na
    u1 = a1 / na
    u2 = a2 / na
    if abs(u0) < 0.9:
        n0, n1, n2 = cross(u0, u1, u2, 1.0, 0.0, 0.0)
    else:
        n0, n1, n2 = cross(u0, u1, u2, 0.0, 1.0, 0.0)
    nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    n0 /= nn
    n1 /= nn
    n2 /= nn
    e0, e1, e2 = cross(n0, n1, n2, u0, u1, u2)
    q0, q1, q2, q3 = from_matrix(e0, e1, e2, n0, n1, n2, u0, u1, u2)
    return _rotate_world_about_up(q0, q1, q2, q3, -heading_of(q0, q1, q2, q3))


@jit
def acc_mag_quaternion(a0, a1, a2, m0, m1, m2):
    """ekf.reference.acc_mag_quaternion (TRIAD)."""
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    u0 = a0 / na
    u1 = a1 / na
    u2 = a2 / na
    e0, e1, e2 = cross(m0, m1, m2, u0, u1, u2)
    ne = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    e0 /= ne
    e1 /= ne
    e2 /= ne
    n0, n1, n2 = cross(u0, u1, u2, e0, e1, e2)
    return from_matrix(e0, e1, e2, n0, n1, n2, u0, u1, u2)


@jit
def _rotate_world_about_up(q0, q1, q2, q3, angle):
    """normalize(from_axis_angle(z, angle) ⊗ q)."""
    c = math.cos(angle / 2)
    sn = math.sin(angle / 2)
    return quat_normalize(c * q0 - sn * q3, c * q1 - sn * q2, c * q2 + sn * q1, c * q3 + sn * q0)


@jit
def _elevation_deg(v0, v1, v2):
    """reference ``_elevation_deg``: angle of a world-frame vector above the horizontal."""
    return math.degrees(math.atan2(v2, math.hypot(v0, v1)))


# ---- sample entry points ------------------------------------------------------------------

@jit
def update_gyr(s, c, t, v0, v1, v2):
    """reference ``update_gyr``."""
    if not _accept(s, t, v0, v1, v2, False):
        return
    t = _not_before(s, t)
    if c[C.gyr_rate_before_sample] != 0.0 and s[S.gyr_enabled] != 0.0:
        # the sample is the rate over the interval ending now: it drives the state up to t
        if s[S.omega_valid] == 0.0 or t - s[S.omega_t] <= c[C.gyr_hold_s]:
            s[S.omega] = v0
            s[S.omega + 1] = v1
            s[S.omega + 2] = v2
            s[S.omega_valid] = 1.0
        _advance(s, c, t)
    else:
        _advance(s, c, t)
    if s[S.gyr_enabled] == 0.0:
        return
    s[S.omega] = v0
    s[S.omega + 1] = v1
    s[S.omega + 2] = v2
    s[S.omega_valid] = 1.0
    s[S.omega_t] = t
    if s[S.initialised] == 0.0 and s[S.acc_enabled] == 0.0 and s[S.mag_enabled] == 0.0:
        _initialise(s, c, t)   # gyroscope alone: nothing absolute, start at identity (flat)
    _detect_rest_gyr(s, c, t, v0, v1, v2)
    if (int(s[S.n]) == 7 and s[S.initialised] != 0.0 and s[S.at_rest] != 0.0
            and t - s[S.rest_updated_t] >= c[C.update_period_s]):
        s[S.rest_updated_t] = t
        _zero_rate_update(s, c, v0, v1, v2)


@jit
def update_acc(s, c, t, v0, v1, v2):
    """reference ``update_acc``."""
    if not _accept(s, t, v0, v1, v2, True):
        return
    t = _not_before(s, t)
    _advance(s, c, t)
    s[S.last_acc] = v0
    s[S.last_acc + 1] = v1
    s[S.last_acc + 2] = v2
    s[S.last_acc_valid] = 1.0
    s[S.last_acc_t] = t
    if s[S.acc_enabled] == 0.0:
        s[S.used_acc] = 0.0
        return
    if _clipped(s, c, v0, v1, v2):
        # a saturated axis: no update, no average, no start; motion for the rest detector
        s[S.acc_rejected] = 1.0
        s[S.used_acc] = 0.0
        s[S.acc_norm] = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        s[S.acc_rejected_by] = ACC_CLIPPED
        if c[C.acc_lowpass_s] > 0.0:
            _shaking(s, c, t, v0, v1, v2)
        s[S.last_motion_t] = t
        _update_rest(s, c, t)
        return
    _detect_rest_acc(s, c, t, v0, v1, v2)
    if s[S.initialised] == 0.0:
        _initialise(s, c, t)
        return
    tau = c[C.acc_lowpass_s]
    if tau > 0.0 and s[S.gyr_enabled] != 0.0 and s[S.used_gyr] != 0.0:
        _acc_lowpass_update(s, c, t, v0, v1, v2, tau)
    else:
        # no gyroscope drives the filter (off, none, silent): the reading itself
        s[S.acc_carried_valid] = 0.0
        _acc_update(s, c, v0, v1, v2, c[C.acc_gate], 1.0)


@jit
def update_mag(s, c, t, v0, v1, v2):
    """reference ``update_mag``."""
    if not _accept(s, t, v0, v1, v2, True):
        return
    t = _not_before(s, t)
    _advance(s, c, t)
    if (c[C.mag_hard_iron_tau_s] > 0.0 and s[S.mag_enabled] != 0.0
            and s[S.initialised] != 0.0):
        _fit_hard_iron(s, c, t, v0, v1, v2)
        _explaining_offset(s, c, v0, v1, v2)
        v0 -= s[S.mag_offset]
        v1 -= s[S.mag_offset + 1]
        v2 -= s[S.mag_offset + 2]
        if math.sqrt(v0 * v0 + v1 * v1 + v2 * v2) < MIN_NORM:
            return
    s[S.last_mag] = v0
    s[S.last_mag + 1] = v1
    s[S.last_mag + 2] = v2
    s[S.last_mag_valid] = 1.0
    s[S.last_mag_t] = t
    if s[S.mag_enabled] == 0.0:
        s[S.used_mag] = 0.0
        return
    if s[S.initialised] == 0.0:
        if s[S.acc_enabled] == 0.0:
            _initialise(s, c, t)
        return
    if s[S.mag_waiting] != 0.0 and s[S.used_gyr] != 0.0:
        # uncalibrated: its offset is being acquired (_check_uncalibrated)
        s[S.used_mag] = 0.0
        s[S.mag_rejected] = 1.0
        s[S.mag_rejected_by] = MAG_UNCALIBRATED
        s[S.mag_norm] = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        return
    if s[S.heading_from_mag] == 0.0:
        _take_heading_from_mag(s, c, v0, v1, v2)
        return
    _mag_update(s, c, v0, v1, v2, t)
    _check_uncalibrated(s, c)


@jit
def step(s, c, t, present, g0, g1, g2, a0, a1, a2, m0, m1, m2):
    """reference ``step``, the one dispatch: the samples present at time t (bit mask: GYR 1,
    ACC 2, MAG 4; 0 only moves the clock), in the order gyroscope, accelerometer, magnetometer.
    Used by FastEKF.step, update_gyr/acc/mag and the batch loop."""
    if present & GYR:
        update_gyr(s, c, t, g0, g1, g2)
    if present & ACC:
        update_acc(s, c, t, a0, a1, a2)
    if present & MAG:
        update_mag(s, c, t, m0, m1, m2)
    if present == 0 and _accept(s, t, 0.0, 0.0, 0.0, False):
        _advance(s, c, _not_before(s, t))


@jit
def _accept(s, t, v0, v1, v2, needs_direction):
    """reference ``_accept``: a degenerate sample is refused and counted."""
    if usable(t, v0, v1, v2, needs_direction):
        return True
    s[S.refused_samples] += 1.0
    return False


@jit
def _not_before(s, t):
    """reference ``_not_before``: a late sample counts as at the latest time."""
    if math.isnan(s[S.t]) or t >= s[S.t]:
        return t
    return s[S.t]


@jit
def _clipped(s, c, y0, y1, y2):
    """reference ``_clipped``: an axis at the accelerometer's range (set, or seen)."""
    largest = max(abs(y0), abs(y1), abs(y2))
    if largest > s[S.acc_axis_max]:
        s[S.acc_axis_max] = largest
    if c[C.acc_range] == 0.0:
        return (s[S.acc_axis_max] >= CLIP_MIN_G * c[C.g]
                and largest >= CLIP_MARGIN * s[S.acc_axis_max])
    return largest >= c[C.acc_range]


# ---- the start ----------------------------------------------------------------------------

@jit
def _initialise(s, c, t):
    """reference ``_initialise``: orientation from the latest enabled acc/mag readings."""
    n = int(s[S.n])
    acc_ok = s[S.acc_enabled] != 0.0 and s[S.last_acc_valid] != 0.0
    mag_ok = (s[S.mag_enabled] != 0.0 and s[S.last_mag_valid] != 0.0
              and t - s[S.last_mag_t] <= 0.1)
    a0 = s[S.last_acc]
    a1 = s[S.last_acc + 1]
    a2 = s[S.last_acc + 2]
    m0 = s[S.last_mag]
    m1 = s[S.last_mag + 1]
    m2 = s[S.last_mag + 2]
    if acc_ok and mag_ok:
        x0, x1, x2 = cross(m0, m1, m2, a0, a1, a2)
        if (math.sqrt(x0 * x0 + x1 * x1 + x2 * x2) <= 1e-6 * math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
                * math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)):
            mag_ok = False   # a field along gravity has no heading: tilt now, heading later
    if acc_ok and mag_ok:
        q = acc_mag_quaternion(a0, a1, a2, m0, m1, m2)
        s[S.heading_from_mag] = 1.0
    elif acc_ok:
        q = tilt_quaternion(a0, a1, a2)
    elif mag_ok:
        half = math.atan2(m0, m1) / 2
        q = (math.cos(half), 0.0, 0.0, math.sin(half))
        s[S.heading_from_mag] = 1.0
    else:
        q = (1.0, 0.0, 0.0, 0.0)
    q = quat_normalize(q[0], q[1], q[2], q[3])
    for i in range(4):
        s[S.x + i] = q[i]
    for i in range(49):
        s[S.P + i] = 0.0
    set_attitude_cov(s, 0.25 * c[C.initial_attitude_std] ** 2)
    if not (acc_ok and mag_ok):
        add_attitude_cov(s, 0.25)
    if n == 7:
        vb = c[C.initial_gyro_bias_std] ** 2
        for i in range(4, 7):
            s[S.P + 8 * i] = vb
    s[S.initialised] = 1.0
    if (s[S.heading_from_mag] != 0.0 and s[S.m0_valid] == 0.0
            and s[S.last_mag_valid] != 0.0):
        _set_m0_from(s, c, m0, m1, m2)


@jit
def _take_heading_from_mag(s, c, y0, y1, y2):
    """reference ``_take_heading_from_mag``."""
    Q = to_matrix(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3])
    mw0 = Q[0] * y0 + Q[1] * y1 + Q[2] * y2
    mw1 = Q[3] * y0 + Q[4] * y1 + Q[5] * y2
    if mw0 ** 2 + mw1 ** 2 < 1e-6:
        return
    psi, _d0, _d1 = _heading_error(s, mw0, mw1)
    q = _rotate_world_about_up(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3], -psi)
    for i in range(4):
        s[S.x + i] = q[i]
    set_attitude_cov(s, 0.25 * c[C.initial_attitude_std] ** 2)
    # a fresh attitude is uncorrelated with the bias estimate (no-op when n = 4)
    for i in range(4):
        for j in range(4, 7):
            s[S.P + 7 * i + j] = 0.0
            s[S.P + 7 * j + i] = 0.0
    s[S.heading_from_mag] = 1.0
    if s[S.m0_valid] == 0.0:
        _set_m0_from(s, c, y0, y1, y2)


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


# ---- rest detection -----------------------------------------------------------------------

@jit
def _detect_rest_gyr(s, c, t, w0, w1, w2):
    """reference ``_detect_rest_gyr``."""
    if int(s[S.n]) == 7:
        d0 = w0 - s[S.x + 4]
        d1 = w1 - s[S.x + 5]
        d2 = w2 - s[S.x + 6]
    else:
        d0 = w0 - c[C.gyr_bias]
        d1 = w1 - c[C.gyr_bias + 1]
        d2 = w2 - c[C.gyr_bias + 2]
    if math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) > c[C.rest_gyr_threshold]:
        s[S.last_motion_t] = t
    _update_rest(s, c, t)


@jit
def _detect_rest_acc(s, c, t, y0, y1, y2):
    """reference ``_detect_rest_acc``."""
    L = S.acc_lowpass
    if s[S.acc_lowpass_valid] == 0.0:
        s[L] = y0
        s[L + 1] = y1
        s[L + 2] = y2
        s[S.acc_lowpass_valid] = 1.0
    s[L] = 0.9 * s[L] + 0.1 * y0
    s[L + 1] = 0.9 * s[L + 1] + 0.1 * y1
    s[L + 2] = 0.9 * s[L + 2] + 0.1 * y2
    d0 = y0 - s[L]
    d1 = y1 - s[L + 1]
    d2 = y2 - s[L + 2]
    if math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) > c[C.rest_acc_threshold]:
        s[S.last_motion_t] = t
    _update_rest(s, c, t)


@jit
def _update_rest(s, c, t):
    """reference ``_update_rest``."""
    if s[S.gyr_enabled] == 0.0 and s[S.acc_enabled] == 0.0:
        s[S.at_rest] = 0.0
        return
    if s[S.last_motion_t] == -_INF:
        s[S.last_motion_t] = t
    s[S.at_rest] = 1.0 if t - s[S.last_motion_t] >= c[C.rest_min_duration] else 0.0


# ---- the time update (eq. 6, task 12) -----------------------------------------------------

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
            record_prediction(s, dt)
    else:
        _time_update_random_walk(s, c, dt)
        s[S.used_gyr] = 0.0
        _normalise(s)
        if c[C.record_prediction] != 0.0:
            record_prediction(s, 0.0)


@jit
def _time_update_gyro(s, c, T):
    # n = 4 or 7 as a compile-time constant: fixed loops are unrolled.
    if int(s[S.n]) == 7:
        return _time_update_gyro_n(s, c, T, 7)
    return _time_update_gyro_n(s, c, T, 4)


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
        _carry(s, c, T, wx, wy, wz, rate, sinc, cs)
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
        turn_pair(s, F)


@jit
def _carry(s, c, T, wx, wy, wz, rate, sinc, cs):
    """reference ``_carry``: turn the carried specific force into the new body frame,
    v <- R(w T)^T v (Rodrigues), by the rotation |w| T of this time update: with the exact F,
    cos = 2 cos^2(half) - 1 and sin = 2 sin(half) cos(half) from F's entries; with the course's
    F the same exact rotation from |w| T."""
    if c[C.exact_discretisation] != 0.0:
        sn = 2.0 * sinc * rate * cs
        cs = 2.0 * cs * cs - 1.0
    else:
        rate = math.sqrt(wx * wx + wy * wy + wz * wz)
        cs = math.cos(rate * T)
        sn = math.sin(rate * T)
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
def _time_update_random_walk(s, c, T):
    """reference ``_time_update_random_walk``: q stays, P grows."""
    add_attitude_cov(s, 0.25 * T * c[C.no_gyro_random_walk] ** 2)
    if int(s[S.n]) == 7:
        qb = c[C.gyro_bias_random_walk] ** 2 * T
        for i in range(4, 7):
            s[S.P + 8 * i] += qb


# ---- the accelerometer update (tasks 6 and 8) ---------------------------------------------

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
    nis = _update(s, c, h, y0 - yh0, y1 - yh1, y2 - yh2, C.acc_noise_cov, gate, noise_scale,
                  _magnetometer_silent(s, c))
    s[S.acc_nis] = nis
    accepted = nis <= gate
    s[S.acc_rejected] = 0.0 if accepted else 1.0
    s[S.used_acc] = 1.0 if accepted else 0.0
    s[S.acc_rejected_by] = NOT_REJECTED if accepted else ACC_NIS_GATE


@jit
def _magnetometer_silent(s, c):
    """reference ``_magnetometer_silent``: acc_tilt_only_after_s without a magnetometer update
    (or none ever)."""
    after = c[C.acc_tilt_only_after_s]
    return after < _INF and not s[S.t] - s[S.mag_updated_t] < after


@jit
def _tilt_only(s, n):
    """reference ``_tilt_only``, applied to the gain K at S.work_gain: without its component
    along a turn about world up in q (u, the direction of (0,0,0,1) ⊗ q) and along up in the
    bias (v, the third row of Q(q))."""
    q0, q1, q2, q3 = s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3]
    u = (-q3, -q2, q1, q0)
    inv_uu = 1.0 / (q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    v = (2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3)
    inv_vv = 1.0 / (v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    K = S.work_gain
    for r in range(3):
        uk = (u[0] * s[K + r] + u[1] * s[K + 3 + r] + u[2] * s[K + 6 + r]
              + u[3] * s[K + 9 + r]) * inv_uu
        for i in range(4):
            s[K + 3 * i + r] -= uk * u[i]
        if n == 7:
            vk = (v[0] * s[K + 12 + r] + v[1] * s[K + 15 + r] + v[2] * s[K + 18 + r]) * inv_vv
            for i in range(3):
                s[K + 3 * (4 + i) + r] -= vk * v[i]


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


# ---- the magnetometer update (tasks 9 and 11, footnote 2) ---------------------------------

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
        Q = to_matrix(q0, q1, q2, q3)
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
        nis = _update(s, c, h, y0 - yh0, y1 - yh1, y2 - yh2, C.mag_noise_cov, c[C.mag_nis_gate],
                      noise_scale)
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
    _count_confirmed(s, c, t)
    s[S.mag_disturbed_time] = 0.0
    s[S.mag_disturbed_t] = _NAN
    s[S.mag_passed_t] = t


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
def _mag_heading_update(s, c, y0, y1, y2, gate, noise_scale, gain_cap):
    # n = 4 or 7 as a compile-time constant: fixed loops are unrolled.
    if int(s[S.n]) == 7:
        return _mag_heading_update_n(s, c, y0, y1, y2, 7, gate, noise_scale, gain_cap)
    return _mag_heading_update_n(s, c, y0, y1, y2, 4, gate, noise_scale, gain_cap)


@jit
def _mag_heading_update_n(s, c, y0, y1, y2, n, gate, noise_scale, gain_cap):
    """reference ``_mag_heading_update``: heading pseudo-measurement, gain projected on a turn
    about world up, at most `gain_cap` of the innovation corrected (mag_return_s). Returns the
    NIS (NaN when the field is vertical: no update)."""
    q0 = s[S.x]
    q1 = s[S.x + 1]
    q2 = s[S.x + 2]
    q3 = s[S.x + 3]
    Q = to_matrix(q0, q1, q2, q3)
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


# ---- the Joseph-form update, the zero-rate update and the normalisation -------------------

@jit
def _update(s, c, h, e0, e1, e2, cov, gate, scale=1.0, tilt_only=False):
    # n = 4 or 7 as a compile-time constant: fixed loops are unrolled.
    if int(s[S.n]) == 7:
        return _update_n(s, c, h, e0, e1, e2, cov, gate, 7, scale, tilt_only)
    return _update_n(s, c, h, e0, e1, e2, cov, gate, 4, scale, tilt_only)


@jit
def _update_n(s, c, h, e0, e1, e2, cov, gate, n, scale, tilt_only):
    """reference ``_update`` for a measurement whose H (3 x n) is non-zero only in the q
    columns (h: the 3x4 block, row-major; cov: the offset of R in the settings, R x scale),
    in Joseph form; returns the NIS, the state untouched when it exceeds `gate`. tilt_only:
    the gain projected by ``_tilt_only`` (the reference's `keep`)."""
    measurement_blocks(s, c, h, cov, scale, n)
    nis = optimal_gain(s, e0, e1, e2, gate, n)
    if nis > gate:
        return nis
    if tilt_only:
        _tilt_only(s, n)
        correct_state(s, e0, e1, e2, n)
        joseph_any_gain(s, n)
    else:
        correct_state(s, e0, e1, e2, n)
        joseph_optimal_gain(s, n)
    _normalise(s)
    return nis


@jit
def _zero_rate_update(s, c, w0, w1, w2):
    """reference ``_zero_rate_update``: H = [0 I], R = I std^2, innovation omega - b."""
    B = S.work_pht
    P = S.P
    for i in range(7):
        for r in range(3):
            s[B + 3 * i + r] = s[P + 7 * i + 4 + r]
    var = c[C.rest_rate_noise_std] ** 2
    for r in range(3):
        for col in range(3):
            s[S.work_s + 3 * r + col] = s[P + 7 * (4 + r) + 4 + col] + (var if r == col else 0.0)
    e0 = w0 - s[S.x + 4]
    e1 = w1 - s[S.x + 5]
    e2 = w2 - s[S.x + 6]
    optimal_gain(s, e0, e1, e2, _INF, 7)
    correct_state(s, e0, e1, e2, 7)
    joseph_optimal_gain(s, 7)
    _normalise(s)


@jit
def _flip_sign(s):
    """reference ``_flip_sign``: q <- -q (same rotation, w >= 0); P_qb changes sign."""
    for i in range(4):
        s[S.x + i] = -s[S.x + i]
    if int(s[S.n]) == 7:
        for i in range(4):
            for j in range(4, 7):
                v = -s[S.P + 7 * i + j]
                s[S.P + 7 * i + j] = v
                s[S.P + 7 * j + i] = v


@jit
def _normalise(s):
    """q <- q/|q| (w >= 0), P <- J P J^T with J = (I - u u^T)/|q| on the q block, u = q/|q|.

    J P J^T = (P - u w^T - w u^T + (u.w) u u^T)/|q|^2 with w = P_qq u; the q-bias block is
    J P_qb. The sign flip for w >= 0 multiplies J by -1 (cancels in the q block)."""
    n = int(s[S.n])
    q0 = s[S.x]
    q1 = s[S.x + 1]
    q2 = s[S.x + 2]
    q3 = s[S.x + 3]
    norm = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    inv_norm = 1.0 / norm   # one division on the critical path instead of six
    u = (q0 * inv_norm, q1 * inv_norm, q2 * inv_norm, q3 * inv_norm)
    sign = -1.0 if u[0] < 0.0 else 1.0
    for i in range(4):
        s[S.x + i] = sign * u[i]
    P = S.P
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


# ---- the online hard-iron fit -------------------------------------------------------------

@jit
def _fit_hard_iron(s, c, t, y0, y1, y2):
    """reference ``_fit_hard_iron``: pairs of readings turned >= 20 deg apart (the turn
    integrated from the gyroscope, mag_pair_q), D b = e with D = I - A, e = y_j - A y_i,
    A = Q(turn)^T; weighted sums with forgetting; b solved."""
    y0, y1, y2 = _turned_to_stamp(s, c, y0, y1, y2)
    if math.isnan(s[S.mag_pair_t]) or t - s[S.mag_pair_t] > HARD_IRON_PAIR_MAX_S:
        _open_pair(s, t, y0, y1, y2)
        return
    P = S.mag_pair_q
    inv = 1.0 / math.sqrt(s[P] ** 2 + s[P + 1] ** 2 + s[P + 2] ** 2 + s[P + 3] ** 2)
    if 2.0 * math.acos(min(1.0, abs(s[P] * inv))) < HARD_IRON_PAIR_ANGLE:
        return
    Qt = to_matrix(s[P] * inv, s[P + 1] * inv, s[P + 2] * inv, s[P + 3] * inv)
    # D = I - A with A = Q(turn)^T, e = y - A y_i, r = e - D b
    R = S.mag_pair_raw
    B = S.mag_offset_fit
    D = S.work_s          # scratch 3x3
    e = S.work_pht        # scratch: e (3), then r (3)
    for r in range(3):
        for k in range(3):
            s[D + 3 * r + k] = (1.0 if r == k else 0.0) - Qt[3 * k + r]
    yv = (y0, y1, y2)
    for r in range(3):
        # A y_i = y_i - D y_i
        ay = s[R + r] - (s[D + 3 * r] * s[R] + s[D + 3 * r + 1] * s[R + 1]
                         + s[D + 3 * r + 2] * s[R + 2])
        s[e + r] = yv[r] - ay
        s[e + 3 + r] = s[e + r] - (s[D + 3 * r] * s[B] + s[D + 3 * r + 1] * s[B + 1]
                                   + s[D + 3 * r + 2] * s[B + 2])
    residual = math.sqrt(s[e + 3] ** 2 + s[e + 4] ** 2 + s[e + 5] ** 2)
    w = min(1.0, HARD_IRON_RESIDUAL / residual) if residual > 0.0 else 1.0
    forget = 0.0
    if math.isfinite(s[S.mag_offset_t]):
        forget = math.exp(-(t - s[S.mag_offset_t]) / c[C.mag_hard_iron_tau_s])
    if s[S.mag_acquiring] != 0.0:
        w = 1.0                          # large residuals: the offset is far, not new
    elif residual > HARD_IRON_RESTART_RESIDUAL or (
            residual > HARD_IRON_RESIDUAL and math.isfinite(s[S.mag_restart_t])):
        _restart_evidence(s, t)
    M = S.mag_offset_info
    V = S.mag_offset_rhs
    add_pair(s, M, V, forget, w)
    s[S.mag_offset_t] = t
    if s[S.mag_acquiring] == 0.0 and _restart_due(s):
        # a new offset: the fit starts again from the pairs that revealed it
        for i in range(9):
            s[M + i] = s[S.mag_restart_info + i]
        for i in range(3):
            s[V + i] = s[S.mag_restart_rhs + i]
        _drop_restart(s)
    # b = (M + prior I)^-1 (v + prior b_prior) (M symmetric positive semi-definite)
    prior = ACQUIRING_PRIOR if s[S.mag_acquiring] != 0.0 else c[C.mag_hard_iron_prior]
    c00, c01, c02, c11, c12, c22, inv_det = inverse_plus(s, S.mag_offset_info, prior)
    v0 = s[V] + prior * s[S.mag_offset_prior]
    v1 = s[V + 1] + prior * s[S.mag_offset_prior + 1]
    v2 = s[V + 2] + prior * s[S.mag_offset_prior + 2]
    s[B] = (c00 * v0 + c01 * v1 + c02 * v2) * inv_det
    s[B + 1] = (c01 * v0 + c11 * v1 + c12 * v2) * inv_det
    s[B + 2] = (c02 * v0 + c12 * v1 + c22 * v2) * inv_det
    _acquisition_progress(s, y0, y1, y2)
    _open_pair(s, t, y0, y1, y2)


@jit
def _restart_evidence(s, t):
    """reference ``_restart_evidence``: the pair (D in work_s, e in work_pht) into the second
    fit's sums, forgotten with HARD_IRON_RESTART_TAU_S; the first pair only opens it."""
    if math.isnan(s[S.mag_restart_t]):
        s[S.mag_restart_t] = t
        return
    forget = math.exp(-(t - s[S.mag_restart_t]) / HARD_IRON_RESTART_TAU_S)
    add_pair(s, S.mag_restart_info, S.mag_restart_rhs, forget, 1.0)
    e = S.work_pht
    s[S.mag_restart_sq] = forget * s[S.mag_restart_sq] + (s[e] ** 2 + s[e + 1] ** 2
                                                          + s[e + 2] ** 2)
    s[S.mag_restart_n] = forget * s[S.mag_restart_n] + 1.0
    s[S.mag_restart_t] = t


@jit
def _restart_due(s):
    """reference ``_restart_due``: the second fit knows every direction, explains its pairs
    within HARD_IRON_RESIDUAL (RMS) and the fit's offset does not (beyond
    HARD_IRON_RESTART_RESIDUAL); dropped when the fit explains them or nothing came for
    HARD_IRON_RESTART_TAU_S."""
    if math.isnan(s[S.mag_restart_t]):
        return False
    if s[S.mag_offset_t] - s[S.mag_restart_t] > HARD_IRON_RESTART_TAU_S:
        _drop_restart(s)
        return False
    n = s[S.mag_restart_n]
    if n == 0.0:
        return False
    M = S.mag_restart_info
    V = S.mag_restart_rhs
    B = S.mag_offset_fit
    bv = s[B] * s[V] + s[B + 1] * s[V + 1] + s[B + 2] * s[V + 2]
    bmb = 0.0
    for r in range(3):
        for k in range(3):
            bmb += s[B + r] * s[M + 3 * r + k] * s[B + k]
    if (s[S.mag_restart_sq] - 2.0 * bv + bmb) / n <= HARD_IRON_RESTART_RESIDUAL ** 2:
        _drop_restart(s)
        return False
    if not known_everywhere(s, M):
        return False
    c00, c01, c02, c11, c12, c22, inv_det = inverse_plus(s, M, 0.0)
    v0 = s[V]
    v1 = s[V + 1]
    v2 = s[V + 2]
    cv = (v0 * (c00 * v0 + c01 * v1 + c02 * v2) + v1 * (c01 * v0 + c11 * v1 + c12 * v2)
          + v2 * (c02 * v0 + c12 * v1 + c22 * v2)) * inv_det
    return (s[S.mag_restart_sq] - cv) / n <= HARD_IRON_RESIDUAL ** 2


@jit
def _drop_restart(s):
    """reference ``_drop_restart``."""
    for i in range(9):
        s[S.mag_restart_info + i] = 0.0
    for i in range(3):
        s[S.mag_restart_rhs + i] = 0.0
    s[S.mag_restart_sq] = 0.0
    s[S.mag_restart_n] = 0.0
    s[S.mag_restart_t] = _NAN


@jit
def _explaining_offset(s, c, y0, y1, y2):
    """reference ``_explaining_offset``: the fit's offset applied to a raw magnetometer always,
    to a calibrated one as ``_choose_offset`` decides."""
    F = S.mag_offset_fit
    U = S.mag_offset
    Pr = S.mag_offset_prior
    if (s[S.mag_acquiring] != 0.0 or s[S.mag_waiting] != 0.0 or s[Pr] != 0.0
            or s[Pr + 1] != 0.0 or s[Pr + 2] != 0.0):
        for i in range(3):
            s[U + i] = s[F + i]
    elif math.isfinite(s[S.mag_strength]):
        _choose_offset(s, c, y0, y1, y2)
    s[S.mag_offset_norm] = math.sqrt(s[U] ** 2 + s[U + 1] ** 2 + s[U + 2] ** 2)


@jit
def _choose_offset(s, c, y0, y1, y2):
    """reference ``_choose_offset``: for a calibrated magnetometer, the fit's offset where the
    reading fails the strength gate as it is and passes it corrected, none where it passes as it
    is and fails corrected; else the choice stays."""
    F = S.mag_offset_fit
    U = S.mag_offset
    L = s[S.mag_strength]
    gate = c[C.mag_gate]
    as_is = abs(math.sqrt(y0 * y0 + y1 * y1 + y2 * y2) - L) <= gate
    corrected = abs(math.sqrt((y0 - s[F]) ** 2 + (y1 - s[F + 1]) ** 2
                              + (y2 - s[F + 2]) ** 2) - L) <= gate
    applied = s[U] != 0.0 or s[U + 1] != 0.0 or s[U + 2] != 0.0
    if corrected and not as_is:
        applied = True
    elif as_is and not corrected:
        applied = False
    for i in range(3):
        s[U + i] = s[F + i] if applied else 0.0


@jit
def _turned_to_stamp(s, c, y0, y1, y2):
    """reference ``_turned_to_stamp``: y <- b + R(-(w - b_w) mag_delay_s) (y - b) (Rodrigues),
    not while the offset is acquired or without a gyroscope."""
    delay = c[C.mag_delay_s]
    if (not delay > 0.0 or s[S.omega_valid] == 0.0 or s[S.gyr_enabled] == 0.0
            or s[S.mag_acquiring] != 0.0 or s[S.mag_waiting] != 0.0):
        return y0, y1, y2
    w0, w1, w2 = _unbiased_rate(s, c)
    rate = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if rate == 0.0:
        return y0, y1, y2
    k0 = w0 / rate
    k1 = w1 / rate
    k2 = w2 / rate
    angle = -rate * delay
    ca = math.cos(angle)
    sa = math.sin(angle)
    b0 = s[S.mag_offset_fit]
    b1 = s[S.mag_offset_fit + 1]
    b2 = s[S.mag_offset_fit + 2]
    x0 = y0 - b0
    x1 = y1 - b1
    x2 = y2 - b2
    kx = (k0 * x0 + k1 * x1 + k2 * x2) * (1.0 - ca)
    return (b0 + x0 * ca + (k1 * x2 - k2 * x1) * sa + k0 * kx,
            b1 + x1 * ca + (k2 * x0 - k0 * x2) * sa + k1 * kx,
            b2 + x2 * ca + (k0 * x1 - k1 * x0) * sa + k2 * kx)


@jit
def _check_uncalibrated(s, c):
    """reference ``_check_uncalibrated``."""
    if (c[C.mag_hard_iron_tau_s] > 0.0 and s[S.mag_waiting] == 0.0
            and s[S.mag_strength] > EARTH_FIELD_MAX):
        s[S.mag_acquiring] = 1.0
        s[S.mag_waiting] = 1.0


@jit
def _acquisition_progress(s, y0, y1, y2):
    """reference ``_acquisition_progress``."""
    B = S.mag_offset_fit
    if s[S.mag_acquiring] != 0.0 and known_everywhere(s, S.mag_offset_info):
        s[S.mag_acquiring] = 0.0
        for i in range(3):
            s[S.mag_offset_prior + i] = s[B + i]
    if s[S.mag_waiting] == 0.0:
        return
    if math.sqrt((y0 - s[B]) ** 2 + (y1 - s[B + 1]) ** 2 + (y2 - s[B + 2]) ** 2) \
            > EARTH_FIELD_MAX:
        return
    # H M^-1 H^T with H the rows x, y of Q(q): the offset's uncertainty in the horizontal plane
    c00, c01, c02, c11, c12, c22, inv_det = inverse_plus(s, S.mag_offset_info, ACQUIRING_PRIOR)
    Q = to_matrix(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3])
    # rows of H times the inverse
    g0 = (Q[0] * c00 + Q[1] * c01 + Q[2] * c02) * inv_det
    g1 = (Q[0] * c01 + Q[1] * c11 + Q[2] * c12) * inv_det
    g2 = (Q[0] * c02 + Q[1] * c12 + Q[2] * c22) * inv_det
    k0 = (Q[3] * c00 + Q[4] * c01 + Q[5] * c02) * inv_det
    k1 = (Q[3] * c01 + Q[4] * c11 + Q[5] * c12) * inv_det
    k2 = (Q[3] * c02 + Q[4] * c12 + Q[5] * c22) * inv_det
    a = g0 * Q[0] + g1 * Q[1] + g2 * Q[2]
    b = g0 * Q[3] + g1 * Q[4] + g2 * Q[5]
    d = k0 * Q[3] + k1 * Q[4] + k2 * Q[5]
    largest = 0.5 * (a + d) + math.sqrt(0.25 * (a - d) ** 2 + b * b)
    if largest * ACQUIRED_INFO <= 1.0:
        _offset_acquired(s)


@jit
def _offset_acquired(s):
    """reference ``_offset_acquired``."""
    s[S.mag_waiting] = 0.0
    s[S.heading_from_mag] = 0.0
    s[S.m0_valid] = 0.0
    s[S.mag_strength] = _NAN
    s[S.mag_confirmed_time] = 0.0
    s[S.mag_disturbed_time] = 0.0
    s[S.mag_disturbed_t] = _NAN
    s[S.mag_passing_since] = _NAN
    s[S.mag_rejected_since] = _NAN


@jit
def _open_pair(s, t, y0, y1, y2):
    s[S.mag_pair_t] = t
    s[S.mag_pair_raw] = y0
    s[S.mag_pair_raw + 1] = y1
    s[S.mag_pair_raw + 2] = y2
    s[S.mag_pair_q] = 1.0
    for i in range(1, 4):
        s[S.mag_pair_q + i] = 0.0


# ---- the magnetic field reference ---------------------------------------------------------

@jit
def _learn_reference(s, c, y0, y1, y2, t):
    """reference ``_learn_reference``: add a reading to the expected field's sums (restarted
    from it when it disagrees with their mean beyond the gates); meanwhile L_k is their mean.
    Returns ‖y‖."""
    norm = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    Q = to_matrix(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3])
    w0 = Q[0] * y0 + Q[1] * y1 + Q[2] * y2
    w1 = Q[3] * y0 + Q[4] * y1 + Q[5] * y2
    w2 = Q[6] * y0 + Q[7] * y1 + Q[8] * y2
    R = S.mag_reference_sum
    count = s[S.mag_reference_count]
    if (abs(norm - s[S.mag_reference_norm_sum] / count) > c[C.mag_gate]
            or abs(_elevation_deg(w0, w1, w2)
                   - _elevation_deg(s[R] / count, s[R + 1] / count, s[R + 2] / count))
            > c[C.mag_dip_gate_deg]):
        s[S.mag_reference_until] = t + c[C.mag_reference_s]
        s[R] = 0.0
        s[R + 1] = 0.0
        s[R + 2] = 0.0
        s[S.mag_reference_norm_sum] = 0.0
        s[S.mag_reference_count] = 0.0
    s[R] += w0
    s[R + 1] += w1
    s[R + 2] += w2
    s[S.mag_reference_norm_sum] += norm
    s[S.mag_reference_count] += 1.0
    s[S.mag_strength] = s[S.mag_reference_norm_sum] / s[S.mag_reference_count]
    s[S.mag_norm] = norm
    s[S.mag_expected] = s[S.mag_strength]
    s[S.mag_gate] = c[C.mag_gate]
    return norm


@jit
def _finish_reference(s):
    """reference ``_finish_reference``: L_k the mean strength; m0 that strength and the dip of
    the mean world-frame reading, its horizontal direction kept."""
    count = s[S.mag_reference_count]
    strength = s[S.mag_reference_norm_sum] / count
    e = s[S.mag_reference_sum] / count
    n = s[S.mag_reference_sum + 1] / count
    u = s[S.mag_reference_sum + 2] / count
    dip = math.atan2(u, math.hypot(e, n))
    horizontal = math.hypot(s[S.m0], s[S.m0 + 1])
    if horizontal > 0.0:
        scale = strength * math.cos(dip) / horizontal
        s[S.m0] = s[S.m0] * scale
        s[S.m0 + 1] = s[S.m0 + 1] * scale
        s[S.m0 + 2] = strength * math.sin(dip)
    s[S.mag_strength] = strength
    s[S.mag_reference_count] = 0.0
    s[S.mag_reference_until] = -_INF
    s[S.mag_expected] = strength
    s[S.mag_reference_dip_deg] = _reference_dip_deg(s)


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
def _track_new_field(s, c, y0, y1, y2, t, norm, dip):
    """reference ``_track_new_field``: a new field is learned only when the rejected readings
    agree with each other (strength and dip within the gates of their running mean) for
    mag_relearn_s."""
    if c[C.mag_relearn_world] != 0.0:
        _track_new_field_world(s, c, y0, y1, y2, t)
        return
    cn = s[S.mag_candidate_norm]
    cd = s[S.mag_candidate_dip]
    if (math.isnan(s[S.mag_rejected_since]) or abs(norm - cn) > c[C.mag_gate]
            or abs(dip - cd) > c[C.mag_dip_gate_deg]):
        s[S.mag_rejected_since] = t
        s[S.mag_candidate_norm] = norm
        s[S.mag_candidate_dip] = dip
    else:
        alpha = c[C.mag_alpha]
        s[S.mag_candidate_norm] = cn + alpha * (norm - cn)
        s[S.mag_candidate_dip] = cd + alpha * (dip - cd)
        if t - s[S.mag_rejected_since] >= c[C.mag_relearn_s]:
            _relearn_field(s, y0, y1, y2)


@jit
def _track_new_field_world(s, c, y0, y1, y2, t):
    """reference ``_track_new_field_world``: the rejected readings must agree in the world
    frame while the phone turns faster than mag_relearn_min_rate, for mag_relearn_s; the new
    m0 has their strength and dip, north kept."""
    Q = to_matrix(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3])
    mw0 = Q[0] * y0 + Q[1] * y1 + Q[2] * y2
    mw1 = Q[3] * y0 + Q[4] * y1 + Q[5] * y2
    mw2 = Q[6] * y0 + Q[7] * y1 + Q[8] * y2
    W = S.mag_candidate_world
    agrees = (abs(math.sqrt(mw0 * mw0 + mw1 * mw1 + mw2 * mw2)
                  - math.sqrt(s[W] ** 2 + s[W + 1] ** 2 + s[W + 2] ** 2)) <= c[C.mag_gate]
              and abs(_elevation_deg(mw0, mw1, mw2) - _elevation_deg(s[W], s[W + 1], s[W + 2]))
              <= c[C.mag_dip_gate_deg])
    fresh = math.isnan(s[S.mag_rejected_since])
    if not fresh and not agrees:
        s[S.mag_candidate_time] -= t - s[S.mag_candidate_t]
    if fresh or (not agrees and s[S.mag_candidate_time] <= 0.0):
        s[S.mag_rejected_since] = t
        s[W] = mw0
        s[W + 1] = mw1
        s[W + 2] = mw2
        s[S.mag_candidate_time] = 0.0
    elif agrees:
        alpha = c[C.mag_alpha]
        s[W] += alpha * (mw0 - s[W])
        s[W + 1] += alpha * (mw1 - s[W + 1])
        s[W + 2] += alpha * (mw2 - s[W + 2])
        first = c[C.mag_first_relearn_s]
        young = s[S.mag_confirmed_time] < first
        if young or _turn_rate(s, c) >= c[C.mag_relearn_min_rate]:
            s[S.mag_candidate_time] += t - s[S.mag_candidate_t]
        needed = min(first, c[C.mag_relearn_s]) if young else c[C.mag_relearn_s]
        if s[S.mag_candidate_time] >= needed:
            # the new field's strength and dip; north stays where it was
            horizontal = math.hypot(s[S.m0], s[S.m0 + 1])
            if horizontal > 0.0:
                scale = math.hypot(s[W], s[W + 1]) / horizontal
                s[S.m0] = s[S.m0] * scale
                s[S.m0 + 1] = s[S.m0 + 1] * scale
            s[S.m0 + 2] = s[W + 2]
            s[S.mag_strength] = math.sqrt(s[W] ** 2 + s[W + 1] ** 2 + s[W + 2] ** 2)
            s[S.mag_reference_dip_deg] = _reference_dip_deg(s)
            s[S.mag_rejected_since] = _NAN
    s[S.mag_candidate_t] = t


@jit
def _count_confirmed(s, c, t):
    """reference ``_count_confirmed``: a reading that passed the gates of the learned field
    counts the time since the previous one towards confirming it (gaps beyond max_dt do not)."""
    if s[S.mag_reference_count] == 0.0 and t - s[S.mag_passed_t] <= c[C.max_dt]:
        s[S.mag_confirmed_time] += t - s[S.mag_passed_t]


@jit
def _turn_rate(s, c):
    """reference ``_turn_rate``: ‖w - b‖ of the latest gyroscope sample (0: none)."""
    if s[S.omega_valid] == 0.0 or s[S.gyr_enabled] == 0.0:
        return 0.0
    d0, d1, d2 = _unbiased_rate(s, c)
    return math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@jit
def _unbiased_rate(s, c):
    """reference ``_unbiased_rate``: w - b of the latest gyroscope sample (b the estimate, or
    the setting gyr_bias without the bias in the state)."""
    if int(s[S.n]) == 7:
        return (s[S.omega] - s[S.x + 4], s[S.omega + 1] - s[S.x + 5],
                s[S.omega + 2] - s[S.x + 6])
    return (s[S.omega] - c[C.gyr_bias], s[S.omega + 1] - c[C.gyr_bias + 1],
            s[S.omega + 2] - c[C.gyr_bias + 2])


@jit
def _set_m0_from(s, c, y0, y1, y2):
    """reference ``_set_m0_from``: m0 = (0, horizontal, vertical) of the reading in the world;
    with mag_reference_s it starts the mean that becomes the expected field."""
    level_m0(s, y0, y1, y2)
    s[S.m0_valid] = 1.0
    strength = math.sqrt(s[S.m0 + 1] ** 2 + s[S.m0 + 2] * s[S.m0 + 2])
    s[S.mag_strength] = strength
    s[S.mag_expected] = strength
    s[S.mag_reference_dip_deg] = _reference_dip_deg(s)
    if c[C.mag_reference_s] > 0.0:
        s[S.mag_reference_until] = s[S.t] + c[C.mag_reference_s]
        for i in range(3):
            s[S.mag_reference_sum + i] = s[S.m0 + i]
        s[S.mag_reference_norm_sum] = strength
        s[S.mag_reference_count] = 1.0


@jit
def _relearn_field(s, y0, y1, y2):
    """reference ``_relearn_field``."""
    s[S.mag_strength] = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    if s[S.m0_valid] != 0.0:
        level_m0(s, y0, y1, y2)
        s[S.mag_reference_dip_deg] = _reference_dip_deg(s)
    s[S.mag_rejected_since] = _NAN


@jit
def _dip_deg(s, c, y0, y1, y2):
    """reference ``_dip_deg``: angle between up and the field (from the estimate, or from the
    latest accelerometer reading)."""
    if c[C.mag_dip_from_estimate] != 0.0:
        Q = to_matrix(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3])
        up = Q[6] * y0 + Q[7] * y1 + Q[8] * y2
        ny = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
        return math.degrees(math.acos(max(-1.0, min(1.0, up / (ny + 1e-300)))))
    if s[S.last_acc_valid] == 0.0 or s[S.acc_rejected] != 0.0:
        return _NAN
    a0 = s[S.last_acc]
    a1 = s[S.last_acc + 1]
    a2 = s[S.last_acc + 2]
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    ny = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    cv = (a0 * y0 + a1 * y1 + a2 * y2) / (na * ny + 1e-300)
    return math.degrees(math.acos(max(-1.0, min(1.0, cv))))


@jit
def _reference_dip_deg(s):
    """reference ``_reference_dip_deg``."""
    if s[S.m0_valid] == 0.0:
        return _NAN
    return field_dip_deg(s[S.m0], s[S.m0 + 1], s[S.m0 + 2])


@jit
def _compiled_cache_key():
    return CACHE_KEY


check_cache(_compiled_cache_key, globals(), CACHE_KEY)
