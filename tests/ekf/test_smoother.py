"""The offline smoother (ekf.smooth_batch): the EKF forward, the backward RTS pass."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

import ekf
from ekf.simulate import simulate


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.fixture(scope="module", params=[0, 3], ids=lambda s: f"seed{s}")
def session(request):
    s = simulate(duration_s=40.0, seed=request.param, gyro_bias=(0.01, -0.02, 0.015))
    t, g, a, m = s.to_batch_arrays()
    return t, g, a, m, s.quat_at(np.round(t * 1000).astype(np.int64))


@pytest.mark.parametrize("preset", ["default", "course"])
def test_the_smoother_is_never_worse_than_the_forward_filter(session, preset):
    t, g, a, m, truth = session
    forward = ekf.filter_batch(t, g, a, m, settings=preset)
    smoothed = ekf.smooth_batch(t, g, a, m, settings=preset)
    sel = t > t[0] + 2.0
    f_tot, _, f_incl = ekf.error_angles_deg(forward.quat[sel], truth[sel])
    s_tot, _, s_incl = ekf.error_angles_deg(smoothed.quat[sel], truth[sel])
    assert _rms(s_tot) <= _rms(f_tot)
    # the low-passed accelerometer (default) is correlated in time, which the RTS pass does not
    # model: its tilt may come out a little rougher, never much
    assert _rms(s_incl) <= 1.1 * _rms(f_incl)
    np.testing.assert_allclose(np.linalg.norm(smoothed.quat, axis=1), 1.0, atol=1e-12)
    assert (smoothed.quat[:, 0] >= 0).all()


def test_the_last_estimate_and_the_lights_are_the_forward_filters(session):
    t, g, a, m, _ = session
    keep_fit = ekf.PRESETS["default"].with_changes(smooth_hard_iron=True,
                                                   mag_bias_innovation_limit=math.inf)
    forward = ekf.filter_batch(t, g, a, m, settings=keep_fit)
    smoothed = ekf.smooth_batch(t, g, a, m, settings=keep_fit)
    np.testing.assert_array_equal(smoothed.quat[-1], forward.quat[-1])
    np.testing.assert_array_equal(smoothed.mag_rejected, forward.mag_rejected)
    np.testing.assert_array_equal(smoothed.at_rest, forward.at_rest)


def test_the_forward_pass_runs_without_the_bias_innovation_limit(session):
    """The limit holds back a gain the forward covariance asks for; the backward pass trusts
    those covariances, so the smoother's forward pass always runs without it (its lights are
    still those of the filter as set)."""
    t, g, a, m, _ = session
    limited = ekf.PRESETS["default"].with_changes(smooth_hard_iron=True,
                                                  mag_bias_innovation_limit=0.5)
    as_set = ekf.filter_batch(t, g, a, m, settings=limited)
    unlimited = ekf.filter_batch(t, g, a, m, settings=limited.with_changes(
        mag_bias_innovation_limit=math.inf))
    smoothed = ekf.smooth_batch(t, g, a, m, settings=limited)
    np.testing.assert_array_equal(smoothed.quat[-1], unlimited.quat[-1])
    assert not np.array_equal(as_set.quat[-1], unlimited.quat[-1])    # the limit did something
    for light in ("acc_rejected", "mag_rejected", "at_rest"):
        np.testing.assert_array_equal(getattr(smoothed, light), getattr(as_set, light))


def test_without_the_hard_iron_fit_the_forward_pass_drops_only_the_fit(session):
    """smooth_hard_iron false (the default preset): the pass forward is the filter without the
    online fit, the lights stay those of the filter as set."""
    t, g, a, m, _ = session
    default = ekf.PRESETS["default"]
    assert not default.smooth_hard_iron and default.mag_hard_iron_tau_s > 0
    m = m + np.array([8.0, -6.0, 4.0])          # an offset for the fit to find
    as_set = ekf.filter_batch(t, g, a, m, settings=default)
    no_fit = ekf.filter_batch(t, g, a, m, settings=default.with_changes(
        mag_hard_iron_tau_s=0.0, mag_bias_innovation_limit=math.inf))
    smoothed = ekf.smooth_batch(t, g, a, m, settings=default)
    np.testing.assert_array_equal(smoothed.quat[-1], no_fit.quat[-1])
    assert not np.array_equal(as_set.quat[-1], no_fit.quat[-1])
    assert (as_set.mag_rejected != no_fit.mag_rejected).any()   # so the lights tell them apart
    for light in ("acc_rejected", "mag_rejected", "at_rest"):
        np.testing.assert_array_equal(getattr(smoothed, light), getattr(as_set, light))


def test_the_smoother_sees_the_future_a_late_magnetometer_fixes_the_start():
    """Magnetometer off for the first 10 s (heading from a wrong start), then on: the forward
    filter is wrong until the field arrives, the smoother carries it back."""
    s = simulate(duration_s=30.0, seed=5)
    t, g, a, m = s.to_batch_arrays()
    truth = s.quat_at(np.round(t * 1000).astype(np.int64))
    m = m.copy()
    m[t < t[0] + 10.0] = np.nan
    forward = ekf.filter_batch(t, g, a, m)
    smoothed = ekf.smooth_batch(t, g, a, m)
    early = (t > t[0] + 1.0) & (t < t[0] + 9.0)
    f_err = _rms(ekf.error_angles_deg(forward.quat[early], truth[early])[1])
    s_err = _rms(ekf.error_angles_deg(smoothed.quat[early], truth[early])[1])
    assert s_err < 0.5 * f_err


def test_a_raw_magnetometer_is_calibrated_before_smoothing(session):
    """A raw magnetometer (400 uT of hard iron): the filter acquires its offset; the smoother's
    forward pass, which runs without the online fit, gets the readings corrected by the offset
    the filter found, so its heading holds (without that correction it would have none: every
    reading beyond the gates of the field learned at the start)."""
    t, g, a, m, truth = session
    offset = np.array([60.0, -55.0, 400.0])
    raw = m + offset
    default = ekf.PRESETS["default"]
    forward = ekf.filter_batch(t, g, a, raw, settings=default)
    smoothed = ekf.smooth_batch(t, g, a, raw, settings=default)
    late = t > t[0] + 20.0
    f_head = _rms(ekf.error_angles_deg(forward.quat[late], truth[late])[1])
    s_head = _rms(ekf.error_angles_deg(smoothed.quat[late], truth[late])[1])
    calibrated = ekf.smooth_batch(t, g, a, m, settings=default)
    c_head = _rms(ekf.error_angles_deg(calibrated.quat[late], truth[late])[1])
    assert f_head < 5.0 and s_head < 5.0
    assert s_head < 1.5 * c_head + 0.5           # as if it had been calibrated
    np.testing.assert_array_equal(smoothed.mag_rejected, forward.mag_rejected)


def _magnet_session(seed: int, field_turn_deg: float = 0.0):
    """A phone turning (the standard script, 60 s, its own small disturbance taken out) with a
    150 uT magnet held beside it (a sensor-frame field, ramped in and out over 0.5 s) from 25 s
    to 35 s; from the middle of the magnet on, the Earth field's horizontal part is turned by
    `field_turn_deg` about up (the phone carried to where north reads differently: the same
    strength and dip, so the gates pass it). Returns t, gyr, acc, mag, the truth per row and
    the rows of the magnet."""
    s = simulate(duration_s=60.0, seed=seed)
    t, g, a, m = s.to_batch_arrays()
    t_ms = np.round(t * 1000).astype(np.int64)
    truth = s.quat_at(t_ms)
    rows = np.isfinite(m[:, 0])
    R = ekf.quaternion.to_matrix(truth[rows])                 # sensor -> world
    field = m[rows] - np.einsum("nji,nj->ni", R, s.mag_disturbance_at(t_ms[rows]))
    tau = t[rows] - t[0]
    edge = np.clip(np.minimum(tau - 25.0, 35.0 - tau) / 0.5, 0.0, 1.0)
    field += (edge * edge * (3.0 - 2.0 * edge))[:, None] * np.array([150.0, 0.0, 0.0])
    if field_turn_deg:
        m0 = np.asarray(s.metadata["m0"])
        c, sn = math.cos(math.radians(field_turn_deg)), math.sin(math.radians(field_turn_deg))
        turned = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]]) @ m0
        after = tau > 30.0
        field[after] += np.einsum("nji,j->ni", R[after], turned - m0)
    m = m.copy()
    m[rows] = field
    magnet = (t > t[0] + 25.0) & (t < t[0] + 35.0)
    return t, g, a, m, truth, magnet


@pytest.mark.parametrize("seed", [1, 3])
def test_a_magnet_beside_the_phone_the_smoother_is_nowhere_worse_than_forward(seed):
    """The gates reject the magnet for its 10 s; the field after it is the one before. The
    smoothed heading is within 1 deg of the forward filter's at every row or better, and the
    whole is no worse."""
    t, g, a, m, truth, magnet = _magnet_session(seed)
    forward = ekf.filter_batch(t, g, a, m)
    smoothed = ekf.smooth_batch(t, g, a, m)
    assert forward.mag_rejected[magnet].mean() > 0.95
    sel = t > t[0] + 2.0
    f_tot, f_head, _ = ekf.error_angles_deg(forward.quat[sel], truth[sel])
    s_tot, s_head, _ = ekf.error_angles_deg(smoothed.quat[sel], truth[sel])
    assert np.max(s_head - f_head) <= 1.0
    assert _rms(s_tot) <= _rms(f_tot)


@pytest.mark.parametrize("seed, turn_deg", [(1, 30.0), (3, -30.0)])
def test_no_heading_is_carried_across_a_rejected_stretch(seed, turn_deg):
    """The magnet of the test above, and north reads 30 deg off after it: the forward filter
    held its heading through the magnet by the gyroscope and comes to the new field slowly
    (mag_return_s). An RTS pass that carried the heading learned after the magnet back across
    the rejected stretch would turn the whole stretch by it; within the stretch the smoothed
    heading is the forward filter's (within 1 deg of the filter as set, which keeps its
    hard-iron fit)."""
    t, g, a, m, truth, magnet = _magnet_session(seed, turn_deg)
    forward = ekf.filter_batch(t, g, a, m)
    smoothed = ekf.smooth_batch(t, g, a, m)
    f_head = ekf.error_angles_deg(forward.quat[magnet], truth[magnet])[1]
    s_head = ekf.error_angles_deg(smoothed.quat[magnet], truth[magnet])[1]
    assert np.max(s_head - f_head) <= 1.0, (np.max(s_head - f_head), _rms(f_head), _rms(s_head))
    # without the rule the stretch takes the heading from after it
    carried = ekf.smooth_batch(t, g, a, m, rejected_stretch_s=math.inf)
    c_head = ekf.error_angles_deg(carried.quat[magnet], truth[magnet])[1]
    assert np.max(c_head - f_head) > 5.0


def test_a_rejected_stretch_is_a_long_run_of_rejected_readings_after_a_used_one():
    """Rows with no magnetometer reading between passing ones, a short rejection (a reading
    out and the settling after it) and a run with no passing reading before it are in no
    stretch; a run of rejected readings longer than the limit is, up to the passing reading."""
    from ekf.smoother import rejected_stretches

    t = np.arange(0.0, 10.0, 0.01)
    present = np.zeros(t.size, bool)
    present[::5] = True                                   # the magnetometer at 20 Hz
    flag = np.zeros(t.size, bool)
    flag[100:150] = True                                  # 0.5 s: short
    flag[300:600] = True                                  # 3 s: a stretch
    out = rejected_stretches(t, present, flag, 1.0)
    assert not out[:300].any() and out[300:600].all() and not out[600:].any()
    assert not rejected_stretches(t, present, flag, 3.5).any()
    flag[:300] = True                     # rejected from the first reading on, through 6 s
    assert not rejected_stretches(t, present, flag, 1.0).any()
    assert not rejected_stretches(t, present, np.zeros(t.size, bool), 1.0).any()


@pytest.fixture(scope="module")
def raw_session():
    """A raw magnetometer (hard iron the filter acquires) and a gyroscope bias: the smoother's
    forward pass subtracts the offset and runs without the fit; rows of every kind."""
    s = simulate(duration_s=12.0, seed=5, gyro_bias=(0.01, -0.02, 0.015))
    t, g, a, m = s.to_batch_arrays()
    return t, g, a, m + np.array([180.0, -120.0, 60.0])


@given(block_rows=st.integers(1, 1300), preset=st.sampled_from(["default", "course"]))
@hsettings(max_examples=12, deadline=None,
           suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_the_smoothed_estimates_do_not_depend_on_the_block_size(raw_session, block_rows, preset):
    """The forward records are held one block at a time and recorded again for the backward
    pass: any block size gives the estimates of one block, bit for bit."""
    t, g, a, m = raw_session
    whole = ekf.smooth_batch(t, g, a, m, settings=preset, block_rows=len(t))
    blocks = ekf.smooth_batch(t, g, a, m, settings=preset, block_rows=block_rows)
    for name in ("quat", "gyro_bias", "acc_rejected", "mag_rejected", "at_rest"):
        assert np.array_equal(getattr(whole, name), getattr(blocks, name)), name
