"""Two Gaussian estimates of one state: whether they agree, and their combination.

Two independent estimates x_f ~ N(x, P_f) and x_b ~ N(x, P_b) of the same state x:

* **consistency**: their difference d = x_b - x_f is N(0, P_f + P_b), so d^T (P_f + P_b)^-1 d
  is chi-square with dim(x) degrees of freedom; a value beyond its 99 % point says that one of
  them is wrong (:func:`mahalanobis2`, :func:`consistency`);
* **combination** in information form (Y = P^-1, the information matrix; y = P^-1 x, the
  information vector): information adds up, Y = Y_f + Y_b and y = y_f + y_b, and the combined
  estimate is x = Y^-1 y with covariance Y^-1 (:func:`fuse_information`). In covariance form
  the same is x = P_b (P_f + P_b)^-1 x_f + P_f (P_f + P_b)^-1 x_b. The information form also
  takes an estimate that says nothing in some direction (a zero there in Y).

Compiled (numba) with the small dense algebra by hand: ``ekf.smoother`` calls them per row.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["consistency", "fuse_information", "inverse", "mahalanobis2", "mm", "mv", "solve_spd"]


# Small dense algebra by hand: numba's np.linalg and @ need scipy's BLAS, which ekf does not use.
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
