"""Compiled magnetic-field reference: the expected field m0 learned in the first seconds (its
strength and dip), set from a reading, re-learned in a new field, and the tracking of a
disturbance that turns out to be a new normal field (with the turn rate it asks for). The
reference's twins are in ``ekf.reference_field``.
"""

from __future__ import annotations

import math

from ekf.fast._jit import CACHE_KEY, check_cache, jit
from ekf.fast.algebra import _to_matrix
from ekf.fast.layout import C, S

_INF = math.inf
_NAN = math.nan


@jit
def _reference_dip_deg(s):
    """reference ``_reference_dip_deg``."""
    if s[S.m0_valid] == 0.0:
        return _NAN
    m0 = s[S.m0]
    m1 = s[S.m0 + 1]
    m2 = s[S.m0 + 2]
    return math.degrees(math.acos(m2 / (math.sqrt(m0 * m0 + m1 * m1 + m2 * m2) + 1e-300)))


@jit
def _level_m0(s, y0, y1, y2):
    """m0 = (0, sqrt(mx^2 + my^2), mz) of the reading expressed in the (level) world frame."""
    Q = _to_matrix(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3])
    mw0 = Q[0] * y0 + Q[1] * y1 + Q[2] * y2
    mw1 = Q[3] * y0 + Q[4] * y1 + Q[5] * y2
    mw2 = Q[6] * y0 + Q[7] * y1 + Q[8] * y2
    s[S.m0] = 0.0
    s[S.m0 + 1] = math.hypot(mw0, mw1)
    s[S.m0 + 2] = mw2


@jit
def _set_m0_from(s, c, y0, y1, y2):
    """reference ``_set_m0_from``: m0 = (0, horizontal, vertical) of the reading in the world;
    with mag_reference_s it starts the mean that becomes the expected field."""
    _level_m0(s, y0, y1, y2)
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
def _elevation_deg(v0, v1, v2):
    """reference ``_elevation_deg``: angle of a world-frame vector above the horizontal."""
    return math.degrees(math.atan2(v2, math.hypot(v0, v1)))


@jit
def _learn_reference(s, c, y0, y1, y2, t):
    """reference ``_learn_reference``: add a reading to the expected field's sums (restarted
    from it when it disagrees with their mean beyond the gates); meanwhile L_k is their mean.
    Returns ‖y‖."""
    norm = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    Q = _to_matrix(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3])
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
def _relearn_field(s, y0, y1, y2):
    """reference ``_relearn_field``."""
    s[S.mag_strength] = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    if s[S.m0_valid] != 0.0:
        _level_m0(s, y0, y1, y2)
        s[S.mag_reference_dip_deg] = _reference_dip_deg(s)
    s[S.mag_rejected_since] = _NAN


@jit
def _dip_deg(s, c, y0, y1, y2):
    """reference ``_dip_deg``: angle between up and the field (from the estimate, or from the
    latest accelerometer reading)."""
    if c[C.mag_dip_from_estimate] != 0.0:
        Q = _to_matrix(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3])
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
def _unbiased_rate(s, c):
    """reference ``_unbiased_rate``: w - b of the latest gyroscope sample (b the estimate, or
    the setting gyr_bias without the bias in the state)."""
    if int(s[S.n]) == 7:
        return (s[S.omega] - s[S.x + 4], s[S.omega + 1] - s[S.x + 5],
                s[S.omega + 2] - s[S.x + 6])
    return (s[S.omega] - c[C.gyr_bias], s[S.omega + 1] - c[C.gyr_bias + 1],
            s[S.omega + 2] - c[C.gyr_bias + 2])


@jit
def _turn_rate(s, c):
    """reference ``_turn_rate``: ‖w - b‖ of the latest gyroscope sample (0: none)."""
    if s[S.omega_valid] == 0.0 or s[S.gyr_enabled] == 0.0:
        return 0.0
    d0, d1, d2 = _unbiased_rate(s, c)
    return math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@jit
def _track_new_field_world(s, c, y0, y1, y2, t):
    """reference ``_track_new_field_world``: the rejected readings must agree in the world
    frame while the phone turns faster than mag_relearn_min_rate, for mag_relearn_s; the new
    m0 has their strength and dip, north kept."""
    Q = _to_matrix(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3])
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
def _compiled_cache_key():
    return CACHE_KEY


check_cache(_compiled_cache_key, globals())
