"""The calibration workspace's numerics on simulated data with known truth: rest statistics,
warnings, Allan deviation read-offs, the magnetometer ellipsoid fit and its coverage."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st

from ekf import magcal
from ekf.allan import allan_deviation
from ekf.noise import VERDICT_RULE, analyse_rest, autocorrelation
from ekf.simulate import DEFAULT_NOISE_STD, simulate

BIAS = (0.01, -0.02, 0.005)


def _sensors(session):
    return dict(t_acc=session.acc.t_ms / 1000, acc=session.acc.values,
                t_gyr=session.gyr.t_ms / 1000, gyr=session.gyr.values,
                t_mag=session.mag.t_ms / 1000, mag=session.mag.values)


@pytest.fixture(scope="module")
def rest():
    return simulate(duration_s=20.0, script="rest", seed=3, gyro_bias=BIAS)


def test_rest_statistics_find_the_simulators_noise_and_bias_within_10_percent(rest):
    analysis = analyse_rest(**_sensors(rest))
    result = analysis.result
    for name in ("acc", "gyr", "mag"):
        truth = np.array(DEFAULT_NOISE_STD[name])
        np.testing.assert_allclose(result.sensor(name).std, truth, rtol=0.10)
    np.testing.assert_allclose(result.gyr_bias, BIAS, rtol=0.10)
    assert result.g == pytest.approx(9.81, rel=1e-3)
    assert analysis.warnings == []
    for reports in analysis.axes.values():
        assert len(reports) == 3
        for r in reports:          # simulated noise is white and Gaussian
            assert r.gaussian and not r.correlated
            assert r.acf[0] == pytest.approx(1.0)
    assert "Gaussian" in analysis.format_report()


def test_motion_warning_fires_on_a_moving_stream_and_says_when():
    moving = simulate(duration_s=30.0, seed=5)
    analysis = analyse_rest(**_sensors(moving))
    moved = [w for w in analysis.warnings if w.kind == "moved"]
    assert moved and moved[0].intervals_s
    start, end = moved[0].intervals_s[0]
    t0 = moving.t0_ms / 1000
    first_motion = moving.rest_intervals_ms[0, 1] / 1000   # the first rest ends here
    assert abs(start - first_motion) < 0.5 and end > start
    assert f"{start - t0:.1f}" in moved[0].message
    assert analysis.moving.any() and not analysis.moving.all()


def test_missing_sensor_too_few_samples_and_a_strong_field_are_warned(rest):
    short = analyse_rest(t_acc=rest.acc.t_ms[:50] / 1000, acc=rest.acc.values[:50],
                         t_mag=rest.mag.t_ms[:50] / 1000, mag=rest.mag.values[:50] * 2.0)
    kinds = short.warning_kinds()
    assert {"missing", "too_few", "field_strength"} <= kinds
    assert any("gyroscope" in w.message for w in short.warnings if w.kind == "missing")
    assert "gyr" not in short.axes


def test_correlated_noise_is_seen_in_the_autocorrelation():
    rng = np.random.default_rng(0)
    white = rng.standard_normal(5000)
    ar1 = np.empty_like(white)
    ar1[0] = white[0]
    for k in range(1, len(white)):
        ar1[k] = 0.9 * ar1[k - 1] + white[k]
    acf = autocorrelation(ar1, 20)
    assert acf[1] == pytest.approx(0.9, abs=0.03)
    assert acf[10] == pytest.approx(0.9 ** 10, abs=0.1)
    t = np.arange(5000) / 50.0
    analysis = analyse_rest(t_mag=t, mag=np.column_stack([ar1, white, white]) * 0.1 + [0, 20, -40])
    x, y, _ = analysis.axes["mag"]
    assert x.correlated and not y.correlated
    assert x.correlation_time_s == pytest.approx(0.2, abs=0.06)   # 1/e after ~ -1/ln 0.9 lags


def test_allan_deviation_reads_off_the_angle_random_walk():
    session = simulate(duration_s=120.0, script="rest", seed=8, gyro_bias=BIAS)
    result = allan_deviation(session.gyr.t_ms / 1000, session.gyr.values)
    rate = result.rate_hz
    assert rate == pytest.approx(100.0, rel=0.01)
    for axis, std in zip(result.axes, DEFAULT_NOISE_STD["gyr"]):
        # white rate noise of std s at rate f: N = s / sqrt(f)
        assert axis.arw == pytest.approx(std / np.sqrt(rate), rel=0.10)
        assert axis.bias_instability_is_bound       # no flicker floor in white noise
        taus, line = axis.arw_line([1.0])
        assert line[0] == pytest.approx(axis.arw)
    assert "ARW" in result.format_table()
    with pytest.raises(ValueError, match="at least 10"):
        allan_deviation(np.arange(5) / 100.0, np.zeros((5, 3)))


def test_allan_bias_instability_is_the_minimum_over_0664():
    rng = np.random.default_rng(4)
    n = 100 * 600
    # white noise plus a slow random walk: a bottom inside the curve, not at its end
    rate = 1e-3 * rng.standard_normal(n) + np.cumsum(2e-6 * rng.standard_normal(n))
    result = allan_deviation(np.arange(n) / 100.0, np.column_stack([rate, rate, rate]))
    axis = result.axes[0]
    assert not axis.bias_instability_is_bound
    assert axis.bias_instability == pytest.approx(axis.adev.min() / 0.664)


# ---- magnetometer ---------------------------------------------------------------------------

def _sphere_readings(n, field=50.0, seed=1, noise=0.3):
    rng = np.random.default_rng(seed)
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return field * d + rng.normal(0.0, noise, (n, 3))


SOFT = np.array([[1.12, 0.06, 0.02], [0.06, 0.93, -0.04], [0.02, -0.04, 1.0]])
SOFT = SOFT / np.linalg.det(SOFT) ** (1 / 3)       # det 1: a pure distortion
OFFSET = np.array([35.0, -20.0, 300.0])


def test_ellipsoid_fit_recovers_a_known_offset_and_matrix():
    true = _sphere_readings(3000)
    raw = true @ SOFT.T + OFFSET
    cal = magcal.calibrate_magnetometer(raw)
    assert cal.model == "ellipsoid" and not cal.nothing_to_correct
    np.testing.assert_allclose(cal.offset, OFFSET, atol=0.2)
    np.testing.assert_allclose(cal.soft_iron, np.linalg.inv(SOFT), atol=0.01)
    assert cal.field_strength == pytest.approx(50.0, rel=0.005)
    assert cal.norm_std_before > 20 and cal.norm_std_after < 0.4
    assert cal.coverage == 1.0 and cal.fit_error_pct < 1.0
    np.testing.assert_allclose(np.linalg.norm(cal.correct(raw), axis=1).mean(), 50.0, rtol=0.01)
    again = magcal.MagCalibration.from_dict(cal.to_dict())
    np.testing.assert_allclose(again.soft_iron, cal.soft_iron)
    assert "hard-iron offset" in cal.format_report()


def test_calibrated_readings_have_nothing_to_correct():
    cal = magcal.calibrate_magnetometer(_sphere_readings(2000))
    assert cal.nothing_to_correct and "nothing to correct" in cal.message
    assert cal.settings_changes()["mag_hard_iron"] == (0.0, 0.0, 0.0)


def test_little_coverage_fits_the_offset_only_and_says_so():
    rng = np.random.default_rng(2)
    # turning about one axis only: a circle of directions
    angle = rng.uniform(0, 2 * np.pi, 800)
    circle = np.column_stack([np.cos(angle), np.sin(angle), 0.3 + 0 * angle]) * 45.0
    cal = magcal.calibrate_magnetometer(circle + OFFSET + rng.normal(0, 0.2, circle.shape))
    assert cal.model == "sphere"
    np.testing.assert_array_equal(cal.soft_iron, np.eye(3))
    assert cal.coverage < 0.35 and "directions" in cal.message


def test_coverage_grows_with_the_directions_visited():
    full = _sphere_readings(5000)
    assert magcal.coverage(full) == 1.0
    upper = full[full[:, 2] > 0]
    assert 0.45 <= magcal.coverage(upper) <= 0.62   # half, plus the bins along the equator
    assert magcal.coverage(full[:3]) <= 0.03
    assert magcal.coverage(full + OFFSET, center=OFFSET) == 1.0
    assert magcal.coverage(np.empty((0, 3))) == 0.0
    d = magcal.fibonacci_directions(100)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.abs(d.mean(axis=0)).max() < 0.02           # evenly spread


@hsettings(max_examples=25, deadline=None)
@given(offset=st.tuples(*[st.floats(-400, 400)] * 3), field=st.floats(20, 70),
       seed=st.integers(0, 10_000))
def test_any_hard_iron_offset_is_found(offset, field, seed):
    raw = _sphere_readings(600, field, seed, noise=0.1) + np.array(offset)
    cal = magcal.calibrate_magnetometer(raw)
    np.testing.assert_allclose(cal.offset, offset, atol=0.05 * field)
    assert cal.field_strength == pytest.approx(field, rel=0.05)


def test_the_settings_correction_is_none_for_the_identity():
    import ekf
    assert magcal.settings_correction(ekf.PRESETS["default"]) is None
    s = ekf.PRESETS["default"].with_changes(mag_hard_iron=(1.0, 2.0, 3.0))
    offset, soft = magcal.settings_correction(s)
    np.testing.assert_array_equal(offset, [1, 2, 3])
    np.testing.assert_array_equal(soft, np.eye(3))


def test_a_magnet_passing_by_is_left_out_of_the_fit():
    session = simulate(duration_s=40.0, seed=5)       # the script has a magnetic disturbance
    raw = session.mag.values + OFFSET
    disturbed = session.inside(session.mag_disturbance_intervals_ms, session.mag.t_ms)
    cal = magcal.calibrate_magnetometer(raw)
    np.testing.assert_allclose(cal.offset, OFFSET, atol=0.3)
    assert cal.outliers >= 0.5 * disturbed.sum() and "left out" in cal.message
    assert cal.fit_error_pct < 3.0


def test_readings_of_a_phone_lying_still_are_no_fit():
    from ekf import magcal
    rng = np.random.default_rng(4)
    still = np.array([5.0, 20.0, -40.0]) + 0.8 * rng.standard_normal((500, 3))
    with pytest.raises(ValueError, match="the phone hardly turned"):
        magcal.calibrate_magnetometer(still)
    circle = np.column_stack([45 * np.cos(np.linspace(0, 6, 500)),
                              45 * np.sin(np.linspace(0, 6, 500)), np.full(500, -20.0)])
    assert magcal.calibrate_magnetometer(circle).samples == 500   # one plane is enough to fit


def test_the_gaussian_verdict_names_its_tests_and_says_mixed_when_they_disagree():
    """Issue 51: "Gaussian" came from the D'Agostino p-value alone (an unstated 1 % cut) while
    the Anderson-Darling figure beside it said otherwise (a quantised gyroscope axis: p = 0.44,
    A² = 93)."""
    rng = np.random.default_rng(1)
    quantised = np.round(rng.standard_normal(3000))       # few levels: a step-shaped CDF
    samples = {"Gaussian": rng.standard_normal(3000), "mixed": quantised,
               "not Gaussian": rng.exponential(size=3000)}
    for expected, x in samples.items():
        analysis = analyse_rest(t_gyr=np.arange(len(x)) * 0.01,
                                gyr=np.column_stack([x, x, x]) * 1e-3)
        report = analysis.axes["gyr"][2]
        assert report.verdict == expected, (expected, report.normality_p, report.anderson)
        assert report.gaussian == (expected == "Gaussian")
        assert report.anderson_critical == pytest.approx(1.035, abs=0.01)    # A² at 1 %
        assert analysis.to_dict()["axes"]["gyr"][2]["normality_verdict"] == expected
    mixed = analyse_rest(t_gyr=np.arange(3000) * 0.01, gyr=np.column_stack([quantised] * 3))
    report = mixed.axes["gyr"][0]
    assert report.normality_p >= 0.01 and report.anderson > report.anderson_critical
    text = mixed.format_report()
    assert "mixed" in text and VERDICT_RULE in text
    assert "D'Agostino–Pearson K² p ≥ 0.01" in VERDICT_RULE and "Anderson–Darling" in VERDICT_RULE


def test_a_moment_of_motion_reads_as_a_moment_not_a_zero_length_stretch():
    """Issue 51: the motion warning listed "0.6–0.6 s"."""
    from ekf.noise import _stretch_text
    assert _stretch_text(0.61, 0.63) == "0.6 s"
    assert _stretch_text(3.21, 4.0) == "3.2–4.0 s"
