"""Compiled building blocks that have no twin in the reference: what ``numpy`` and
``ekf.quaternion`` do for :mod:`ekf.reference` (quaternion helpers, the 3x3 inverse), the pieces
of the Joseph-form update unrolled for the packed state (P is symmetric: the upper triangle is
computed, then mirrored; zero blocks of H are skipped), and the smoother's recording of each
time update. The reference's own steps, compiled, are in :mod:`ekf.fast.kernels`.
"""

from __future__ import annotations

import math

from ekf.fast.jit import CACHE_KEY, check_cache, jit
from ekf.fast.layout import S
from ekf.reference import ACQUIRED_INFO


# ---- quaternions ------------------------------------------------------------------------------
@jit
def quat_normalize(q0, q1, q2, q3):
    """ekf.quaternion.normalize: unit, w >= 0."""
    norm = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    q0 = q0 / norm
    q1 = q1 / norm
    q2 = q2 / norm
    q3 = q3 / norm
    if q0 < 0.0:
        return -q0, -q1, -q2, -q3
    return q0, q1, q2, q3


@jit
def heading_of(q0, q1, q2, q3):
    """ekf.quaternion.heading_of: 2 atan2(z, w) of the normalised q."""
    w, _x, _y, z = quat_normalize(q0, q1, q2, q3)
    return 2.0 * math.atan2(z, w)


@jit
def from_matrix(r00, r01, r02, r10, r11, r12, r20, r21, r22):
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
    return quat_normalize(q[0], q[1], q[2], q[3])


@jit
def to_matrix(q0, q1, q2, q3):
    """Q(q) of eq. (2a), row-major as a 9-tuple."""
    return (2 * (q0 * q0 + q1 * q1) - 1, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2),
            2 * (q1 * q2 + q0 * q3), 2 * (q0 * q0 + q2 * q2) - 1, 2 * (q2 * q3 - q0 * q1),
            2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 2 * (q0 * q0 + q3 * q3) - 1)


@jit
def cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


# ---- covariance blocks and the field reference -----------------------------------------------
@jit
def attitude_cov(s, scale, add):
    """P[:4, :4] = scale * S̄(q) S̄(q)^T, or += with add (the other blocks untouched)."""
    q0 = s[S.x]
    q1 = s[S.x + 1]
    q2 = s[S.x + 2]
    q3 = s[S.x + 3]
    sb = ((-q1, -q2, -q3), (q0, -q3, q2), (q3, q0, -q1), (-q2, q1, q0))
    for i in range(4):
        for j in range(i, 4):
            m = sb[i][0] * sb[j][0] + sb[i][1] * sb[j][1] + sb[i][2] * sb[j][2]
            v = scale * m
            if add:
                v += s[S.P + 7 * i + j]
            s[S.P + 7 * i + j] = v
            s[S.P + 7 * j + i] = v


@jit
def set_attitude_cov(s, scale):
    """P[:4, :4] = scale * S̄(q) S̄(q)^T (the other blocks untouched)."""
    attitude_cov(s, scale, False)


@jit
def add_attitude_cov(s, scale):
    """P[:4, :4] += scale * S̄(q) S̄(q)^T."""
    attitude_cov(s, scale, True)


@jit
def field_dip_deg(m0, m1, m2):
    """Angle between up and the field m0 (ENU) [deg] (``ekf.state.reference_dip_deg``)."""
    return math.degrees(math.acos(m2 / (math.sqrt(m0 * m0 + m1 * m1 + m2 * m2) + 1e-300)))


@jit
def level_m0(s, y0, y1, y2):
    """m0 = (0, sqrt(mx^2 + my^2), mz) of the reading expressed in the (level) world frame."""
    Q = to_matrix(s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3])
    mw0 = Q[0] * y0 + Q[1] * y1 + Q[2] * y2
    mw1 = Q[3] * y0 + Q[4] * y1 + Q[5] * y2
    mw2 = Q[6] * y0 + Q[7] * y1 + Q[8] * y2
    s[S.m0] = 0.0
    s[S.m0 + 1] = math.hypot(mw0, mw1)
    s[S.m0 + 2] = mw2


@jit
def turn_pair(s, F):
    """The hard-iron fit's open pair: its turn since the first reading, from the gyro alone
    (mag_pair_q <- F mag_pair_q, the reference's _time_update_gyro)."""
    M = S.mag_pair_q
    p0, p1, p2, p3 = s[M], s[M + 1], s[M + 2], s[M + 3]
    for i in range(4):
        s[M + i] = F[i][0] * p0 + F[i][1] * p1 + F[i][2] * p2 + F[i][3] * p3


@jit
def record_prediction(s, T):
    """For the smoother (c[C.record_prediction]): x, P and T right after a time update."""
    for i in range(7):
        s[S.work_pred_x + i] = s[S.x + i]
    for i in range(49):
        s[S.work_pred_P + i] = s[S.P + i]
    s[S.work_pred_T] = T
    for i in range(3):
        s[S.work_pred_omega + i] = s[S.omega + i]


# ---- the Joseph-form update, unrolled ----------------------------------------------------------
@jit
def inverse3(s, src, dst):
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


@jit
def measurement_blocks(s, c, h, cov, scale, n):
    """B = P H^T (n x 3) at S.work_pht and S = H P H^T + R (3x3) at S.work_s for a measurement
    whose H (3 x n) is non-zero only in the q columns: h = the 3x4 block (row-major 12-tuple),
    cov = offset of R in the settings, R x scale."""
    B = S.work_pht
    P = S.P
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
            s[S.work_s + 3 * r + col] = (h[4 * r] * s[B + col] + h[4 * r + 1] * s[B + 3 + col]
                                         + h[4 * r + 2] * s[B + 6 + col]
                                         + h[4 * r + 3] * s[B + 9 + col]) \
                + c[cov + 3 * r + col] * scale


@jit
def optimal_gain(s, e0, e1, e2, gate, n):
    """The NIS and, when it passes the gate, the optimal gain K = B S^-1 (n x 3) at S.work_gain,
    given B = P H^T (n x 3) at S.work_pht and S = H P H^T + R (3x3) at S.work_s."""
    inverse3(s, S.work_s, S.work_s_inv)
    Si = S.work_s_inv
    t0 = s[Si + 0] * e0 + s[Si + 1] * e1 + s[Si + 2] * e2
    t1 = s[Si + 3] * e0 + s[Si + 4] * e1 + s[Si + 5] * e2
    t2 = s[Si + 6] * e0 + s[Si + 7] * e1 + s[Si + 8] * e2
    nis = e0 * t0 + e1 * t1 + e2 * t2
    if nis > gate:
        return nis
    B = S.work_pht
    K = S.work_gain
    for i in range(n):
        b0 = s[B + 3 * i]
        b1 = s[B + 3 * i + 1]
        b2 = s[B + 3 * i + 2]
        s[K + 3 * i] = b0 * s[Si + 0] + b1 * s[Si + 3] + b2 * s[Si + 6]
        s[K + 3 * i + 1] = b0 * s[Si + 1] + b1 * s[Si + 4] + b2 * s[Si + 7]
        s[K + 3 * i + 2] = b0 * s[Si + 2] + b1 * s[Si + 5] + b2 * s[Si + 8]
    return nis


@jit
def correct_state(s, e0, e1, e2, n):
    """x <- x + K e with the gain at S.work_gain."""
    K = S.work_gain
    for i in range(n):
        s[S.x + i] += s[K + 3 * i] * e0 + s[K + 3 * i + 1] * e1 + s[K + 3 * i + 2] * e2


@jit
def joseph_optimal_gain(s, n):
    """P <- (I - KH) P (I - KH)^T + K R K^T for the optimal gain K = B S^-1 at S.work_gain (K S
    = B), given B = P H^T at S.work_pht: the Joseph form P - K B^T - B K^T + K S K^T equals
    P - K B^T exactly; that (symmetric: upper triangle, mirrored) is what is evaluated."""
    B = S.work_pht
    K = S.work_gain
    for i in range(n):
        k0 = s[K + 3 * i]
        k1 = s[K + 3 * i + 1]
        k2 = s[K + 3 * i + 2]
        for j in range(i, n):
            v = s[S.P + 7 * i + j] - (k0 * s[B + 3 * j] + k1 * s[B + 3 * j + 1]
                                      + k2 * s[B + 3 * j + 2])
            s[S.P + 7 * i + j] = v
            s[S.P + 7 * j + i] = v


@jit
def joseph_any_gain(s, n):
    """P <- P - K B^T - B K^T + K S K^T, the Joseph form for any gain K at S.work_gain (the
    projected tilt-only gain), given B = P H^T at S.work_pht and S = H P H^T + R at S.work_s."""
    B = S.work_pht
    K = S.work_gain
    W = S.work_s
    for i in range(n):
        # (K S)[i, :]
        ks0 = s[K + 3 * i] * s[W] + s[K + 3 * i + 1] * s[W + 3] + s[K + 3 * i + 2] * s[W + 6]
        ks1 = s[K + 3 * i] * s[W + 1] + s[K + 3 * i + 1] * s[W + 4] + s[K + 3 * i + 2] * s[W + 7]
        ks2 = s[K + 3 * i] * s[W + 2] + s[K + 3 * i + 1] * s[W + 5] + s[K + 3 * i + 2] * s[W + 8]
        for j in range(i, n):
            kj0 = s[K + 3 * j]
            kj1 = s[K + 3 * j + 1]
            kj2 = s[K + 3 * j + 2]
            v_ij = (s[S.P + 7 * i + j]
                    - (s[K + 3 * i] * s[B + 3 * j] + s[K + 3 * i + 1] * s[B + 3 * j + 1]
                       + s[K + 3 * i + 2] * s[B + 3 * j + 2])
                    - (s[B + 3 * i] * kj0 + s[B + 3 * i + 1] * kj1 + s[B + 3 * i + 2] * kj2)
                    + ks0 * kj0 + ks1 * kj1 + ks2 * kj2)
            s[S.P + 7 * i + j] = v_ij
            s[S.P + 7 * j + i] = v_ij


# ---- the hard-iron fit's normal matrix ---------------------------------------------------------
@jit
def add_pair(s, M, V, forget, w):
    """A pair of the hard-iron fit into a fit's sums (normal matrix at offset M, right-hand side
    at V of the state), the old sums forgotten: M <- forget M + w Dᵀ D, V <- forget V + w Dᵀ e,
    with D (3x3) in work_s and e (3) in work_pht."""
    D = S.work_s
    e = S.work_pht
    for r in range(3):
        for k in range(3):
            dtd = (s[D + r] * s[D + k] + s[D + 3 + r] * s[D + 3 + k]
                   + s[D + 6 + r] * s[D + 6 + k])
            s[M + 3 * r + k] = forget * s[M + 3 * r + k] + w * dtd
        dte = s[D + r] * s[e] + s[D + 3 + r] * s[e + 1] + s[D + 6 + r] * s[e + 2]
        s[V + r] = forget * s[V + r] + w * dte


@jit
def inverse_plus(s, M, d):
    """(M + d I)^-1 of a normal matrix of the hard-iron fit (the 3x3 at offset M of the state:
    S.mag_offset_info or S.mag_restart_info) by the adjugate: its upper triangle c00, c01, c02,
    c11, c12, c22 (to be multiplied by) 1 / det."""
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
def known_everywhere(s, M):
    """A normal matrix's (at offset M of the state) smallest eigenvalue >= ACQUIRED_INFO:
    M - ACQUIRED_INFO I positive semi-definite, i.e. every principal minor of it >= 0."""
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
def _compiled_cache_key():
    return CACHE_KEY


check_cache(_compiled_cache_key, globals(), CACHE_KEY)
