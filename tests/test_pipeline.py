"""EstimatorRunner / run_offline: rows per distinct time, comparisons, commands."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import ekf
from app.stream.logfile import read_log
from app.stream.protocol import Sample
from app.engine.offline import run_offline
from app.engine.runner import COMBINATIONS, EstimatorRunner, angle_deg

REALPHONE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "realphone"


def _still_samples(seconds: float = 3.0) -> list[Sample]:
    out = []
    for k in range(int(seconds * 100)):
        t = 1000 + 10 * k
        out += [Sample(t, "GYR", (0.0, 0.0, 0.0)), Sample(t, "ACC", (0.0, 0.0, 9.81)),
                Sample(t, "MAG", (0.0, 20.0, -40.0)), Sample(t + 5, "ORI", (1.0, 0.0, 0.0, 0.0))]
    return out


def test_rows_per_distinct_time_and_phone_angle():
    rows = run_offline(_still_samples())
    assert len(rows) == 600                           # sensor times and ORI times
    assert rows.t_ms.tolist() == sorted(set(rows.t_ms.tolist()))
    assert np.isnan(rows.phone_quat[0]).all() and not np.isnan(rows.phone_quat[-1]).any()
    # flat, field pointing north: identity; the phone says identity too
    assert rows.angle_deg[-1] < 1.0
    assert np.allclose(np.linalg.norm(rows.quat, axis=1), 1.0)


def test_comparisons_cover_the_seven_sensor_sets():
    runner = EstimatorRunner(comparisons=True)
    runner.feed_many(_still_samples())
    runner.finish()
    assert [c.name for c in runner.comparisons] == [
        "gyr+acc+mag", "gyr+acc", "gyr+mag", "acc+mag", "gyr", "acc", "mag"]
    assert len(COMBINATIONS) == 7
    by_name = {c.name: c for c in runner.comparisons}
    assert by_name["gyr+acc+mag"].rmse_deg < 2.0 and by_name["acc+mag"].count > 0
    assert all(math.isfinite(c.angle_to_phone_deg) for c in runner.comparisons)


def test_commands_switch_sensors_and_estimator():
    runner = EstimatorRunner()
    runner.set_sensor_enabled("mag", False)
    assert runner.sensors_enabled == {"gyr": True, "acc": True, "mag": False}
    runner.set_estimator("complementary")
    assert runner.estimator_name == "complementary" and runner.sensors_enabled["mag"] is False
    with pytest.raises(ValueError):
        runner.set_sensor_enabled("baro", True)
    assert runner.align_heading() is False          # no ORI yet
    runner.feed_many(_still_samples(0.5))
    assert runner.align_heading() is True


def test_angle_deg():
    assert angle_deg((1, 0, 0, 0), (-1, 0, 0, 0)) == 0.0
    half = math.sqrt(0.5)
    assert angle_deg((1, 0, 0, 0), (half, 0, 0, half)) == pytest.approx(90.0)
    assert math.isnan(angle_deg(None, (1, 0, 0, 0)))


def test_run_offline_matches_filter_batch_on_sensor_rows():
    if not REALPHONE.is_dir():
        pytest.skip(f"shared real-phone logs not found at {REALPHONE}")
    log = read_log(REALPHONE / "tsrt14_lab2_calibration.txt")
    rows = run_offline(log.samples)
    arrays = log.to_arrays()
    assert np.array_equal(rows.t_ms, arrays.t_ms)
    sensor_rows = ~(np.isnan(arrays.gyr[:, 0]) & np.isnan(arrays.acc[:, 0])
                    & np.isnan(arrays.mag[:, 0]))
    batch = ekf.filter_batch(arrays.t_s[sensor_rows], arrays.gyr[sensor_rows],
                             arrays.acc[sensor_rows], arrays.mag[sensor_rows])
    assert np.array_equal(batch.quat, rows.quat[sensor_rows])


def _per_sample_reference(samples, name="ekf", comparisons=False):
    """The runner's contract, sample by sample: update_gyr/acc/mag in order, one row per
    distinct time from the state when a later time arrives; plot flags right after ACC/MAG.
    One sample per step() call is update_gyr/acc/mag."""
    main = ekf.make_estimator(name)
    compared = [ekf.make_estimator("ekf", None, combo) for combo in COMBINATIONS] \
        if comparisons else []
    sums, counts = [0.0] * len(compared), [0] * len(compared)
    rows, acc_flags, mag_flags = [], [], []
    row_t, phone = None, None

    def commit():
        status = main.flags
        rows.append((row_t, main.quat.tolist(), status.acc_rejected, status.mag_rejected,
                     status.at_rest))
        if phone is not None:
            for index, estimator in enumerate(compared):
                error = angle_deg(estimator.quat, phone)
                if error == error:
                    sums[index] += error * error
                    counts[index] += 1

    for sample in samples:
        if row_t is not None and sample.t_ms != row_t:
            commit()
        if sample.tag == "ORI":
            phone = sample.values
        else:
            keyword = {"GYR": "gyr", "ACC": "acc", "MAG": "mag"}[sample.tag]
            for estimator in [main] + compared:
                estimator.step(sample.t_ms / 1000.0, **{keyword: np.array(sample.values)})
            status = main.flags
            if sample.tag == "ACC":
                acc_flags.append(bool(status.acc_rejected))
            elif sample.tag == "MAG":
                mag_flags.append(bool(status.mag_rejected))
        row_t = sample.t_ms
    commit()
    return rows, acc_flags, mag_flags, sums, counts


def _disturbed_samples() -> list[Sample]:
    """Still, then shaken (acc rejected) and near a magnet (mag rejected), with duplicate
    times of one tag and ORI-only times."""
    out = []
    for k in range(400):
        t = 1000 + 10 * k
        shake = 12.0 if 150 <= k < 200 else 0.0
        magnet = 200.0 if 250 <= k < 300 else 0.0
        out += [Sample(t, "GYR", (0.01, 0.0, 0.02 if k > 100 else 0.0)),
                Sample(t, "ACC", (shake, 0.0, 9.81)),
                Sample(t, "MAG", (magnet, 20.0, -40.0))]
        if k % 7 == 0:
            out.append(Sample(t, "GYR", (0.0, 0.01, 0.0)))         # same time, same tag again
        if k % 2 == 0:
            out.append(Sample(t + 5, "ORI", (1.0, 0.0, 0.0, 0.0)))
    order = {"GYR": 0, "ACC": 1, "MAG": 2, "ORI": 3}
    return sorted(out, key=lambda s: (s.t_ms, order[s.tag]))


@pytest.mark.parametrize("name", ["ekf", "complementary"])
def test_chunked_batch_path_equals_feeding_sample_by_sample(name):
    samples = _disturbed_samples()
    rows, acc_flags, mag_flags, sums, counts = _per_sample_reference(samples, name, True)
    assert any(acc_flags) and (name != "ekf" or any(mag_flags))    # the data exercises the gates
    rng = np.random.default_rng(1)
    runner = EstimatorRunner(name, comparisons=True, collect_plot=True)
    start = 0
    while start < len(samples):
        size = int(rng.integers(1, 40))
        runner.feed_many(samples[start:start + size])
        start += size
    runner.finish()
    out = runner.take_rows()
    plot = runner.take_plot_samples()
    assert [(t, q, a, m, r) for t, q, a, m, r in zip(
        out.t_ms.tolist(), out.quat.tolist(), out.acc_rejected.tolist(),
        out.mag_rejected.tolist(), out.at_rest.tolist())] == rows
    assert plot["acc_rejected"].tolist() == acc_flags and plot["mag_rejected"].tolist() == mag_flags
    assert len(plot["t_gyr"]) == sum(s.tag == "GYR" for s in samples)
    assert [c.squared_sum for c in runner.comparisons] == sums
    assert [c.count for c in runner.comparisons] == counts


def test_batch_path_equals_feeding_sample_by_sample_on_real_logs():
    if not REALPHONE.is_dir():
        pytest.skip(f"shared real-phone logs not found at {REALPHONE}")
    for path in sorted(REALPHONE.glob("*.txt")):
        samples = read_log(path).samples
        rows, acc_flags, mag_flags, _, _ = _per_sample_reference(samples)
        runner = EstimatorRunner(collect_plot=True)
        for start in range(0, len(samples), 333):
            runner.feed_many(samples[start:start + 333])
        runner.finish()
        out = runner.take_rows()
        plot = runner.take_plot_samples()
        assert out.t_ms.tolist() == [row[0] for row in rows], path.name
        assert out.quat.tolist() == [row[1] for row in rows], path.name
        assert plot["acc_rejected"].tolist() == acc_flags, path.name
        assert plot["mag_rejected"].tolist() == mag_flags, path.name


def test_warm_up_runs_every_kernel_the_engine_uses():
    """`make run` / `make test` call it after installing; it must keep working."""
    from app.engine import warmup
    warmup.warm_up()
