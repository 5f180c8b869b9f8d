"""The reference EKF compiled with numba: same estimates as :mod:`ekf.reference`, much faster.

All filter state lives in ONE float64 array and all settings in ONE float64 array, laid out from
the declarations (``ekf.fast.layout``: ``S`` and ``C``), so a sample costs one compiled call
(``kernels.step``, the one dispatch) that mutates the state in place, a snapshot is one
unpacking of that array, and :meth:`FastEKF.run_batch` is a single compiled loop over it.

Modules:

* ``kernels``: the twin of :mod:`ekf.reference`. Every function of the reference that a sample
  runs through (its module functions and ``OrientationEKF``'s methods, from ``update_gyr`` to
  ``_reference_dip_deg``) is a compiled function of the same name, in the same order and the
  same sections; ``OrientationEKF.step`` is ``kernels.step``, ``OrientationEKF._advance`` is
  ``kernels._advance``. Only the ``*_n`` bodies (one per n = 4 or 7 for the function before
  them) are extra. tests/ekf/test_fast.py reads both lists from the code and compares them.
* ``algebra``: compiled building blocks without a twin: what numpy and ``ekf.quaternion`` do
  for the reference, the Joseph-form update unrolled, the smoother's recording.
* ``filter``: :class:`FastEKF` (the reference's ``set_enabled``, ``set_settings`` and
  ``align_heading``, not per-sample, run in Python on the packed array, line by line as in the
  reference) and the compiled batch loops.
* ``layout``: the generated offsets and the packing; ``jit``: the decorator and the on-disk
  cache guard (used by every numba kernel of the program).

The arithmetic is the reference's; only the order of floating-point operations differs where
structure is exploited exactly (the hand-unrolled hot spots: time-update covariance, Joseph
update, normalisation):

* P is symmetric: only the upper triangle is computed, then mirrored;
* zero blocks are skipped: A = [[F, -G], [0, I]], H = [H_q 0] (acc, mag) or [0 I] (zero rate),
  J = blockdiag((I - u u^T)/|q|, I), so J P J^T = (P - u w^T - w u^T + (u.w) u u^T)/|q|^2
  with w = P_qq u (a rank-2 update instead of two 7x7 products);
* the Joseph form (I - K H) P (I - K H)^T + K R K^T = P - K B^T - B K^T + K S K^T, with
  B = P H^T and S = H P H^T + R, for any gain K: the projected heading-only gain uses this;
  for the optimal gain K = B S^-1 (K S = B) it is P - K B^T, which the 3-vector updates use;
* S^-1 (3x3) by the adjugate; divisions by |q| and S replaced by one reciprocal; the hard-iron
  fit's "every direction known" test by the principal minors of M − ACQUIRED_INFO·I instead of
  an eigenvalue.

Estimates agree with the reference to ~1e-14 on the tests' data (tested to 1e-9).

``FastEKF`` and ``warm_up`` are imported when first used, so that importing ``ekf.fast.jit``
or ``ekf.fast.layout`` compiles nothing.
"""

from __future__ import annotations

from typing import Any

__all__ = ["FastEKF", "warm_up"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from ekf.fast import filter as _filter
        return getattr(_filter, name)
    raise AttributeError(f"module 'ekf.fast' has no attribute {name!r}")
