"""The reference EKF compiled with numba: same estimates as :mod:`ekf.reference`, much faster.

All filter state lives in ONE float64 array and all settings in ONE float64 array, laid out from
the declarations (``ekf.fast.layout``: ``S`` and ``C``), so a sample costs one compiled call
(``_step``, the one dispatch) that mutates the state in place, a snapshot is one unpacking of
that array, and :meth:`FastEKF.run_batch` is a single compiled loop over ``_step``.

Modules: ``layout`` (generated offsets, packing), ``algebra`` (quaternion helpers, normalisation,
Joseph update), ``time_update``, ``measurements`` (the accelerometer and magnetometer updates and
their gates), ``field`` (the field reference m0 and its re-learning), ``hard_iron`` (the online
hard-iron fit), ``steps`` (entry points, ``_step``, batch loop),
``filter`` (:class:`FastEKF`), ``_jit`` (decorators and the on-disk cache guard).

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
* S^-1 (3x3) by the adjugate; divisions by |q| and S replaced by one reciprocal.

Estimates agree with the reference to ~1e-14 on the tests' data (tested to 1e-9).

Which compiled function mirrors which reference method (``OrientationEKF.<name>``):

==========================================  ===============================================
ekf.fast                                    ekf.reference
==========================================  ===============================================
``time_update._advance``                    ``_advance``
``time_update._time_update_gyro``           ``_time_update_gyro`` (eq. 6, Euler or exact F)
``time_update._carry``, ``_carry_along``    ``_carry``
``time_update._time_update_random_walk``    ``_time_update_random_walk``
``measurements._acc_update``                ``_acc_update``
``measurements._acc_lowpass_update``        ``_acc_lowpass_update``
``measurements._shaking``                   ``_shaking``
``measurements._mag_update``                ``_mag_update``
``measurements._mag_gates``                 ``_mag_gates``
``measurements._uneven_field``              ``_uneven_field``
``measurements._heading_gain_cap``          ``_heading_gain_cap``
``measurements._count_disturbance``         ``_count_disturbance``
``measurements._count_passing``             ``_count_passing`` (with ``_count_confirmed``)
``field._learn_reference``                  ``_learn_reference``
``field._finish_reference``                 ``_finish_reference``
``hard_iron._fit_hard_iron``                ``_fit_hard_iron``
``hard_iron._open_pair``                    ``_open_pair``
``hard_iron._explaining_offset``            ``_explaining_offset`` and ``_choose_offset``
``hard_iron._turned_to_stamp``              ``_turned_to_stamp``
``hard_iron._acquisition_progress``         ``_acquisition_progress``
``hard_iron._known_everywhere``             its smallest-eigenvalue test (the principal
                                            minors of M − ACQUIRED_INFO·I, not eigvalsh)
``hard_iron._inverse_plus``                 (M + d·I)⁻¹ of ``_fit_hard_iron`` and
                                            ``_acquisition_progress`` (by the adjugate)
``hard_iron._check_uncalibrated``           ``_check_uncalibrated``
``hard_iron._offset_acquired``              ``_offset_acquired``
``field._turn_rate``                        ``_turn_rate``
``field._unbiased_rate``                    ``_unbiased_rate``
``field._track_new_field``                  ``_track_new_field``
``field._track_new_field_world``            ``_track_new_field_world``
``measurements._mag_heading_update``        ``_mag_heading_update``
``measurements._heading_error``             ``_heading_error``
``field._set_m0_from``                      ``_set_m0_from``
``field._relearn_field``                    ``_relearn_field``
``field._dip_deg``                          ``_dip_deg``
``field._reference_dip_deg``                ``_reference_dip_deg``
``field._elevation_deg``                    ``ekf.reference_field._elevation_deg``
``algebra._joseph_update``                  ``_update`` (B = P H^T and S given by the caller)
``algebra._measurement_update_q``           ``_update`` with H non-zero in the q columns only
``algebra._tilt_only_update_n``             ``_update`` with keep = ``_tilt_only``(q)
``algebra._zero_rate_update``               ``_zero_rate_update``
``algebra._normalise``                      ``_normalise``
``algebra._flip_sign``                      ``_flip_sign``
``algebra._tilt_quaternion``                ``ekf.reference.tilt_quaternion``
``algebra._acc_mag_quaternion``             ``ekf.reference.acc_mag_quaternion``
``steps._accept``, ``steps._usable``        ``_accept``, ``ekf.reference.usable``
``steps._not_before``                       ``_not_before``
``steps._clipped``                          ``_clipped``
``steps._initialise``                       ``_initialise``
``steps._take_heading_from_mag``            ``_take_heading_from_mag``
``steps._detect_rest_gyr/_acc``             ``_detect_rest_gyr`` / ``_detect_rest_acc``
``steps._update_rest``                      ``_update_rest``
``steps._update_gyr/_acc/_mag``             ``update_gyr`` / ``update_acc`` / ``update_mag``
``steps._step``                             ``step``
``steps._run_batch``                        ``EstimatorBase.run_batch``'s row loop
``steps._run_batch_record``                 the same, recording predictions for
                                            ``ekf.smooth_batch`` (no reference twin)
==========================================  ===============================================

(The reference's methods live in ``ekf.reference`` and in its mixins of ``OrientationEKF``:
``ekf.reference_time_update`` (the time update), ``ekf.reference_updates`` (the measurement
updates, the Joseph update and the normalisation) and ``ekf.reference_field`` (the magnetic
field reference).)

``reset``, ``set_enabled``, ``set_settings`` and ``align_heading`` are not per-sample and run in
Python on the packed array (``ekf.fast.filter``), line by line as in the reference.
"""

from ekf.fast.filter import FastEKF, warm_up
from ekf.fast.layout import C, S, pack_settings, pack_state, unpack_state

__all__ = ["FastEKF", "warm_up", "S", "C", "pack_settings", "pack_state", "unpack_state"]
