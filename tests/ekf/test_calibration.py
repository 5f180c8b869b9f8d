"""Task-2 calibration: statistics recovered from synthetic rest data with known truth, a tilted
rest pose, automatic rest finding, and the course's real calibration log."""

from __future__ import annotations

import numpy as np
import pytest

from ekf.calibration import (RestSegment, calibrate, calibrate_rest, find_rest_segment,
                             rest_mask)
from ekf.quaternion import from_euler
from ekf.settings import PRESETS, EKFSettings
from ekf.simulate import simulate

ACC_COV = np.array([[4e-4, 1e-4, -5e-5], [1e-4, 3e-4, 2e-5], [-5e-5, 2e-5, 9e-4]])
GYR_COV = np.array([[6e-7, -1e-7, 0.0], [-1e-7, 1e-6, 3e-7], [0.0, 3e-7, 2.5e-6]])
MAG_COV = np.array([[0.45, 0.05, -0.02], [0.05, 0.40, 0.0], [-0.02, 0.0, 0.5]])


@pytest.fixture(scope="module")
def flat_rest():
    """Two minutes flat and still at 200 Hz, known noise covariances and gyro bias."""
    return simulate(duration_s=120.0, script="rest", seed=21, gyro_bias=(0.002, -0.001, 0.0005),
                    noise={"acc": ACC_COV, "gyr": GYR_COV, "mag": MAG_COV},
                    rates_hz={"gyr": 200, "acc": 200, "mag": 100, "ori": 10})


def test_recovers_means_covariances_bias_g_and_m0_from_flat_rest(flat_rest):
    s = flat_rest
    result = calibrate(s.acc.values, s.gyr.values, s.mag.values)
    counts = (result.acc.count, result.gyr.count, result.mag.count)
    assert counts == (len(s.acc), len(s.gyr), len(s.mag))
    for stats, cov in ((result.acc, ACC_COV), (result.gyr, GYR_COV), (result.mag, MAG_COV)):
        n = stats.count
        # Sample covariance entries scatter by about sqrt((Σii Σjj + Σij²) / n).
        tolerance = 5 * np.sqrt((np.outer(np.diag(cov), np.diag(cov)) + cov ** 2) / n)
        assert np.all(np.abs(stats.cov - cov) < tolerance)
        np.testing.assert_allclose(stats.std, np.sqrt(np.diag(stats.cov)))
    gyr_tol = 5 * np.sqrt(np.diag(GYR_COV) / result.gyr.count)
    assert np.all(np.abs(result.gyr_bias - [0.002, -0.001, 0.0005]) < gyr_tol)
    assert abs(result.g - 9.81) < 5 * np.sqrt(ACC_COV[2, 2] / result.acc.count)
    assert result.tilt_deg < 0.05
    np.testing.assert_allclose(result.m0, [0.0, 15.5, -48.0], atol=0.05)
    assert result.field_strength == pytest.approx(np.hypot(15.5, 48.0), abs=0.05)


def test_flat_phone_gives_exactly_the_course_formula(flat_rest):
    # Gravity exactly along z: no tilt to undo, so m0 is the course's (0, sqrt(mx² + my²), mz).
    exactly_flat = flat_rest.acc.values * [0.0, 0.0, 1.0]
    result = calibrate(exactly_flat, None, flat_rest.mag.values)
    mx, my, mz = flat_rest.mag.values.mean(axis=0)
    np.testing.assert_allclose(result.m0, [0.0, np.hypot(mx, my), mz], rtol=1e-12, atol=1e-12)
    # With the noisy accelerometer of a flat phone the two differ only by noise.
    noisy = calibrate(flat_rest.acc.values, None, flat_rest.mag.values)
    np.testing.assert_allclose(noisy.m0, result.m0, atol=0.02)


def test_tilted_rest_pose_still_gives_the_level_field():
    tilted = from_euler(np.radians(-70.0), np.radians(25.0), np.radians(-40.0))
    s = simulate(duration_s=30.0, script="rest", seed=22, initial_quat=tilted)
    result = calibrate(s.acc.values, s.gyr.values, s.mag.values)
    assert result.tilt_deg == pytest.approx(np.degrees(np.arccos(
        np.cos(np.radians(25.0)) * np.cos(np.radians(40.0)))), abs=0.1)
    assert result.g == pytest.approx(9.81, abs=0.01)
    np.testing.assert_allclose(result.m0, [0.0, 15.5, -48.0], atol=0.1)
    # The flat-phone formula applied naively would be far off here: the tilt matters.
    mx, my, mz = result.mag.mean
    assert abs(mz - (-48.0)) > 5.0


def test_nan_rows_are_dropped(flat_rest):
    acc = flat_rest.acc.values.copy()
    acc[::7] = np.nan
    acc[3, 1] = np.nan
    result = calibrate(acc, flat_rest.gyr.values, flat_rest.mag.values)
    kept = np.all(np.isfinite(acc), axis=1)
    assert result.acc.count == kept.sum()
    np.testing.assert_allclose(result.acc.mean, acc[kept].mean(axis=0))
    np.testing.assert_allclose(result.acc.cov, np.cov(acc[kept], rowvar=False))


def test_missing_sensor_keeps_base_settings(flat_rest):
    result = calibrate(flat_rest.acc.values, None, flat_rest.mag.values)
    assert result.gyr is None and result.gyr_bias is None
    base = PRESETS["course"]
    settings = result.to_settings(base)
    assert settings.gyr_noise_cov == base.gyr_noise_cov and settings.gyr_bias == base.gyr_bias
    assert settings.g == pytest.approx(result.g)
    assert "(no data)" in result.format_table()


def test_to_settings_replaces_calibrated_fields_only(flat_rest):
    result = calibrate(flat_rest.acc.values, flat_rest.gyr.values, flat_rest.mag.values)
    base = PRESETS["course"].with_changes(acc_gate=0.7)
    settings = result.to_settings(base)
    assert isinstance(settings, EKFSettings)
    assert settings.acc_gate == 0.7 and settings.mag_alpha == base.mag_alpha
    assert settings.g == pytest.approx(result.g)
    assert settings.m0 == tuple(result.m0) and isinstance(settings.m0, tuple)
    assert settings.gyr_bias == tuple(result.gyr_bias)
    np.testing.assert_allclose(settings.acc_noise_cov, result.acc.cov)
    np.testing.assert_allclose(settings.gyr_noise_cov, result.gyr.cov)
    np.testing.assert_allclose(settings.mag_noise_cov, result.mag.cov)
    assert isinstance(settings.mag_noise_cov, list) and isinstance(settings.mag_noise_cov[0], list)
    # Survives the JSON round trip the CLI uses, and the default base is the "default" preset.
    assert EKFSettings.from_dict(settings.to_dict()) == settings
    assert result.to_settings().estimate_gyro_bias == PRESETS["default"].estimate_gyro_bias


def test_default_preset_keeps_its_tuned_noise(flat_rest):
    """The default preset's covariances are tuning values (far above sensor noise): calibration
    sets g, m0 and the bias but keeps them, unless asked to replace them."""
    result = calibrate(flat_rest.acc.values, flat_rest.gyr.values, flat_rest.mag.values)
    default = PRESETS["default"]
    settings = result.to_settings()
    assert settings.acc_noise_cov == default.acc_noise_cov
    assert settings.gyr_noise_cov == default.gyr_noise_cov
    assert settings.mag_noise_cov == default.mag_noise_cov
    assert settings.g == pytest.approx(result.g) and settings.m0 == tuple(result.m0)
    assert settings.gyr_bias == tuple(result.gyr_bias)
    forced = result.to_settings(replace_noise=True)
    np.testing.assert_allclose(forced.acc_noise_cov, result.acc.cov)


def test_histograms_match_the_samples_and_their_gaussian(flat_rest):
    result = calibrate(flat_rest.acc.values, flat_rest.gyr.values, flat_rest.mag.values)
    hists = result.histograms(bins=40)
    assert set(hists) == {"acc", "gyr", "mag"}
    for name, per_axis in hists.items():
        assert [h.axis for h in per_axis] == ["x", "y", "z"]
        for k, h in enumerate(per_axis):
            assert len(h.counts) == 40 and len(h.edges) == 41
            assert h.counts.sum() == result.sensor(name).count
            assert np.sum(h.density * np.diff(h.edges)) == pytest.approx(1.0)
            assert np.trapezoid(h.pdf, h.pdf_x) == pytest.approx(1.0, abs=1e-3)
            assert h.mean == pytest.approx(result.sensor(name).mean[k])
            # Gaussian noise: the histogram follows the overlay (largest bin near the peak).
            centres = 0.5 * (h.edges[1:] + h.edges[:-1])
            assert abs(centres[np.argmax(h.counts)] - h.mean) < 0.5 * h.std


def test_table_holds_the_numbers(flat_rest):
    result = calibrate(flat_rest.acc.values, flat_rest.gyr.values, flat_rest.mag.values)
    table = result.format_table()
    for word in ("acc", "gyr", "mag", "Covariance", "m/s^2", "rad/s", "uT", "m0", "g "):
        assert word in table
    assert f"{result.g:.4f}" in table
    assert f"{result.m0[2]:.3f}" in table
    d = result.to_dict()
    assert d["acc"]["count"] == result.acc.count and d["m0"] == pytest.approx(list(result.m0))


def test_finds_the_longest_rest_of_a_scripted_session():
    s = simulate(duration_s=120.0, seed=23)
    t_s, gyr, acc, mag = s.to_batch_arrays()
    segment = find_rest_segment(t_s, gyr, acc)
    lengths = np.diff(s.rest_intervals_ms, axis=1).ravel()
    longest = s.rest_intervals_ms[np.argmax(lengths)] / 1000.0
    assert longest[0] - 1e-3 <= segment.start_s < segment.end_s <= longest[1] + 1e-3
    assert segment.duration_s > (longest[1] - longest[0]) - 1.0
    # Nothing but rest in it: the calibration of that stretch is clean.
    result = calibrate_rest(t_s, gyr, acc, mag)
    assert result.interval_s == (segment.start_s, segment.end_s)
    assert result.g == pytest.approx(9.81, abs=0.01)
    mask = rest_mask(t_s, gyr, acc)
    t_ms = np.round(t_s * 1000)
    clearly_moving = ((np.linalg.norm(s.angular_velocity_at(t_ms), axis=1) > 0.2)
                      | (np.linalg.norm(s.specific_force_at(t_ms), axis=1) > 1.0))
    assert clearly_moving.sum() > 1000 and not np.any(mask[clearly_moving])
    assert np.mean(mask[s.inside(s.rest_intervals_ms, t_ms)]) > 0.8   # rest mostly is rest


def test_rest_is_found_without_a_gyroscope_and_with_handling_at_both_ends():
    s = simulate(duration_s=20.0, script="rest", seed=24, rates_hz={"gyr": 0})
    t_s, gyr, acc, mag = s.to_batch_arrays()
    rng = np.random.default_rng(0)
    handled = (t_s - t_s[0] < 2.0) | (t_s[-1] - t_s < 1.5)
    shaken = handled & ~np.isnan(acc[:, 0])
    acc[shaken] += rng.normal(0.0, 2.0, (shaken.sum(), 3))
    segment = find_rest_segment(t_s, gyr, acc)
    assert t_s[0] + 2.0 <= segment.start_s <= t_s[0] + 2.5
    assert t_s[-1] - 2.0 <= segment.end_s <= t_s[-1] - 1.5
    assert isinstance(segment, RestSegment) and segment.mask(t_s).sum() > 0
    start, end = segment                                   # unpacks as (start_s, end_s)
    assert (start, end) == (segment.start_s, segment.end_s)


def test_no_rest_long_enough_raises():
    s = simulate(duration_s=60.0, seed=25)
    t_s, gyr, acc, _ = s.to_batch_arrays()
    assert find_rest_segment(t_s, gyr, acc, min_duration_s=30.0) is None
    assert find_rest_segment(t_s, gyr, acc, min_duration_s=3.0) is not None
    with pytest.raises(ValueError, match="no still interval"):
        calibrate_rest(t_s, gyr, acc, None, min_duration_s=30.0)
    with pytest.raises(ValueError):
        find_rest_segment(t_s, None, None)


def _read_batch(path):
    """Minimal reader for a phone log: ACC/GYR/MAG rows on their union of times (NaN elsewhere)."""
    per_tag: dict[str, dict[int, list[float]]] = {"GYR": {}, "ACC": {}, "MAG": {}}
    for line in path.read_text().splitlines():
        fields = line.split("\t")
        if len(fields) == 5 and fields[1] in per_tag:
            try:
                per_tag[fields[1]][int(fields[0])] = [float(v) for v in fields[2:]]
            except ValueError:
                continue
    times = np.array(sorted(set().union(*per_tag.values())), dtype=np.int64)
    arrays = []
    for tag in ("GYR", "ACC", "MAG"):
        a = np.full((len(times), 3), np.nan)
        keys = np.array(sorted(per_tag[tag]), dtype=np.int64)
        a[np.searchsorted(times, keys)] = [per_tag[tag][k] for k in keys]
        arrays.append(a)
    return (times / 1000.0, *arrays)


def test_real_course_calibration_log(realphone_dir):
    t_s, gyr, acc, mag = _read_batch(realphone_dir / "tsrt14_lab2_calibration.txt")
    norms = np.linalg.norm(acc, axis=1)
    assert np.nanmax(np.abs(norms - 9.0)) > 2.0          # the log has handling at its edges
    result = calibrate_rest(t_s, gyr, acc, mag)
    start, end = result.interval_s
    assert end - start > 15.0
    inside = (t_s >= start) & (t_s <= end)
    assert np.nanmax(np.abs(norms[inside] - 9.0)) < 0.2  # ... which the rest interval leaves out
    assert result.g == pytest.approx(9.0, abs=0.05)
    assert np.linalg.norm(result.m0) == pytest.approx(42.0, abs=1.0)
    assert result.m0[0] == 0.0 and result.m0[1] > 0 and result.m0[2] < 0
    assert np.all(np.abs(result.gyr_bias) < 0.005)
    assert np.all(result.acc.std < 0.05) and np.all(result.mag.std < 1.5)
