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
    """The last row has no rows after it: the combination leaves the forward estimate (to the
    rounding of a renormalised quaternion); the lights are the forward filter's."""
    t, g, a, m, _ = session
    keep_fit = ekf.PRESETS["default"].with_changes(smooth_hard_iron=True,
                                                   mag_bias_innovation_limit=math.inf)
    forward = ekf.filter_batch(t, g, a, m, settings=keep_fit)
    smoothed = ekf.smooth_batch(t, g, a, m, settings=keep_fit)
    np.testing.assert_allclose(smoothed.quat[-1], forward.quat[-1], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(smoothed.mag_rejected, forward.mag_rejected)
    np.testing.assert_array_equal(smoothed.at_rest, forward.at_rest)


def test_the_combination_is_anchored_on_the_filter_as_set_with_its_bias_limit(session):
    """The RTS pass runs over a forward pass without ``mag_bias_innovation_limit``; the
    estimate it is combined with, kept where the two disagree, is the filter as set (limit
    included), and so are the lights."""
    t, g, a, m, _ = session
    limited = ekf.PRESETS["default"].with_changes(smooth_hard_iron=True,
                                                  mag_bias_innovation_limit=0.5)
    as_set = ekf.filter_batch(t, g, a, m, settings=limited)
    unlimited = ekf.filter_batch(t, g, a, m, settings=limited.with_changes(
        mag_bias_innovation_limit=math.inf))
    smoothed = ekf.smooth_batch(t, g, a, m, settings=limited)
    assert not np.allclose(as_set.quat[-1], unlimited.quat[-1], atol=1e-9)  # the limit acts
    np.testing.assert_allclose(smoothed.quat[-1], as_set.quat[-1], rtol=0, atol=1e-12)
    for light in ("acc_rejected", "mag_rejected", "at_rest"):
        np.testing.assert_array_equal(getattr(smoothed, light), getattr(as_set, light))


def test_the_combination_is_anchored_on_the_filter_as_set_with_its_hard_iron_fit(session):
    """smooth_hard_iron false (the default preset): the RTS pass's forward pass runs without the
    online fit; the estimate combined with it is the filter as set, fit included, and so are
    the lights."""
    t, g, a, m, _ = session
    default = ekf.PRESETS["default"]
    assert not default.smooth_hard_iron and default.mag_hard_iron_tau_s > 0
    m = m + np.array([8.0, -6.0, 4.0])          # an offset for the fit to find
    as_set = ekf.filter_batch(t, g, a, m, settings=default)
    no_fit = ekf.filter_batch(t, g, a, m, settings=default.with_changes(
        mag_hard_iron_tau_s=0.0, mag_bias_innovation_limit=math.inf))
    smoothed = ekf.smooth_batch(t, g, a, m, settings=default)
    assert not np.allclose(as_set.quat[-1], no_fit.quat[-1], atol=1e-9)
    np.testing.assert_allclose(smoothed.quat[-1], as_set.quat[-1], rtol=0, atol=1e-12)
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
    """A raw magnetometer (400 uT of hard iron): the filter acquires its offset; the RTS pass's
    forward pass, which runs without the online fit, gets the readings corrected by the offset
    the filter found (without that correction it would have no heading: every reading beyond
    the gates of the field learned at the start). The smoothed heading is no worse than the
    forward filter's."""
    t, g, a, m, truth = session
    offset = np.array([60.0, -55.0, 400.0])
    raw = m + offset
    default = ekf.PRESETS["default"]
    forward = ekf.filter_batch(t, g, a, raw, settings=default)
    smoothed = ekf.smooth_batch(t, g, a, raw, settings=default)
    late = t > t[0] + 20.0
    f_head = ekf.error_angles_deg(forward.quat[late], truth[late])[1]
    s_head = ekf.error_angles_deg(smoothed.quat[late], truth[late])[1]
    assert _rms(f_head) < 5.0 and _rms(s_head) <= _rms(f_head) + 0.1
    assert np.max(s_head - f_head) <= 0.5
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
    heading is the forward filter's (within 1 deg). Without the stretch rule the RTS pass does
    carry it, and the consistency gate is what keeps the forward heading there."""
    t, g, a, m, truth, magnet = _magnet_session(seed, turn_deg)
    forward = ekf.filter_batch(t, g, a, m)
    smoothed = ekf.smooth_batch(t, g, a, m)
    f_head = ekf.error_angles_deg(forward.quat[magnet], truth[magnet])[1]
    s_head = ekf.error_angles_deg(smoothed.quat[magnet], truth[magnet])[1]
    assert np.max(s_head - f_head) <= 1.0, (np.max(s_head - f_head), _rms(f_head), _rms(s_head))
    x_s = ekf.smoother.smooth_parts(t, g, a, m, rejected_stretch_s=math.inf)[1]
    c_head = ekf.error_angles_deg(x_s[magnet, :4], truth[magnet])[1]
    assert np.max(c_head - f_head) > 5.0          # the combination without the rule
    gated = ekf.smooth_batch(t, g, a, m, rejected_stretch_s=math.inf)
    g_head = ekf.error_angles_deg(gated.quat[magnet], truth[magnet])[1]
    assert np.max(g_head - f_head) <= 1.0


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


def _magnet_at_the_end(seed: int, strength_ut: float):
    """A phone turning (the standard script, 60 s, its own disturbance taken out) with a magnet
    of `strength_ut` held beside it (a sensor-frame field along x, ramped in over 0.5 s) from
    45 s to the end: a backward pass meets it first. Returns t, gyr, acc, mag, the truth."""
    s = simulate(duration_s=60.0, seed=seed)
    t, g, a, m = s.to_batch_arrays()
    t_ms = np.round(t * 1000).astype(np.int64)
    truth = s.quat_at(t_ms)
    rows = np.isfinite(m[:, 0])
    R = ekf.quaternion.to_matrix(truth[rows])                 # sensor -> world
    field = m[rows] - np.einsum("nji,nj->ni", R, s.mag_disturbance_at(t_ms[rows]))
    edge = np.clip((t[rows] - t[0] - 45.0) / 0.5, 0.0, 1.0)
    field += (edge * edge * (3.0 - 2.0 * edge))[:, None] * np.array([strength_ut, 0.0, 0.0])
    m = m.copy()
    m[rows] = field
    return t, g, a, m, truth


@pytest.mark.parametrize("seed", [0, 3])
def test_a_magnet_the_backward_pass_meets_first_makes_no_row_worse(seed):
    """A 20 uT magnet from 45 s to the end: weak enough that the forward filter's gates pass
    some of its readings, so the heading it ends with is off, and an RTS pass alone carries that
    heading back over the rows before (4 to 6 deg worse than the forward filter there). The
    combination keeps the forward estimate where the two disagree: at every row after the
    first 2 s the smoothed total error is at most the forward filter's + 0.5 deg, and its mean
    is no larger."""
    t, g, a, m, truth = _magnet_at_the_end(seed, 20.0)
    forward = ekf.filter_batch(t, g, a, m)
    smoothed = ekf.smooth_batch(t, g, a, m)
    sel = t > t[0] + 2.0
    f_tot = ekf.error_angles_deg(forward.quat[sel], truth[sel])[0]
    s_tot = ekf.error_angles_deg(smoothed.quat[sel], truth[sel])[0]
    assert np.max(s_tot - f_tot) <= 0.5, np.max(s_tot - f_tot)
    assert np.mean(s_tot) <= np.mean(f_tot)
    # where the gate found the two inconsistent, the forward filter's estimate, bit for bit
    _, combined, _, stat, _, _ = ekf.smoother.smooth_parts(t, g, a, m)
    kept = ~(stat <= ekf.smoother.CHI2_99[3])
    assert 0.01 < kept.mean() < 0.99
    np.testing.assert_array_equal(smoothed.quat[kept], forward.quat[kept])
    np.testing.assert_array_equal(smoothed.quat[~kept], combined[~kept, :4])


@pytest.mark.parametrize("seed", [0, 7])
def test_on_a_clean_recording_the_smoother_is_no_worse_than_forward(seed):
    """The standard script without its magnetic disturbance: the mean total error of the
    smoothed estimates (after the first 2 s) is at most the forward filter's, and in every
    whole second the mean smoothed error is at most the forward filter's + 0.25 deg."""
    s = simulate(duration_s=60.0, seed=seed)
    t, g, a, m = s.to_batch_arrays()
    t_ms = np.round(t * 1000).astype(np.int64)
    truth = s.quat_at(t_ms)
    rows = np.isfinite(m[:, 0])
    R = ekf.quaternion.to_matrix(truth[rows])
    m = m.copy()
    m[rows] -= np.einsum("nji,nj->ni", R, s.mag_disturbance_at(t_ms[rows]))
    forward = ekf.filter_batch(t, g, a, m)
    smoothed = ekf.smooth_batch(t, g, a, m)
    sel = t > t[0] + 2.0
    f_tot = ekf.error_angles_deg(forward.quat[sel], truth[sel])[0]
    s_tot = ekf.error_angles_deg(smoothed.quat[sel], truth[sel])[0]
    assert np.mean(s_tot) <= np.mean(f_tot)
    second = np.floor(t[sel] - t[sel][0]).astype(int)
    per_second = np.bincount(second, s_tot - f_tot) / np.bincount(second)
    assert np.max(per_second) <= 0.25, np.max(per_second)


def test_fuse_information_is_the_combination_of_two_gaussian_estimates():
    """Information form against the covariance form of the same combination:
    x = P_b (P_f + P_b)^-1 x_f + P_f (P_f + P_b)^-1 x_b,  P = P_f (P_f + P_b)^-1 P_b."""
    from ekf.smoother import fuse_information

    rng = np.random.default_rng(4)
    for _ in range(20):
        A, B = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
        P_f, P_b = A @ A.T + 0.1 * np.eye(6), B @ B.T + 0.1 * np.eye(6)
        x_f, x_b = rng.normal(size=6), rng.normal(size=6)
        Y_f, Y_b = np.linalg.inv(P_f), np.linalg.inv(P_b)
        x, P = fuse_information(Y_f, Y_f @ x_f, Y_b, Y_b @ x_b)
        S_inv = np.linalg.inv(P_f + P_b)
        np.testing.assert_allclose(x, P_b @ S_inv @ x_f + P_f @ S_inv @ x_b, atol=1e-9)
        np.testing.assert_allclose(P, P_f @ S_inv @ P_b, atol=1e-9)
    # an estimate with no information in a direction leaves the other's there
    P_f = np.diag([1.0, 2.0, 3.0])
    x, _ = fuse_information(np.linalg.inv(P_f), np.zeros(3), np.diag([4.0, 0.0, 0.0]),
                            np.array([4.0, 0.0, 0.0]))
    np.testing.assert_allclose(x, [0.8, 0.0, 0.0], atol=1e-12)


def test_the_consistency_statistic_is_chi_square_with_three_degrees_of_freedom():
    """Two independent Gaussian estimates of one truth: their attitude difference tested
    against the sum of their attitude covariances exceeds the 99 % point about 1 % of the
    time, and the gate's value is that point."""
    from ekf.smoother import consistency
    from ekf.smoother import CHI2_99

    rng = np.random.default_rng(7)
    A, B = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    P_f, P_b = A @ A.T + 0.1 * np.eye(6), B @ B.T + 0.1 * np.eye(6)
    Y_b = np.linalg.inv(P_b)
    L = np.linalg.cholesky(P_f + P_b)
    stats = np.array([consistency(Y_b, Y_b @ (L @ rng.normal(size=6)), P_f)
                      for _ in range(4000)])
    assert 0.005 < np.mean(stats > CHI2_99[3]) < 0.02
    assert 2.0 < np.median(stats) < 2.8                     # chi-square(3): 2.37
    chi2 = pytest.importorskip("scipy.stats").chi2
    assert CHI2_99[3] == pytest.approx(chi2.ppf(0.99, 3), rel=1e-12)
    assert CHI2_99[6] == pytest.approx(chi2.ppf(0.99, 6), rel=1e-12)
