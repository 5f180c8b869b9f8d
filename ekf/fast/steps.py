"""Compiled sample entry points: initialisation, rest detection, ``update_gyr/acc/mag``, the
one dispatch ``_step`` and the batch loop over it.
"""

from __future__ import annotations

import math

from ekf.fast._jit import CACHE_KEY, check_cache, jit
from ekf.fast.algebra import (_acc_mag_quaternion, _add_attitude_cov, _cross, _quat_normalize,
                              _rotate_world_about_up, _set_attitude_cov, _tilt_quaternion,
                              _to_matrix, _zero_rate_update)
from ekf.fast.layout import C, S
from ekf.fast.field import _set_m0_from
from ekf.fast.hard_iron import _check_uncalibrated, _explaining_offset, _fit_hard_iron
from ekf.fast.measurements import (_acc_lowpass_update, _acc_update, _heading_error, _mag_update,
                                   _shaking)
from ekf.fast.time_update import _advance
from ekf.outputs import ACC_CLIPPED, MAG_UNCALIBRATED

# bits of _step's `present` mask
GYR = 1
ACC = 2
MAG = 4

_INF = math.inf
# ekf.reference.MAX_READING, MIN_NORM, CLIP_MARGIN, CLIP_MIN_G
_MAX_READING = 1e6
_MIN_NORM = 1e-6
_CLIP_MARGIN = 0.99
_CLIP_MIN_G = 1.5


# ---- degenerate samples ---------------------------------------------------------------------
@jit
def _usable(t, v0, v1, v2, needs_direction):
    """ekf.reference.usable: finite time and values within MAX_READING, and (acc, mag) a
    direction."""
    if not (math.isfinite(t) and math.isfinite(v0) and math.isfinite(v1)
            and math.isfinite(v2)):
        return False
    if abs(v0) > _MAX_READING or abs(v1) > _MAX_READING or abs(v2) > _MAX_READING:
        return False
    return not needs_direction or math.sqrt(v0 * v0 + v1 * v1 + v2 * v2) >= _MIN_NORM


@jit
def _accept(s, t, v0, v1, v2, needs_direction):
    """reference ``_accept``: a degenerate sample is refused and counted."""
    if _usable(t, v0, v1, v2, needs_direction):
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
        return (s[S.acc_axis_max] >= _CLIP_MIN_G * c[C.g]
                and largest >= _CLIP_MARGIN * s[S.acc_axis_max])
    return largest >= c[C.acc_range]


# ---- initialisation -------------------------------------------------------------------------
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
        x0, x1, x2 = _cross(m0, m1, m2, a0, a1, a2)
        if (math.sqrt(x0 * x0 + x1 * x1 + x2 * x2) <= 1e-6 * math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
                * math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)):
            mag_ok = False   # a field along gravity has no heading: tilt now, heading later
    if acc_ok and mag_ok:
        q = _acc_mag_quaternion(a0, a1, a2, m0, m1, m2)
        s[S.heading_from_mag] = 1.0
    elif acc_ok:
        q = _tilt_quaternion(a0, a1, a2)
    elif mag_ok:
        half = math.atan2(m0, m1) / 2
        q = (math.cos(half), 0.0, 0.0, math.sin(half))
        s[S.heading_from_mag] = 1.0
    else:
        q = (1.0, 0.0, 0.0, 0.0)
    q = _quat_normalize(q[0], q[1], q[2], q[3])
    for i in range(4):
        s[S.x + i] = q[i]
    for i in range(49):
        s[S.P + i] = 0.0
    _set_attitude_cov(s, 0.25 * c[C.initial_attitude_std] ** 2)
    if not (acc_ok and mag_ok):
        _add_attitude_cov(s, 0.25)
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
    Q = _to_matrix(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3])
    mw0 = Q[0] * y0 + Q[1] * y1 + Q[2] * y2
    mw1 = Q[3] * y0 + Q[4] * y1 + Q[5] * y2
    if mw0 ** 2 + mw1 ** 2 < 1e-6:
        return
    psi, _d0, _d1 = _heading_error(s, mw0, mw1)
    q = _rotate_world_about_up(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3], -psi)
    for i in range(4):
        s[S.x + i] = q[i]
    _set_attitude_cov(s, 0.25 * c[C.initial_attitude_std] ** 2)
    # a fresh attitude is uncorrelated with the bias estimate (no-op when n = 4)
    for i in range(4):
        for j in range(4, 7):
            s[S.P + 7 * i + j] = 0.0
            s[S.P + 7 * j + i] = 0.0
    s[S.heading_from_mag] = 1.0
    if s[S.m0_valid] == 0.0:
        _set_m0_from(s, c, y0, y1, y2)


# ---- rest detection -------------------------------------------------------------------------
@jit
def _update_rest(s, c, t):
    """reference ``_update_rest``."""
    if s[S.gyr_enabled] == 0.0 and s[S.acc_enabled] == 0.0:
        s[S.at_rest] = 0.0
        return
    if s[S.last_motion_t] == -_INF:
        s[S.last_motion_t] = t
    s[S.at_rest] = 1.0 if t - s[S.last_motion_t] >= c[C.rest_min_duration] else 0.0


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


# ---- sample entry points --------------------------------------------------------------------
@jit
def _update_gyr(s, c, t, v0, v1, v2):
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
def _update_acc(s, c, t, v0, v1, v2):
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
def _update_mag(s, c, t, v0, v1, v2):
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
        if math.sqrt(v0 * v0 + v1 * v1 + v2 * v2) < _MIN_NORM:
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
def _step(s, c, t, present, g0, g1, g2, a0, a1, a2, m0, m1, m2):
    """reference ``step``, the one dispatch: the samples present at time t (bit mask: GYR 1,
    ACC 2, MAG 4; 0 only moves the clock), in the order gyroscope, accelerometer, magnetometer.
    Used by FastEKF.step, update_gyr/acc/mag and the batch loop."""
    if present & GYR:
        _update_gyr(s, c, t, g0, g1, g2)
    if present & ACC:
        _update_acc(s, c, t, a0, a1, a2)
    if present & MAG:
        _update_mag(s, c, t, m0, m1, m2)
    if present == 0 and _accept(s, t, 0.0, 0.0, 0.0, False):
        _advance(s, c, _not_before(s, t))


@jit
def _run_batch(s, c, t, gyr, acc, mag, out_q, out_flags, out_bias):
    """All rows through _step in one loop (a row with any NaN in a sensor's columns has no such
    sample). out_flags columns: acc_rejected, mag_rejected, at_rest."""
    for k in range(t.shape[0]):
        g0 = gyr[k, 0]
        g1 = gyr[k, 1]
        g2 = gyr[k, 2]
        a0 = acc[k, 0]
        a1 = acc[k, 1]
        a2 = acc[k, 2]
        m0 = mag[k, 0]
        m1 = mag[k, 1]
        m2 = mag[k, 2]
        present = 0
        if not (math.isnan(g0) or math.isnan(g1) or math.isnan(g2)):
            present |= GYR
        if not (math.isnan(a0) or math.isnan(a1) or math.isnan(a2)):
            present |= ACC
        if not (math.isnan(m0) or math.isnan(m1) or math.isnan(m2)):
            present |= MAG
        _step(s, c, t[k], present, g0, g1, g2, a0, a1, a2, m0, m1, m2)
        for i in range(4):
            out_q[k, i] = s[S.x + i]
        out_flags[k, 0] = s[S.acc_rejected] != 0.0
        out_flags[k, 1] = s[S.mag_rejected] != 0.0
        out_flags[k, 2] = s[S.at_rest] != 0.0
        if int(s[S.n]) == 7:
            for i in range(3):
                out_bias[k, i] = s[S.x + 4 + i]
        else:
            for i in range(3):
                out_bias[k, i] = c[C.gyr_bias + i]


@jit
def _run_batch_record(s, c, t, gyr, acc, mag, out_q, out_flags, out_x, out_P, out_xp, out_Pp,
                      out_omega, out_T):
    """_run_batch for the smoother (c[C.record_prediction] = 1): per row also x and P after
    the row, x and P after the row's time update (before its measurements), the gyroscope
    sample that drove it and its T (-1: the row had no time update)."""
    for k in range(t.shape[0]):
        s[S.work_pred_T] = -1.0
        present = 0
        if not (math.isnan(gyr[k, 0]) or math.isnan(gyr[k, 1]) or math.isnan(gyr[k, 2])):
            present |= GYR
        if not (math.isnan(acc[k, 0]) or math.isnan(acc[k, 1]) or math.isnan(acc[k, 2])):
            present |= ACC
        if not (math.isnan(mag[k, 0]) or math.isnan(mag[k, 1]) or math.isnan(mag[k, 2])):
            present |= MAG
        _step(s, c, t[k], present, gyr[k, 0], gyr[k, 1], gyr[k, 2], acc[k, 0], acc[k, 1],
              acc[k, 2], mag[k, 0], mag[k, 1], mag[k, 2])
        for i in range(4):
            out_q[k, i] = s[S.x + i]
        out_flags[k, 0] = s[S.acc_rejected] != 0.0
        out_flags[k, 1] = s[S.mag_rejected] != 0.0
        out_flags[k, 2] = s[S.at_rest] != 0.0
        for i in range(7):
            out_x[k, i] = s[S.x + i]
            out_xp[k, i] = s[S.work_pred_x + i]
            for j in range(7):
                out_P[k, i, j] = s[S.P + 7 * i + j]
                out_Pp[k, i, j] = s[S.work_pred_P + 7 * i + j]
        for i in range(3):
            out_omega[k, i] = s[S.work_pred_omega + i]
        out_T[k] = s[S.work_pred_T]


@jit
def _compiled_cache_key():
    return CACHE_KEY


check_cache(_compiled_cache_key, globals())
