"""Compiled online hard-iron fit: pairs of magnetometer readings taken while the phone turns,
the least-squares offset they give, how well the directions seen pin it down (the acquisition
of a raw magnetometer's offset), and whether an offset explains a reading the field alone would
reject. The reference's twins are in ``ekf.reference_field``.
"""

from __future__ import annotations

import math

from ekf.fast._jit import CACHE_KEY, check_cache, jit
from ekf.fast.algebra import _to_matrix
from ekf.fast.field import _unbiased_rate
from ekf.fast.layout import C, S
from ekf.reference_field import ACQUIRED_INFO, ACQUIRING_PRIOR, EARTH_FIELD_MAX

_NAN = math.nan
# ekf.reference.HARD_IRON_*
_PAIR_ANGLE = math.radians(20.0)
_PAIR_MAX_S = 2.0
_RESIDUAL = 5.0
_RESET_RESIDUAL = 20.0
_RESET_COUNT = 5.0


@jit
def _open_pair(s, t, y0, y1, y2):
    s[S.mag_pair_t] = t
    s[S.mag_pair_raw] = y0
    s[S.mag_pair_raw + 1] = y1
    s[S.mag_pair_raw + 2] = y2
    s[S.mag_pair_q] = 1.0
    for i in range(1, 4):
        s[S.mag_pair_q + i] = 0.0


@jit
def _fit_hard_iron(s, c, t, y0, y1, y2):
    """reference ``_fit_hard_iron``: pairs of readings turned >= 20 deg apart (the turn
    integrated from the gyroscope, mag_pair_q), D b = e with D = I - A, e = y_j - A y_i,
    A = Q(turn)^T; weighted sums with forgetting; b solved."""
    y0, y1, y2 = _turned_to_stamp(s, c, y0, y1, y2)
    if math.isnan(s[S.mag_pair_t]) or t - s[S.mag_pair_t] > _PAIR_MAX_S:
        _open_pair(s, t, y0, y1, y2)
        return
    P = S.mag_pair_q
    inv = 1.0 / math.sqrt(s[P] ** 2 + s[P + 1] ** 2 + s[P + 2] ** 2 + s[P + 3] ** 2)
    if 2.0 * math.acos(min(1.0, abs(s[P] * inv))) < _PAIR_ANGLE:
        return
    Qt = _to_matrix(s[P] * inv, s[P + 1] * inv, s[P + 2] * inv, s[P + 3] * inv)
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
    w = min(1.0, _RESIDUAL / residual) if residual > 0.0 else 1.0
    forget = 0.0
    if math.isfinite(s[S.mag_offset_t]):
        forget = math.exp(-(t - s[S.mag_offset_t]) / c[C.mag_hard_iron_tau_s])
    if residual > _RESET_RESIDUAL:
        s[S.mag_offset_outliers] += 1.0
    else:
        s[S.mag_offset_outliers] = 0.0
    if s[S.mag_acquiring] != 0.0:
        w = 1.0                          # large residuals: the offset is far, not new
        s[S.mag_offset_outliers] = 0.0
    if s[S.mag_offset_outliers] >= _RESET_COUNT:
        forget = 0.0
        w = 1.0
        s[S.mag_offset_outliers] = 0.0
    M = S.mag_offset_info
    V = S.mag_offset_rhs
    for r in range(3):
        for k in range(3):
            dtd = (s[D + r] * s[D + k] + s[D + 3 + r] * s[D + 3 + k]
                   + s[D + 6 + r] * s[D + 6 + k])
            s[M + 3 * r + k] = forget * s[M + 3 * r + k] + w * dtd
        dte = s[D + r] * s[e] + s[D + 3 + r] * s[e + 1] + s[D + 6 + r] * s[e + 2]
        s[V + r] = forget * s[V + r] + w * dte
    s[S.mag_offset_t] = t
    # b = (M + prior I)^-1 (v + prior b_prior) (M symmetric positive semi-definite)
    prior = ACQUIRING_PRIOR if s[S.mag_acquiring] != 0.0 else c[C.mag_hard_iron_prior]
    c00, c01, c02, c11, c12, c22, inv_det = _inverse_plus(s, prior)
    v0 = s[V] + prior * s[S.mag_offset_prior]
    v1 = s[V + 1] + prior * s[S.mag_offset_prior + 1]
    v2 = s[V + 2] + prior * s[S.mag_offset_prior + 2]
    s[B] = (c00 * v0 + c01 * v1 + c02 * v2) * inv_det
    s[B + 1] = (c01 * v0 + c11 * v1 + c12 * v2) * inv_det
    s[B + 2] = (c02 * v0 + c12 * v1 + c22 * v2) * inv_det
    _acquisition_progress(s, y0, y1, y2)
    _open_pair(s, t, y0, y1, y2)


@jit
def _explaining_offset(s, c, y0, y1, y2):
    """reference ``_explaining_offset`` (with ``_choose_offset``): the fit's offset applied to
    a raw magnetometer always, to a calibrated one where the reading fails the strength gate as
    it is and passes it corrected; dropped where it passes as it is and fails corrected."""
    F = S.mag_offset_fit
    U = S.mag_offset
    Pr = S.mag_offset_prior
    if (s[S.mag_acquiring] != 0.0 or s[S.mag_waiting] != 0.0 or s[Pr] != 0.0
            or s[Pr + 1] != 0.0 or s[Pr + 2] != 0.0):
        for i in range(3):
            s[U + i] = s[F + i]
    elif math.isfinite(s[S.mag_strength]):
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
    s[S.mag_offset_norm] = math.sqrt(s[U] ** 2 + s[U + 1] ** 2 + s[U + 2] ** 2)


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
def _inverse_plus(s, d):
    """(M + d I)^-1 of the fit's normal matrix M by the adjugate: its upper triangle c00, c01,
    c02, c11, c12, c22 (to be multiplied by) 1 / det."""
    M = S.mag_offset_info
    a00 = s[M] + d
    a01 = s[M + 1]
    a02 = s[M + 2]
    a11 = s[M + 4] + d
    a12 = s[M + 5]
    a22 = s[M + 8] + d
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    return c00, c01, c02, c11, c12, c22, 1.0 / (a00 * c00 + a01 * c01 + a02 * c02)


@jit
def _known_everywhere(s):
    """The normal matrix's smallest eigenvalue >= ACQUIRED_INFO: M - ACQUIRED_INFO I positive
    semi-definite, i.e. every principal minor of it >= 0."""
    M = S.mag_offset_info
    a00 = s[M] - ACQUIRED_INFO
    a01 = s[M + 1]
    a02 = s[M + 2]
    a11 = s[M + 4] - ACQUIRED_INFO
    a12 = s[M + 5]
    a22 = s[M + 8] - ACQUIRED_INFO
    if a00 < 0.0 or a11 < 0.0 or a22 < 0.0:
        return False
    m01 = a00 * a11 - a01 * a01
    m02 = a00 * a22 - a02 * a02
    m12 = a11 * a22 - a12 * a12
    if m01 < 0.0 or m02 < 0.0 or m12 < 0.0:
        return False
    return a00 * m12 - a01 * (a01 * a22 - a12 * a02) + a02 * (a01 * a12 - a11 * a02) >= 0.0


@jit
def _acquisition_progress(s, y0, y1, y2):
    """reference ``_acquisition_progress``."""
    B = S.mag_offset_fit
    if s[S.mag_acquiring] != 0.0 and _known_everywhere(s):
        s[S.mag_acquiring] = 0.0
        for i in range(3):
            s[S.mag_offset_prior + i] = s[B + i]
    if s[S.mag_waiting] == 0.0:
        return
    if math.sqrt((y0 - s[B]) ** 2 + (y1 - s[B + 1]) ** 2 + (y2 - s[B + 2]) ** 2) \
            > EARTH_FIELD_MAX:
        return
    # H M^-1 H^T with H the rows x, y of Q(q): the offset's uncertainty in the horizontal plane
    c00, c01, c02, c11, c12, c22, inv_det = _inverse_plus(s, ACQUIRING_PRIOR)
    Q = _to_matrix(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3])
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
def _check_uncalibrated(s, c):
    """reference ``_check_uncalibrated``."""
    if (c[C.mag_hard_iron_tau_s] > 0.0 and s[S.mag_waiting] == 0.0
            and s[S.mag_strength] > EARTH_FIELD_MAX):
        s[S.mag_acquiring] = 1.0
        s[S.mag_waiting] = 1.0


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
def _compiled_cache_key():
    return CACHE_KEY


check_cache(_compiled_cache_key, globals())
