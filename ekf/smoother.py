"""The offline smoother: the filter as set, combined with what the rows after each row add.

For a recording (not live): every estimate uses the samples before *and after* it. Three
steps, each below: an RTS pass (the EKF forward, then a backward Rauch-Tung-Striebel pass)
gives the information the rows after each row add; that information is tested against the
filter as set (its estimate and covariance at the row); where the two are consistent they are
combined in information form, where they are not the filter's estimate is kept.

The RTS pass. Its forward pass is the compiled EKF (``ekf.fast``) with whatever settings,
recording per row k the state after the row's time update, x_{k|k-1} and P_{k|k-1}, and after
its measurements, x_{k|k} and P_{k|k}. The backward pass runs in error-state (multiplicative)
form, because a unit quaternion lives on a sphere where additive corrections leave the
constraint:

* nominal x = (q, b), error delta = (dtheta, db):  q_true = q ⊗ (1, dtheta/2),  b_true = b + db
  (dtheta in the body frame, as the filter's own covariance: P_q = 1/4 S̄(q) P_theta S̄(q)^T);
* the filter's P in error coordinates: P^d = T P T^T with T = blockdiag(2 S̄(q)^T, I)
  (S̄(q)^T S̄(q) = I for a unit q, so this inverts the relation above);
* the time update from row k to k+1 (gyroscope w, bias b, step T) moves the error by
  Phi = [[R(w_c T)^T, -T I], [0, I]],  w_c = w - b  (body-frame error of q ⊗ exp(w_c T));
  without a time update in the row (same time stamp, a gap), Phi = I and x_{k+1|k} = x_{k|k};
* backward, from the last row (x_{N|N} is the filter's) down:
      C_k        = P^d_{k|k} Phi^T (P^d_{k+1|k})^-1
      delta_k+1  = x_{k+1|N} ⊖ x_{k+1|k}   = (log(conj(q_{k+1|k}) ⊗ q_{k+1|N}), b_{k+1|N} - b_{k+1|k})
      x_{k|N}    = x_{k|k} ⊕ C_k delta_k+1  (q ⊗ exp(dtheta), b + db)
  with log and exp the rotation vector of a quaternion and back (exact for large angles too).
      P_{k|N}    = P^d_{k|k} + C_k (P_{k+1|N} - P^d_{k+1|k}) C_k^T
  (the error coordinates of each step are taken about that row's filtered nominal: the usual
  first-order approximation of the multiplicative smoother).

The heading is not carried across a stretch the forward filter rejected the magnetometer in
(``rejected_stretches``: a run of rows whose latest magnetometer reading failed a gate or was
still settling, the ``mag_rejected`` light, from its first rejected reading to the reading that
passes again, longer than ``REJECTED_STRETCH_S``, after a reading that passed). In such a
stretch the heading is held by the gyroscope alone, and the RTS gain, which trusts the model,
would carry the heading the readings give after the stretch back through it (C_k is near the
identity on the heading there) and on into the rows before. Those readings may refer to another
field than the one before (the phone carried where north reads differently, a field re-learned
after the disturbance) or the heading may have drifted in a way the model does not know, and
the whole stretch would be turned by it. At a row k of the stretch the gain is therefore
      C_k  ->  Pi_k C_k Pi_k+1,   Pi = blockdiag(I - u u^T, I - u u^T),  u = R(q)^T e_up
(u the world's up in the body frame of that row's nominal, q_{k|k} for Pi_k, q_{k+1|k} for
Pi_k+1): no rotation about up, nor gyroscope bias about up (which integrates into the heading
and is correlated with it), enters from the row after, and none goes out into row k. Within the
stretch the smoothed heading is the forward pass's, its tilt and the rest are smoothed as
elsewhere; at the stretch's first row the carry starts again from the forward heading, so the
rows before it are smoothed by the readings before it only, and the rows after it by those
after. The rows between two passing readings with no reading of their own, and a short
rejection (one reading out and the settling after it), are smoothed as any other; a run of
rejections from the first reading on has no heading before it to keep apart, and there the
later heading is the only one. The price: where the field after the stretch is the one before
and the model holds, the RTS pass would have closed the gyroscope's drift over the stretch
from both ends, and the rule leaves that drift in (simulated, a 150 uT magnet beside a turning
phone for 10 s: the heading within it 0.27 deg RMS against 0.02 deg without the rule, the
forward filter 1.6 deg; with north reading 30 deg off after the magnet, 0.27 deg against 10.0).

Its heading-only magnetometer gain is not the optimal one, so the RTS pass is the smoother of
the filter as it runs, not of an ideal one.

The backward estimate. Information adds up: the RTS pass's smoothed estimate at row k
(x^s_k, P^s_k) is its forward estimate (x^o_k, P^o_k) combined with an estimate from the rows
after k alone. In information form (Y = P^-1, y = P^-1 x, in error coordinates about the
forward nominal of the filter as set, :func:`backward_information`):
      Y_b = (P^s_k)^-1 - (P^o_k)^-1,    y_b = (P^s_k)^-1 d^s_k - (P^o_k)^-1 d^o_k
(d^s, d^o: x^s and x^o as errors about that nominal). Y_b may be singular: a direction the
rows after say nothing about (the heading across a rejected stretch, the last row).

The test (``consistency``, below). The filter as set at row k, N(x^f_k, P^f_k), and the
backward estimate, N(x^b, P^b) with P^b = Y_b^-1 and x^b = P^b y_b (Y_b made definite by a
relative 1e-9 on its diagonal), are two independent estimates of one state: if both are right,
the small rotation between their attitudes, d = log(conj(q^f) ⊗ q^b), is Gaussian with the sum
of their attitude covariances, and d^T (P^f_theta + P^b_theta)^-1 d is chi-square with 3 degrees
of freedom. Beyond its 99 % point (11.34, ``CHI2_99[3]``, the ``consistency_gate``) one of them
is wrong (a disturbance a pass took for the field, a heading carried from a field read
elsewhere) and the row keeps the estimate of the filter as set. So do rows where the backward
information is degenerate (Y_b not positive semi-definite).

The combination (``fuse_information``, below), where they are consistent: the
information-form combination of two Gaussian estimates, Y = Y_f + Y_b, y = y_f + y_b, x = Y^-1 y
(y_f = 0: the filter's own estimate is the origin of its error coordinates), and the smoothed
state is x^f ⊕ x = (q^f ⊗ exp(x_theta), b^f + x_b).

The gates and lights are the filter's as set (the smoother changes estimates, not decisions).

The online hard-iron fit (``mag_hard_iron_tau_s``) is not in x: it is a least-squares fit beside
the filter whose offset, subtracted from every reading, changes along the recording. The
backward pass cannot smooth it, and carries the late readings' heading (made with a later
offset) back to rows filtered with an earlier one. With ``smooth_hard_iron`` false (the default
preset, chosen by ``benchmarks/tune_defaults.py --smoother``) the RTS pass's forward pass runs
without the fit; the filter as set, which the backward information is combined with, keeps it. A
raw magnetometer (hundreds of uT of hard iron, whose offset the filter acquires:
``OrientationEKF._check_uncalibrated`` in ``ekf.reference``) would leave that pass without a
heading: there the offset the filter as set found by the recording's end is subtracted from every
reading first, as an offline calibration.

The RTS pass's forward pass also runs without ``mag_bias_innovation_limit`` (always: it is no
choice of the smoother's; the filter as set keeps it). That limit keeps a live filter from
reading a heading far off as a gyroscope bias, at the price of a gain below the one its
covariance asks for; the backward pass trusts the forward covariances, and with the bias held
back it spread the heading's corrections wrongly (the Nexus 5 recordings smoothed: 4.37° with
the limit, 3.39° without; the disturbed swinging walk 12.1° against 5.6°). The whole recording
already tells the smoother what the limit guards the live filter against.

Memory: each forward pass runs block by block (``BLOCK_ROWS``), keeping only the filter's state
at each block's start; the backward pass takes the blocks in reverse, each recorded again from
its state (the same compiled loop from the same state: the same records, bit for bit).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from ekf.estimator import SENSORS, BatchResult, batch_rows
from ekf.settings import EKFSettings, resolve_settings

__all__ = ["CHI2_99", "REJECTED_STRETCH_S", "backward_information", "consistency",
           "fuse_information", "mahalanobis2", "rejected_stretches", "smooth_batch", "smooth_parts"]

# ---- two Gaussian estimates of one state: whether they agree, and their combination --------------
# Two independent estimates x_f ~ N(x, P_f) and x_b ~ N(x, P_b) of the same state x:
#
# * **consistency**: their difference d = x_b - x_f is N(0, P_f + P_b), so d^T (P_f + P_b)^-1 d
#   is chi-square with dim(x) degrees of freedom; a value beyond its 99 % point says that one of
#   them is wrong (:func:`mahalanobis2`, :func:`consistency`);
# * **combination** in information form (Y = P^-1, the information matrix; y = P^-1 x, the
#   information vector): information adds up, Y = Y_f + Y_b and y = y_f + y_b, and the combined
#   estimate is x = Y^-1 y with covariance Y^-1 (:func:`fuse_information`). In covariance form
#   the same is x = P_b (P_f + P_b)^-1 x_f + P_f (P_f + P_b)^-1 x_b. The information form also
#   takes an estimate that says nothing in some direction (a zero there in Y).
#
# Compiled (numba) with the small dense algebra by hand (numba's np.linalg and @ need scipy's
# BLAS, which ekf does not use): the smoother calls them per row.
@njit(cache=True)
def mm(A, B):
    out = np.zeros((A.shape[0], B.shape[1]))
    for i in range(A.shape[0]):
        for k in range(A.shape[1]):
            a = A[i, k]
            if a != 0.0:
                for j in range(B.shape[1]):
                    out[i, j] += a * B[k, j]
    return out


@njit(cache=True)
def mv(A, v):
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        for k in range(A.shape[1]):
            out[i] += A[i, k] * v[k]
    return out


@njit(cache=True)
def solve_spd(A, B):
    """A^-1 B for a symmetric positive definite A (Cholesky); None-free: a non-positive pivot
    gives NaN, which the caller treats as a degenerate step."""
    m = A.shape[0]
    L = np.zeros((m, m))
    for j in range(m):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return np.full(B.shape, np.nan)
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, m):
            v = A[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k]
            L[i, j] = v / L[j, j]
    X = B.copy()
    for c in range(B.shape[1]):
        for i in range(m):            # L y = b
            v = X[i, c]
            for k in range(i):
                v -= L[i, k] * X[k, c]
            X[i, c] = v / L[i, i]
        for i in range(m - 1, -1, -1):  # L^T x = y
            v = X[i, c]
            for k in range(i + 1, m):
                v -= L[k, i] * X[k, c]
            X[i, c] = v / L[i, i]
    return X


@njit(cache=True)
def inverse(P):
    m = P.shape[0]
    return solve_spd(0.5 * (P + P.T), np.eye(m))


@njit(cache=True)
def mahalanobis2(d, S):
    """d^T S^-1 d: the squared Mahalanobis distance of a difference d whose covariance is S
    (chi-square with len(d) degrees of freedom when d is zero-mean Gaussian). NaN when S is not
    positive definite."""
    x = solve_spd(S, d.reshape(d.shape[0], 1).copy())
    total = 0.0
    for i in range(d.shape[0]):
        total += d[i] * x[i, 0]
    return total


@njit(cache=True)
def fuse_information(Y_f, y_f, Y_b, y_b):
    """The information-form combination of two independent Gaussian estimates of one state,
    each given by its information matrix Y = P^-1 and information vector y = P^-1 x:

        Y = Y_f + Y_b               information adds up
        y = y_f + y_b               and so does information times mean
        x = Y^-1 y,   P = Y^-1      the combined estimate

    (for two estimates x_f, x_b with covariances P_f, P_b this is
    x = (P_f^-1 + P_b^-1)^-1 (P_f^-1 x_f + P_b^-1 x_b)). Returns (x, P); NaN where Y is not
    positive definite."""
    P = inverse(Y_f + Y_b)
    return mv(P, y_f + y_b), P


@njit(cache=True)
def consistency(Y_b, y_b, P_f):
    """The chi-square statistic of the attitudes of a forward estimate N(0, P_f) and a backward
    one given by its information (Y_b, y_b): the backward estimate in covariance form,
    P_b = Y_b^-1 and d = P_b y_b (Y_b made definite by a relative 1e-9 on its diagonal: a
    direction it says nothing about gets a huge variance, not an infinite one), and
    its attitude difference d_theta against the sum of the two attitude covariances:
        d_theta^T (P_f,theta + P_b,theta)^-1 d_theta    (chi-square, 3 degrees of freedom).
    NaN when Y_b is not positive semi-definite (it would remove information)."""
    m = P_f.shape[0]
    scale = 0.0
    for i in range(m):
        scale = max(scale, abs(Y_b[i, i]))
    P_b = inverse(Y_b + (1e-9 * scale + 1e-300) * np.eye(m))
    d = mv(P_b, y_b)
    return mahalanobis2(d[:3].copy(), P_f[:3, :3] + P_b[:3, :3])


# ---- the smoother --------------------------------------------------------------------------------
BLOCK_ROWS = 1 << 14
"""Rows of forward records held at a time (smooth_batch's memory: about 1 kB a row of them)."""

CHI2_99 = {3: 11.344866730144373, 6: 16.811893829770927}
"""The 99 % points of the chi-square distribution with 3 and 6 degrees of freedom
(``scipy.stats.chi2.ppf(0.99, k)``); 3: the consistency gate on the attitudes of the forward and
backward estimates (module docstring)."""

REJECTED_STRETCH_S = 1.0
"""A stretch of rejected magnetometer readings longer than this [s] is one the backward pass
carries no heading across (module docstring)."""


@njit(cache=True)
def _s_bar(q):
    """S̄(q) (4x3): q ⊗ (0, v) = S̄(q) v."""
    q0, q1, q2, q3 = q[0], q[1], q[2], q[3]
    return np.array([[-q1, -q2, -q3], [q0, -q3, q2], [q3, q0, -q1], [-q2, q1, q0]])


@njit(cache=True)
def _error_cov(q, P, m):
    """P^d = T P T^T, T = blockdiag(2 S̄(q)^T, I): the filter's covariance (n = 4 or 7) in
    error coordinates (m = 3 or 6)."""
    n = 4 if m == 3 else 7
    T = np.zeros((m, n))
    T[:3, :4] = 2.0 * _s_bar(q).T
    for i in range(3, m):
        T[i, i + 1] = 1.0
    return mm(mm(T, P[:n, :n].copy()), T.T.copy())


@njit(cache=True)
def _rotation(w, T):
    """R(w T) by Rodrigues (body turned by |w| T about w)."""
    angle = np.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2) * T
    R = np.eye(3)
    if angle < 1e-12:
        return R
    k = w * T / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return R + np.sin(angle) * K + (1.0 - np.cos(angle)) * mm(K, K)


@njit(cache=True)
def _quat_mul(p, q):
    return np.array([p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
                     p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
                     p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
                     p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0]])


@njit(cache=True)
def _log(e):
    """Rotation vector of a unit quaternion with w >= 0: 2 atan2(|v|, w) v / |v|."""
    nv = np.sqrt(e[1] ** 2 + e[2] ** 2 + e[3] ** 2)
    if nv < 1e-12:
        return 2.0 * e[1:4]
    return (2.0 * np.arctan2(nv, e[0]) / nv) * e[1:4]


@njit(cache=True)
def _exp(d):
    """Unit quaternion of a rotation vector: (cos(|d|/2), sin(|d|/2) d / |d|)."""
    angle = np.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
    if angle < 1e-12:
        return np.array([1.0, 0.5 * d[0], 0.5 * d[1], 0.5 * d[2]])
    k = np.sin(0.5 * angle) / angle
    return np.array([np.cos(0.5 * angle), k * d[0], k * d[1], k * d[2]])


@njit(cache=True)
def _heading_projector(q, m):
    """Pi = blockdiag(I - u u^T, I - u u^T) (m = 6; the first block only for m = 3), u = R(q)^T
    e_up the world's up in the body frame: drops from an error (dtheta, db) the rotation about
    up (the heading) and the bias about up."""
    q0, q1, q2, q3 = q[0], q[1], q[2], q[3]
    n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
    u = np.array([2.0 * (q1 * q3 - q0 * q2), 2.0 * (q2 * q3 + q0 * q1),
                  q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3]) / n2
    Pi = np.eye(m)
    for b in range(0, m, 3):
        for i in range(3):
            for j in range(3):
                Pi[b + i, b + j] -= u[i] * u[j]
    return Pi


@njit(cache=True)
def _backward(x_f, P_f, x_p, P_p, omega, T, bias_fixed, m, rejected, x_s, P_s, Ps_next,
              last):
    """The RTS pass of the module docstring over one block of rows, from its last row down,
    in place into x_s, the smoothed covariances (error coordinates) into P_s. At a row k of a
    rejected stretch (``rejected[k]``) the gain is Pi_k C_k Pi_k+1 (the heading rule of the
    module docstring).

    The last block (`last`) ends the recording: x_s of its last row is x_f's. Any other block's
    arrays hold one row more, the first row of the block after it: its prediction (x_p, P_p,
    omega, T) and its smoothed state x_s, whose smoothed covariance in error coordinates is
    `Ps_next`. Returns the smoothed covariance of the block's first row (error coordinates),
    the `Ps_next` of the block before."""
    if last:
        N = x_f.shape[0]
        x_s[N - 1] = x_f[N - 1]
        Ps = _error_cov(x_f[N - 1, :4], P_f[N - 1], m)
        P_s[N - 1] = Ps
        top = N - 2
    else:
        Ps = Ps_next.copy()
        top = x_f.shape[0] - 2
    for k in range(top, -1, -1):
        Pf = _error_cov(x_f[k, :4], P_f[k], m)
        if T[k + 1] < 0.0:
            # no time update in row k+1: its prediction is row k's estimate
            xp = x_f[k]
            Pp = Pf.copy()
            Phi = np.eye(m)
        else:
            xp = x_p[k + 1]
            Pp = _error_cov(xp[:4], P_p[k + 1], m)
            Phi = np.eye(m)
            b = xp[4:7] if m == 6 else bias_fixed
            Phi[:3, :3] = _rotation(omega[k + 1] - b, T[k + 1]).T
            if m == 6:
                for i in range(3):
                    Phi[i, 3 + i] = -T[k + 1]
        Pp = 0.5 * (Pp + Pp.T) + 1e-15 * np.eye(m)
        C = solve_spd(Pp, mm(Phi, Pf)).T.copy()    # P_f Phi^T Pp^-1 (Pp symmetric)
        if rejected[k]:
            # no heading (nor bias about up) in from row k+1, none out into row k
            C = mm(mm(_heading_projector(x_f[k, :4], m), C), _heading_projector(xp[:4], m))
        # delta = x_s[k+1] ⊖ x_p[k+1]
        conj = np.array([xp[0], -xp[1], -xp[2], -xp[3]])
        e = _quat_mul(conj, x_s[k + 1, :4])
        if e[0] < 0.0:
            e = -e
        delta = np.zeros(m)
        delta[:3] = _log(e)
        if m == 6:
            delta[3:] = x_s[k + 1, 4:7] - xp[4:7]
        d = mv(C, delta)
        q = _quat_mul(x_f[k, :4], _exp(d[:3]))
        q = q / np.sqrt(np.sum(q * q))
        if q[0] < 0.0:
            q = -q
        x_s[k, :4] = q
        x_s[k, 4:7] = x_f[k, 4:7]
        if m == 6:
            x_s[k, 4:7] = x_f[k, 4:7] + d[3:]
        Ps = Pf + mm(mm(C, Ps - Pp), C.T.copy())
        if not np.isfinite(x_s[k]).all():
            x_s[k] = x_f[k]   # a degenerate step: keep the filter's estimate
            Ps = Pf
        P_s[k] = Ps
    return Ps


@njit(cache=True)
def _is_identity(x):
    """A filter before it initialised: its quaternion exactly (1, 0, 0, 0)."""
    return x[0] == 1.0 and x[1] == 0.0 and x[2] == 0.0 and x[3] == 0.0


@njit(cache=True)
def _error_of(x_ref, x, m):
    """x as an error about the nominal x_ref: (log(conj(q_ref) ⊗ q), b - b_ref)."""
    e = _quat_mul(np.array([x_ref[0], -x_ref[1], -x_ref[2], -x_ref[3]]), x[:4])
    if e[0] < 0.0:
        e = -e
    d = np.zeros(m)
    d[:3] = _log(e)
    if m == 6:
        d[3:] = x[4:7] - x_ref[4:7]
    return d


@njit(cache=True)
def backward_information(x_o, P_o, x_s, P_s, x_ref, m):
    """The backward estimate at a row in information form, (Y_b, y_b), in error coordinates
    about the nominal `x_ref`: what the rows after it add to the forward pass that the RTS pass
    smoothed (x_o, P_o, its estimate; x_s, P_s the smoothed one, P_s in error coordinates).
    Information adds up, so the rows after contribute
        Y_b = P_s^-1 - P_o^-1,      y_b = P_s^-1 d_s - P_o^-1 d_o
    (d_s, d_o: x_s and x_o as errors about x_ref)."""
    Y_s = inverse(P_s)
    Y_o = inverse(_error_cov(x_o[:4], P_o, m))
    Y_b = Y_s - Y_o
    Y_b = 0.5 * (Y_b + Y_b.T)
    y_b = mv(Y_s, _error_of(x_ref, x_s, m)) - mv(Y_o, _error_of(x_ref, x_o, m))
    return Y_b, y_b


@njit(cache=True)
def _combine(x_o, P_o, x_s, P_s, x_f, P_f, m, out, stat):
    """Per row of one block: the forward estimate (x_f, P_f: the filter as set) and the
    backward information of the RTS pass over the smoother's own forward pass (x_o, P_o) and
    its smoothed states (x_s, P_s): their combination into out (the forward estimate where the
    combination is degenerate) and the chi-square statistic of their consistency into stat (NaN:
    degenerate; 0: no backward estimate, before the filters initialised)."""
    for k in range(x_f.shape[0]):
        out[k] = x_f[k]
        stat[k] = 0.0
        if _is_identity(x_f[k]) or _is_identity(x_o[k]):
            continue
        Pfd = _error_cov(x_f[k, :4], P_f[k], m)
        Y_b, y_b = backward_information(x_o[k], P_o[k], x_s[k], P_s[k], x_f[k], m)
        stat[k] = consistency(Y_b, y_b, Pfd)
        delta, _ = fuse_information(inverse(Pfd), np.zeros(m), Y_b, y_b)
        q = _quat_mul(x_f[k, :4], _exp(delta[:3]))
        q = q / np.sqrt(np.sum(q * q))
        if q[0] < 0.0:
            q = -q
        if not (np.isfinite(q).all() and np.isfinite(delta).all()):
            stat[k] = np.nan
            continue
        out[k, :4] = q
        if m == 6:
            out[k, 4:7] = x_f[k, 4:7] + delta[3:]


class _Records:
    """A forward pass's records of one block of rows (and one row more: the first row of the
    block after it), refilled block by block."""

    def __init__(self, rows: int) -> None:
        self.q = np.empty((rows, 4))
        self.x_f, self.x_p = np.zeros((rows, 7)), np.zeros((rows, 7))
        self.P_f, self.P_p = np.zeros((rows, 7, 7)), np.zeros((rows, 7, 7))
        self.omega, self.T = np.zeros((rows, 3)), np.zeros(rows)

    def record(self, record, packed, cfg, t, g, a, m, flags) -> None:
        """The forward pass over rows t, g, a, m (from the state `packed`, which it advances)
        into the first len(t) rows, the flags into `flags`."""
        n = t.shape[0]
        record(packed, cfg, t, g, a, m, self.q[:n], flags, self.x_f[:n], self.P_f[:n],
               self.x_p[:n], self.P_p[:n], self.omega[:n], self.T[:n])

    def hold_next(self, first: tuple, n: int) -> None:
        """Row n: the prediction of the next block's first row (`first`, :meth:`first_row`)."""
        self.x_p[n], self.P_p[n], self.omega[n], self.T[n] = first

    def first_row(self) -> tuple:
        return self.x_p[0].copy(), self.P_p[0].copy(), self.omega[0].copy(), float(self.T[0])


def rejected_stretches(t: np.ndarray, mag_present: np.ndarray, mag_rejected: np.ndarray,
                       min_s: float = REJECTED_STRETCH_S) -> np.ndarray:
    """Per row, whether it lies in a rejected stretch of the forward pass (module docstring):
    a run of rows whose latest magnetometer reading was rejected (``mag_rejected``, the light,
    which keeps the decision of the latest reading), from the rejected reading that starts it
    to the row before the reading that passes again, lasting longer than `min_s` (to that
    reading, or to the last row), after a reading (a row of `mag_present`) that passed.
    Gyroscope-only rows between passing readings are in no stretch."""
    n = t.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    flag = np.asarray(mag_rejected, dtype=np.bool_)
    if not flag.any():
        return out
    edges = np.diff(np.concatenate([[0], flag.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)   # [start, end)
    passed = np.asarray(mag_present, dtype=np.bool_) & ~flag
    passed_before = np.concatenate([[False], np.cumsum(passed)[:-1] > 0])
    for a, b in zip(starts, ends):
        length = t[min(b, n - 1)] - t[a]
        if length > min_s and passed_before[a]:
            out[a:b] = True
    return out


def _less(m: np.ndarray, offset: np.ndarray | None) -> np.ndarray:
    return m if offset is None else m - offset


def _record_cfg(est) -> np.ndarray:
    from ekf.fast.layout import C

    cfg = est.packed_settings.copy()
    cfg[C.record_prediction] = 1.0
    return cfg


def _run_as_set(as_set, t, g, a, m, changes: dict, blocks: list,
                flags: np.ndarray) -> tuple[list, np.ndarray | None]:
    """The filter as set over the rows, block by block: its lights into `flags` (N, 3); its
    state at each block's start, and the magnetometer offset for the smoother's own forward
    pass to subtract (None: none)."""
    starts = []
    for first, end in blocks:
        starts.append(as_set.packed_state.copy())
        r = as_set.run_batch(t[first:end], g[first:end], a[first:end], m[first:end])
        flags[first:end, 0], flags[first:end, 1], flags[first:end, 2] = \
            r.acc_rejected, r.mag_rejected, r.at_rest
    state = as_set.snapshot()["state"]
    if "mag_hard_iron_tau_s" in changes and (state["mag_acquiring"] or state["mag_waiting"]
                                             or np.any(state["mag_offset_prior"] != 0.0)):
        # a raw magnetometer (its offset acquired, ekf.reference): without the fit
        # the forward pass would have no heading; the offset the filter found over the
        # whole recording is subtracted instead (its least-squares fit, unshrunk: offline
        # nothing is at stake in between), a calibration as calibrate-mag's
        return starts, np.asarray(state["mag_offset_fit"], float)
    return starts, None


def _forward_passes(est, as_set, t, g, a, m, changes: dict, blocks: list, flags: np.ndarray,
                    records: "_Records", cfg: np.ndarray) -> tuple:
    """The filter as set (its lights into `flags`), then the RTS pass's forward pass (its
    records of the last block left in `records`): the latter's state at each block's start,
    the former's (None: the same filter), the magnetometer offset the latter subtracts, and the
    latter's lights."""
    from ekf.fast.filter import batch_loop_recording

    offset, set_starts, own_flags = None, None, flags
    if as_set is not None:
        set_starts, offset = _run_as_set(as_set, t, g, a, m, changes, blocks, flags)
        own_flags = np.zeros(flags.shape, dtype=np.bool_)
    starts = []
    for first, end in blocks:
        starts.append(est.packed_state.copy())
        records.record(batch_loop_recording, est.packed_state, cfg, t[first:end], g[first:end],
                       a[first:end], _less(m[first:end], offset), own_flags[first:end])
    return starts, set_starts, offset, own_flags


def _forward_backward(est, as_set, t, g, a, m, changes: dict, rejected_stretch_s: float,
                      block_rows: int, gate: float | None) -> tuple:
    """The smoother's forward pass (`est`), the backward RTS pass over it, and per row the
    combination with the filter as set (`as_set`; None: `est` is the filter as set): the
    combined states (N, 7), the states of the filter as set (N, 7), the consistency statistic
    (N,) and the lights of the filter as set (N, 3). With a `gate`, the smoothed states (each
    row the combined state where its statistic is within the gate, else the filter's) and the
    lights only: the recording's memory then holds one state a row.

    Each forward pass runs block by block, keeping only the filter's state at each block's
    start; the backward pass runs the blocks in reverse, each recorded again from its state
    (the same compiled loop from the same state: the same records, bit for bit). Memory: the
    records of one block instead of the whole recording's (~1 kB a row for each pass)."""
    from ekf.fast.filter import batch_loop_recording

    cfg = _record_cfg(est)
    n = t.shape[0]
    flags = np.zeros((n, 3), dtype=np.bool_)
    x_s = np.zeros((n, 7))
    x_set = np.zeros((n, 7)) if gate is None else None
    stat = np.zeros(n) if gate is None else np.zeros(min(block_rows, n))
    blocks = [(first, min(first + block_rows, n)) for first in range(0, n, block_rows)]
    records = _Records(min(block_rows, n) + 1)
    starts, set_starts, offset, own_flags = _forward_passes(est, as_set, t, g, a, m, changes,
                                                            blocks, flags, records, cfg)
    if not n:
        return (x_s, x_set, stat, flags) if gate is None else (x_s, flags)
    m_err = 6 if est.settings.estimate_gyro_bias else 3
    bias_fixed = np.asarray(est.settings.gyr_bias, float)
    # the forward pass's own light (a flag row without a reading keeps the latest one)
    present = np.isfinite(m).all(axis=1)     # the readings of the forward pass
    if offset is not None and not np.isfinite(offset).all():
        present[:] = False
    rejected = rejected_stretches(t, present, own_flags[:, 1], rejected_stretch_s)
    P_s = np.zeros((min(block_rows, n) + 1, m_err, m_err))
    set_records = None
    if as_set is not None:
        set_records, set_cfg = _Records(min(block_rows, n)), _record_cfg(as_set)
    combined = np.zeros((min(block_rows, n), 7))
    Ps = np.zeros((m_err, m_err))
    after, after_smoothed, combined_next = None, None, None
    for index in range(len(blocks) - 1, -1, -1):
        first, end = blocks[index]
        last = after is None
        if not last:       # the last block's records are still those of the forward pass
            records.record(batch_loop_recording, starts[index].copy(), cfg, t[first:end],
                           g[first:end], a[first:end], _less(m[first:end], offset),
                           np.zeros((end - first, 3), dtype=np.bool_))
            records.hold_next(after, end - first)
            x_s[end] = after_smoothed     # the RTS pass's state there, not the combined one
        rows = end - first + (0 if last else 1)
        Ps = _backward(records.x_f[:rows], records.P_f[:rows], records.x_p[:rows],
                       records.P_p[:rows], records.omega[:rows], records.T[:rows],
                       bias_fixed, m_err, rejected[first:end], x_s[first:first + rows],
                       P_s[:rows], Ps, last)
        if not last:
            x_s[end] = combined_next
        k = end - first
        forward = records
        if set_records is not None:
            set_records.record(batch_loop_recording, set_starts[index].copy(), set_cfg,
                               t[first:end], g[first:end], a[first:end], m[first:end],
                               np.zeros((k, 3), dtype=np.bool_))
            forward = set_records
        after, after_smoothed = records.first_row(), x_s[first].copy()
        _combine(records.x_f[:k], records.P_f[:k], x_s[first:end], P_s[:k], forward.x_f[:k],
                 forward.P_f[:k], m_err, combined[:k], stat[:k] if gate is not None else
                 stat[first:end])
        if gate is None:
            x_s[first:end] = combined[:k]
            x_set[first:end] = forward.x_f[:k]
        else:
            x_s[first:end] = np.where((stat[:k] <= gate)[:, None], combined[:k],
                                      forward.x_f[:k])
        combined_next = x_s[first].copy()
    return (x_s, x_set, stat, flags) if gate is None else (x_s, flags)


def smooth_batch(t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
                 mag: ArrayLike | None, settings: EKFSettings | str | None = None,
                 sensors: tuple[str, ...] | list[str] = SENSORS,
                 rejected_stretch_s: float = REJECTED_STRETCH_S,
                 consistency_gate: float = CHI2_99[3],
                 block_rows: int = BLOCK_ROWS) -> BatchResult:
    """The EKF (compiled, `settings` as for ``ekf.filter_batch``) combined with what the rows
    after each row add (module docstring): per row the smoothed quaternion (w-first, sensor ->
    ENU, w >= 0) and gyro bias; the flags are the filter's as set. Same arguments as
    ``ekf.filter_batch``; the RTS pass's forward pass runs without ``mag_bias_innovation_limit``
    and, with ``smooth_hard_iron`` false, without the online hard-iron fit (module docstring).
    Within a stretch of rejected magnetometer readings longer than `rejected_stretch_s` [s] the
    RTS pass carries no heading (inf: no such rule). A row whose two attitude estimates differ
    by more than `consistency_gate` (chi-square, 3 degrees of freedom; inf: no gate) keeps the
    estimate of the filter as set. `block_rows`: the rows whose records are held at a time (the
    result does not depend on it)."""
    t, g, a, m, settings, est, as_set, changes = _set_up(t_s, gyr, acc, mag, settings, sensors)
    x, flags = _forward_backward(est, as_set, t, g, a, m, changes, rejected_stretch_s,
                                 block_rows, consistency_gate)
    bias = x[:, 4:7] if settings.estimate_gyro_bias else np.tile(
        np.asarray(settings.gyr_bias, float), (t.shape[0], 1))
    return BatchResult(t, x[:, :4].copy(), flags[:, 0].copy(), flags[:, 1].copy(),
                       flags[:, 2].copy(), gyro_bias=bias)


def _set_up(t_s, gyr, acc, mag, settings, sensors) -> tuple:
    """The rows, the settings resolved, the RTS pass's forward filter, the filter as set (None:
    the same) and the settings the former drops."""
    from ekf.fast.filter import FastEKF

    t, g, a, m = batch_rows(t_s, gyr, acc, mag)
    settings = resolve_settings(settings)
    changes: dict[str, float] = {}
    if not settings.smooth_hard_iron and settings.mag_hard_iron_tau_s > 0.0:
        changes["mag_hard_iron_tau_s"] = 0.0
    if settings.mag_bias_innovation_limit != math.inf:
        changes["mag_bias_innovation_limit"] = math.inf
    own = settings.with_changes(**changes) if changes else settings
    as_set = FastEKF(settings, sensors) if changes else None
    return t, g, a, m, settings, FastEKF(own, sensors), as_set, changes


def smooth_parts(t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
                 mag: ArrayLike | None, settings: EKFSettings | str | None = None,
                 sensors: tuple[str, ...] | list[str] = SENSORS,
                 rejected_stretch_s: float = REJECTED_STRETCH_S,
                 block_rows: int = BLOCK_ROWS) -> tuple:
    """What :func:`smooth_batch` chooses from, per row: (t, the combined states (N, 7), the
    states of the filter as set (N, 7), the consistency statistic (N,; NaN: degenerate), the
    lights (N, 3), the settings resolved). A state is (q w-first, gyro bias)."""
    t, g, a, m, settings, est, as_set, changes = _set_up(t_s, gyr, acc, mag, settings, sensors)
    x_s, x_set, stat, flags = _forward_backward(est, as_set, t, g, a, m, changes,
                                                rejected_stretch_s, block_rows, None)
    return t, x_s, x_set, stat, flags, settings
