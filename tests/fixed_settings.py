"""The filter settings the behaviour tests run with, written out in full.

Tests of what a mechanism does run on these values, not on ``PRESETS["default"]``: retuning the
default preset moves no test limit here. A test of one mechanism switches it on or off in
``FIXED`` (``FIXED.with_changes(...)``) and compares the two, everything else equal. How
accurate the default preset is on recordings is a figure, measured in ``benchmarks/`` and
quoted in ``docs/benchmarks.md``.
"""

from __future__ import annotations

import math

from ekf.settings import PRESETS


def _diag(value: float) -> list[list[float]]:
    return [[value if i == j else 0.0 for j in range(3)] for i in range(3)]


# The course filter (model 4a) with every extension switched on at a fixed value.
FIXED = PRESETS["course"].with_changes(
    exact_discretisation=True,
    gyr_rate_before_sample=True,
    gyr_noise_cov=_diag(3e-4),
    gyr_scale_noise=0.02,
    estimate_gyro_bias=True,
    gyro_bias_random_walk=1e-5,
    rest_rate_noise_std=0.003,
    acc_lowpass_s=0.75,
    acc_noise_cov=_diag(0.2),
    acc_noise_adapt=50.0,
    acc_tilt_only_after_s=2.0,
    acc_gate=2.0,
    acc_range=0.0,
    mag_heading_only=True,
    mag_noise_cov=_diag(1.0),
    mag_noise_adapt=1000.0,
    mag_noise_adapt_clip=4.0,
    mag_return_s=7.0,
    mag_gate=5.0,
    mag_dip_gate_deg=20.0,
    mag_dip_from_estimate=True,
    mag_settle_s=0.5,
    mag_reference_s=1.0,
    mag_max_reject_no_gyro_s=0.0,
    mag_strength_update="accepted",
    mag_relearn_s=20.0,
    mag_relearn_world=True,
    mag_relearn_min_rate=round(math.radians(20.0), 4),
    mag_first_relearn_s=5.0,
    mag_bias_innovation_limit=1.345,
    mag_hard_iron_tau_s=240.0,
    mag_hard_iron_prior=0.4,
    mag_delay_s=0.03,
    update_period_s=0.05,
    smooth_hard_iron=False,
)
