"""The simulator's sensor data must agree with its own ground truth (the tests of every estimator
rest on that), be deterministic by seed, and keep the rates, phases and events it promises."""

from __future__ import annotations

import time

import numpy as np
import pytest

from ekf.quaternion import angle_between, multiply, normalize, to_matrix
from ekf.simulate import SENSOR_TAGS, simulate

NO_NOISE = {"gyr": 0.0, "acc": 0.0, "mag": 0.0}


@pytest.fixture(scope="module")
def clean():
    """Noise-free standard session with a gyro bias, fast gyro for tight integration checks."""
    return simulate(duration_s=120.0, rates_hz={"gyr": 500, "acc": 100, "mag": 50, "ori": 100},
                    seed=3, noise=NO_NOISE)


@pytest.fixture(scope="module")
def noisy():
    return simulate(duration_s=120.0, seed=1, gyro_bias=(0.01, -0.02, 0.005))


def _strictly_inside(session, intervals, t_ms, margin_ms=20):
    shrunk = np.asarray(intervals).copy()
    shrunk[:, 0] += margin_ms
    shrunk[:, 1] -= margin_ms
    return session.inside(shrunk, t_ms)


def test_accelerometer_is_gravity_in_sensor_frame_at_rest_and_force_in_bursts(clean):
    q = clean.quat_at(clean.acc.t_ms)
    expected = np.einsum("nji,j->ni", to_matrix(q), [0.0, 0.0, 9.81])
    rest = _strictly_inside(clean, clean.rest_intervals_ms, clean.acc.t_ms)
    assert rest.sum() > 3000
    np.testing.assert_allclose(clean.acc.values[rest], expected[rest], atol=1e-9)
    # In the bursts the extra specific force is large: ||acc|| leaves g by metres per second².
    burst = _strictly_inside(clean, clean.acc_disturbance_intervals_ms, clean.acc.t_ms)
    deviation = np.abs(np.linalg.norm(clean.acc.values[burst], axis=1) - 9.81)
    assert deviation.max() > 3.0
    # Outside the bursts (rotations included: no lever arm) ||acc|| is exactly g.
    outside = ~clean.inside(clean.acc_disturbance_intervals_ms, clean.acc.t_ms)
    np.testing.assert_allclose(np.linalg.norm(clean.acc.values[outside], axis=1), 9.81, atol=1e-9)


def test_magnetometer_is_earth_field_in_sensor_frame_outside_the_disturbance(clean):
    q = clean.quat_at(clean.mag.t_ms)
    m0 = np.array(clean.metadata["m0"])
    expected = np.einsum("nji,j->ni", to_matrix(q), m0)
    disturbed = clean.inside(clean.mag_disturbance_intervals_ms, clean.mag.t_ms)
    np.testing.assert_allclose(clean.mag.values[~disturbed], expected[~disturbed], atol=1e-9)
    middle = _strictly_inside(clean, clean.mag_disturbance_intervals_ms, clean.mag.t_ms,
                              margin_ms=600)
    strength_change = np.linalg.norm(clean.mag.values[middle], axis=1) - np.linalg.norm(m0)
    assert strength_change.min() > 10.0
    added = np.linalg.norm(clean.mag_disturbance_at(clean.mag.t_ms[middle]), axis=1)
    assert np.all((added >= 20.0) & (added <= 60.0))


def test_angular_velocity_is_the_derivative_of_the_true_orientation(clean):
    # Independent of the closed form: q̇ = ½ q ⊗ (0, ω) by central differences.
    t_ms = np.arange(clean.t0_ms + 1000, clean.t0_ms + 119_000, 37, dtype=float)
    h_ms = 0.01
    q = clean.quat_at(t_ms)
    q_plus, q_minus = clean.quat_at(t_ms + h_ms), clean.quat_at(t_ms - h_ms)
    q_plus *= np.sign(np.sum(q_plus * q, axis=1))[:, None]
    q_minus *= np.sign(np.sum(q_minus * q, axis=1))[:, None]
    q_dot = (q_plus - q_minus) / (2 * h_ms / 1000.0)
    omega = clean.angular_velocity_at(t_ms)
    expected = 0.5 * multiply(q, np.column_stack([np.zeros(len(t_ms)), omega]))
    np.testing.assert_allclose(q_dot, expected, atol=2e-4)
    assert np.abs(omega).max() > 5.0  # the fast turns are several rad/s


def _integrate_gyro(t_ms, gyr, q_start, midpoint):
    q = q_start.copy()
    out = np.empty((len(t_ms), 4))
    out[0] = q
    dt = np.diff(t_ms) / 1000.0
    rates = 0.5 * (gyr[1:] + gyr[:-1]) if midpoint else gyr[:-1]
    for k in range(len(dt)):
        rv = rates[k] * dt[k]
        angle = np.linalg.norm(rv)
        step = np.array([1.0, 0, 0, 0]) if angle == 0 else np.concatenate(
            [[np.cos(angle / 2)], np.sin(angle / 2) * rv / angle])
        q = multiply(q, step)
        q /= np.linalg.norm(q)
        out[k + 1] = q
    return out


def test_noise_free_gyro_integrates_to_the_truth(clean):
    t = clean.gyr.t_ms
    truth = clean.quat_at(t)
    q = _integrate_gyro(t, clean.gyr.values, truth[0], midpoint=True)
    assert np.degrees(angle_between(q, truth)).max() < 0.05


def test_noisy_biased_gyro_integrates_to_the_truth_after_removing_the_bias(noisy):
    t = noisy.gyr.t_ms
    truth = noisy.quat_at(t)
    bias = np.array(noisy.metadata["gyr_bias"])
    q = _integrate_gyro(t, noisy.gyr.values - bias, truth[0], midpoint=True)
    assert np.degrees(angle_between(q, truth)).max() < 1.0
    # With the bias left in, the integration drifts far away: the bias really is in the samples.
    drifting = _integrate_gyro(t, noisy.gyr.values, truth[0], midpoint=True)
    assert np.degrees(angle_between(drifting, truth))[-1] > 60.0


def test_gyro_at_rest_measures_bias_plus_noise(noisy):
    rest = _strictly_inside(noisy, noisy.rest_intervals_ms, noisy.gyr.t_ms)
    samples = noisy.gyr.values[rest]
    std = np.sqrt(np.diag(noisy.metadata["noise_cov"]["gyr"]))
    np.testing.assert_allclose(samples.mean(axis=0), [0.01, -0.02, 0.005],
                               atol=5 * std.max() / np.sqrt(len(samples)))
    np.testing.assert_allclose(samples.std(axis=0), std, rtol=0.05)


def test_ori_is_the_unit_truth_with_nonnegative_w(noisy):
    ori = noisy.ori.values
    np.testing.assert_allclose(np.linalg.norm(ori, axis=1), 1.0, atol=1e-12)
    assert np.all(ori[:, 0] >= 0.0)
    np.testing.assert_allclose(ori, normalize(noisy.quat_at(noisy.ori.t_ms)), atol=1e-12)
    # The standard script turns through w = 0, so ORI shows the phone's q -> -q jumps.
    assert np.any(np.sum(ori[1:] * ori[:-1], axis=1) < 0)


@pytest.mark.parametrize("rates", [
    {"gyr": 100, "acc": 100, "mag": 50, "ori": 100},
    {"gyr": 500, "acc": 400, "mag": 100, "ori": 200},
    {"gyr": 333, "acc": 0, "mag": 75, "ori": 60},
])
def test_rates_phases_and_integer_timestamps(rates):
    duration = 30.0
    s = simulate(duration_s=duration, rates_hz=rates, seed=5)
    firsts = []
    for tag in SENSOR_TAGS:
        series = s.series(tag)
        rate = rates[tag.lower()]
        assert series.t_ms.dtype == np.int64
        assert abs(len(series) - rate * duration) <= 1
        if rate == 0:
            continue
        assert np.all(np.diff(series.t_ms) > 0)
        assert abs(np.mean(np.diff(series.t_ms)) - 1000.0 / rate) < 0.01 * 1000.0 / rate
        assert series.t_ms[0] >= s.t0_ms and series.t_ms[-1] <= s.t0_ms + duration * 1000
        firsts.append(series.t_ms[0])
    assert len(set(firsts)) > 1  # asynchronous: the sensors do not share one phase


@pytest.mark.parametrize("duration", [10.0, 36.0, 45.0, 70.0, 82.5, 90.0, 120.0, 300.0])
def test_events_lie_inside_the_session_and_the_script_fits_the_duration(duration):
    s = simulate(duration_s=duration, seed=2)
    end = s.t0_ms + duration * 1000
    for intervals in (s.rest_intervals_ms, s.acc_disturbance_intervals_ms,
                      s.mag_disturbance_intervals_ms):
        assert intervals.dtype == np.int64 and intervals.shape[1] == 2
        assert np.all(intervals[:, 0] < intervals[:, 1])
        assert np.all(intervals[:, 0] >= s.t0_ms) and np.all(intervals[:, 1] <= end)
        assert np.all(intervals[1:, 0] > intervals[:-1, 1])   # sorted, disjoint
    # A rest of at least 3 s starts every session.
    assert s.rest_intervals_ms[0, 0] == s.t0_ms
    assert s.rest_intervals_ms[0, 1] - s.t0_ms >= 3000
    if duration >= 36:
        assert len(s.acc_disturbance_intervals_ms) >= 2
        assert len(s.mag_disturbance_intervals_ms) >= 1
        # Bursts and field disturbance are apart from each other.
        for a0, a1 in s.acc_disturbance_intervals_ms:
            assert not np.any((s.mag_disturbance_intervals_ms[:, 0] < a1)
                              & (s.mag_disturbance_intervals_ms[:, 1] > a0))
    if duration >= 82.5:
        assert s.rest_intervals_ms[-1, 1] == end           # and a rest ends it
    if duration >= 300:
        assert len(s.mag_disturbance_intervals_ms) >= 3     # the script repeats
    # The samples cover the whole session.
    assert s.acc.t_ms[-1] > end - 20


def test_same_seed_same_session_other_seed_other_noise():
    a = simulate(duration_s=20.0, seed=11)
    b = simulate(duration_s=20.0, seed=11)
    c = simulate(duration_s=20.0, seed=12)
    for tag in SENSOR_TAGS:
        np.testing.assert_array_equal(a.series(tag).t_ms, b.series(tag).t_ms)
        np.testing.assert_array_equal(a.series(tag).values, b.series(tag).values)
    assert not np.array_equal(a.acc.values, c.acc.values)


def test_rows_are_time_ordered_with_ties_gyr_acc_mag_ori():
    # 500 Hz with random phases: many sensors share a millisecond.
    s = simulate(duration_s=5.0, rates_hz={"gyr": 500, "acc": 500, "mag": 500, "ori": 500}, seed=4)
    rows = s.to_rows()
    assert len(rows) == sum(len(s.series(tag)) for tag in SENSOR_TAGS)
    priority = {tag: i for i, tag in enumerate(SENSOR_TAGS)}
    keys = [(t, priority[tag]) for t, tag, _ in rows]
    assert keys == sorted(keys)
    assert sum(1 for k in range(1, len(keys)) if keys[k][0] == keys[k - 1][0]) > 100
    # Values are the series' rows, in their own order.
    gyr_rows = [values for _, tag, values in rows if tag == "GYR"]
    np.testing.assert_array_equal(np.array(gyr_rows), s.gyr.values)
    assert all(len(values) == 4 for _, tag, values in rows if tag == "ORI")


def test_batch_arrays_hold_every_sample_once():
    s = simulate(duration_s=10.0, seed=6)
    t_s, gyr, acc, mag = s.to_batch_arrays()
    assert np.all(np.diff(t_s) > 0)
    for values, series in ((gyr, s.gyr), (acc, s.acc), (mag, s.mag)):
        present = ~np.isnan(values[:, 0])
        np.testing.assert_array_equal(np.round(t_s[present] * 1000).astype(np.int64), series.t_ms)
        np.testing.assert_array_equal(values[present], series.values)


def test_rest_script_and_full_covariance_noise():
    cov = [[4e-4, 1e-4, 0.0], [1e-4, 4e-4, 0.0], [0.0, 0.0, 9e-4]]
    s = simulate(duration_s=60.0, seed=8, script="rest", noise={"acc": cov},
                 rates_hz={"acc": 400})
    assert s.rest_intervals_ms.tolist() == [[s.t0_ms, s.t0_ms + 60_000]]
    assert len(s.acc_disturbance_intervals_ms) == 0 and len(s.mag_disturbance_intervals_ms) == 0
    np.testing.assert_allclose(np.cov(s.acc.values, rowvar=False), cov, atol=3e-5)


def test_twenty_minutes_at_500_hz_is_fast():
    start = time.perf_counter()
    s = simulate(duration_s=1200.0, rates_hz={"gyr": 500, "acc": 500, "mag": 500, "ori": 500})
    elapsed = time.perf_counter() - start
    assert len(s.gyr) == 600_000
    assert elapsed < 10.0, f"took {elapsed:.1f} s"


@pytest.mark.parametrize("kwargs", [
    {"duration_s": 0.0}, {"script": "dance"}, {"rates_hz": {"baro": 10}},
    {"noise": {"acc": [[1.0, 2.0]]}}, {"noise": {"gps": 1.0}},
    # refused before anything is allocated (were a ValueError from numpy, NaN samples, a
    # MemoryError after 3.6 GB and a request for 74.5 GiB)
    {"seed": -1}, {"seed": 1.5}, {"gyro_bias": (float("nan"), 0.0, 0.0)},
    {"duration_s": float("inf")}, {"duration_s": float("nan")}, {"duration_s": 1e9},
    {"rates_hz": {"gyr": 1e9}}, {"rates_hz": {"acc": float("nan")}}, {"rates_hz": {"mag": -1}},
    {"g": float("inf")}, {"m0": (0.0, float("nan"), 0.0)},
])
def test_bad_arguments_raise_value_error(kwargs):
    with pytest.raises(ValueError):
        simulate(**kwargs)
