"""Compiled building blocks: quaternion helpers (``ekf.quaternion`` and the reference's start
quaternions), the covariance of a fresh attitude, the normalisation and the Joseph-form
measurement update. The covariance updates are hand-unrolled where they are hot: P is symmetric
(upper triangle computed, then mirrored) and zero blocks of H and J are skipped.
"""

from __future__ import annotations

import math

from ekf.fast._jit import CACHE_KEY, check_cache, jit
from ekf.fast.layout import C, S

_INF = math.inf


@jit
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


@jit
def _rotate_world_about_up(q0, q1, q2, q3, angle):
    """normalize(from_axis_angle(z, angle) ⊗ q)."""
    c = math.cos(angle / 2)
    sn = math.sin(angle / 2)
    return _quat_normalize(c * q0 - sn * q3, c * q1 - sn * q2, c * q2 + sn * q1, c * q3 + sn * q0)


@jit
def _heading_of(q0, q1, q2, q3):
    """ekf.quaternion.heading_of: 2 atan2(z, w) of the normalised q."""
    w, _x, _y, z = _quat_normalize(q0, q1, q2, q3)
    return 2.0 * math.atan2(z, w)


@jit
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


@jit
def _to_matrix(q0, q1, q2, q3):
    """Q(q) of eq. (2a), row-major as a 9-tuple."""
    return (2 * (q0 * q0 + q1 * q1) - 1, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2),
            2 * (q1 * q2 + q0 * q3), 2 * (q0 * q0 + q2 * q2) - 1, 2 * (q2 * q3 - q0 * q1),
            2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 2 * (q0 * q0 + q3 * q3) - 1)


@jit
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@jit
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


@jit
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


@jit
def _attitude_cov(s, scale, add):
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
def _set_attitude_cov(s, scale):
    """P[:4, :4] = scale * S̄(q) S̄(q)^T (the other blocks untouched)."""
    _attitude_cov(s, scale, False)


@jit
def _add_attitude_cov(s, scale):
    """P[:4, :4] += scale * S̄(q) S̄(q)^T."""
    _attitude_cov(s, scale, True)


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


@jit
def _gain_n(s, e0, e1, e2, gate, n):
    """The NIS and, when it passes the gate, the optimal gain K = B S^-1 (n x 3) at S.work_gain,
    given B = P H^T (n x 3) at S.work_pht and S = H P H^T + R (3x3) at S.work_s."""
    _inverse3(s, S.work_s, S.work_s_inv)
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
def _correct_state_n(s, e0, e1, e2, n):
    """x <- x + K e with the gain at S.work_gain."""
    K = S.work_gain
    for i in range(n):
        s[S.x + i] += s[K + 3 * i] * e0 + s[K + 3 * i + 1] * e1 + s[K + 3 * i + 2] * e2


@jit
def _joseph_update_n(s, e0, e1, e2, gate, n):
    """reference ``_update`` for a 3-vector measurement, given B = P H^T (n x 3) at S.work_pht
    and the innovation covariance H P H^T + R (3x3) at S.work_s. Returns the NIS; the state is
    untouched when NIS > gate.

    With the optimal gain K = B S^-1 (K S = B), the Joseph form
    (I - KH) P (I - KH)^T + K R K^T = P - K B^T - B K^T + K S K^T equals P - K B^T exactly;
    that (symmetric: upper triangle, mirrored) is what is evaluated."""
    nis = _gain_n(s, e0, e1, e2, gate, n)
    if nis > gate:
        return nis
    _correct_state_n(s, e0, e1, e2, n)
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
    _normalise(s)
    return nis


@jit
def _joseph_update(s, e0, e1, e2, gate):
    # n = 4 or 7 as a compile-time constant: fixed loops are unrolled.
    if int(s[S.n]) == 7:
        return _joseph_update_n(s, e0, e1, e2, gate, 7)
    return _joseph_update_n(s, e0, e1, e2, gate, 4)


@jit
def _tilt_only_update_n(s, e0, e1, e2, gate, n):
    """reference ``_update`` with ``keep = _tilt_only(q)``: the gain K = B S^-1 (``_gain_n``)
    without its component along a turn about world up in q (u, the direction of
    (0,0,0,1) ⊗ q) and along up in the bias (v, the third row of Q(q)); for a gain that is not
    the optimal one the Joseph form is P - K B^T - B K^T + K S K^T."""
    nis = _gain_n(s, e0, e1, e2, gate, n)
    if nis > gate:
        return nis
    q0, q1, q2, q3 = s[S.x], s[S.x + 1], s[S.x + 2], s[S.x + 3]
    u = (-q3, -q2, q1, q0)
    inv_uu = 1.0 / (q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    v = (2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3)
    inv_vv = 1.0 / (v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    B = S.work_pht
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
    _correct_state_n(s, e0, e1, e2, n)
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
    _normalise(s)
    return nis


@jit
def _measurement_update_q_n(s, c, h, e0, e1, e2, cov, gate, n, scale, tilt_only):
    """Update with a measurement whose H (3 x n) is non-zero only in the q columns:
    h = the 3x4 block (row-major 12-tuple), cov = offset of R in the settings, R x scale;
    tilt_only: the gain without what gravity cannot observe (``_tilt_only_update_n``)."""
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
    if tilt_only:
        return _tilt_only_update_n(s, e0, e1, e2, gate, n)
    return _joseph_update(s, e0, e1, e2, gate)


@jit
def _measurement_update_q(s, c, h, e0, e1, e2, cov, gate, scale=1.0, tilt_only=False):
    # n = 4 or 7 as a compile-time constant: fixed loops are unrolled.
    if int(s[S.n]) == 7:
        return _measurement_update_q_n(s, c, h, e0, e1, e2, cov, gate, 7, scale, tilt_only)
    return _measurement_update_q_n(s, c, h, e0, e1, e2, cov, gate, 4, scale, tilt_only)


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
    _joseph_update(s, w0 - s[S.x + 4], w1 - s[S.x + 5], w2 - s[S.x + 6], _INF)


@jit
def _compiled_cache_key():
    return CACHE_KEY


check_cache(_compiled_cache_key, globals())
