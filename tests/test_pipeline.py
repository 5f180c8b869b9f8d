"""EstimatorRunner / run_offline: rows per distinct time, comparisons, commands."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import ekf
from app.stream.logfile import read_log
from app.stream.protocol import Sample
from app.stream.protocol import FILTER_TAGS, WIDTHS
from app.engine.offline.filtering import run_offline
from app.engine.processing.compare import SameInstant
from app.engine.processing.runner import COMBINATIONS, EstimatorRunner
from app.stream.fastparse import samples_to_arrays

REALPHONE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "realphone"


def _feed(runner: EstimatorRunner, samples: list[Sample]) -> None:
    """Samples in order (a test's readings) to the runner as the arrays it takes."""
    arrays = samples_to_arrays(list(samples))
    runner.feed_arrays(arrays.t_ms, arrays.tag, arrays.values)


def _still_samples(seconds: float = 3.0) -> list[Sample]:
    out = []
    for k in range(int(seconds * 100)):
        t = 1000 + 10 * k
        out += [Sample(t, "GYR", (0.0, 0.0, 0.0)), Sample(t, "ACC", (0.0, 0.0, 9.81)),
                Sample(t, "MAG", (0.0, 20.0, -40.0)), Sample(t + 5, "ORI", (1.0, 0.0, 0.0, 0.0))]
    return out


def test_rows_per_distinct_time_and_errors_at_the_phone_times():
    runner = EstimatorRunner()
    _feed(runner, _still_samples())
    runner.finish()
    rows = runner.take_rows()
    assert len(rows) == 600                           # sensor times and ORI times
    assert rows.t_ms.tolist() == sorted(set(rows.t_ms.tolist()))
    assert rows.has_sample.sum() == 300
    assert np.isnan(rows.phone_quat[0]).all() and not np.isnan(rows.phone_quat[-1]).any()
    assert np.allclose(np.linalg.norm(rows.quat, axis=1), 1.0)
    # flat, field pointing north: identity; the phone says identity too. Every ORI but the last
    # (no estimate after it yet) is compared, at its own time.
    errors = runner.take_errors()
    assert errors.t_ms.tolist() == [1005 + 10 * k for k in range(299)]
    assert errors.error_deg.shape == (299, 3) and errors.error_deg.max() < 1.0


def test_comparisons_cover_the_seven_sensor_sets():
    runner = EstimatorRunner(comparisons=True)
    _feed(runner, _still_samples())
    runner.finish()
    assert [c.name for c in runner.comparisons] == [
        "gyr+acc+mag", "gyr+acc", "gyr+mag", "acc+mag", "gyr", "acc", "mag"]
    assert len(COMBINATIONS) == 7
    by_name = {c.name: c for c in runner.comparisons}
    assert by_name["gyr+acc+mag"].errors.rmse()[0] < 2.0
    assert by_name["acc+mag"].errors.count == 299
    assert all(np.isfinite(c.errors.latest).all() for c in runner.comparisons)


def test_comparisons_run_the_chosen_estimator():
    runner = EstimatorRunner(comparisons=True)
    runner.set_comparisons_enabled(True, "complementary")
    assert runner.comparison_estimator == "complementary"
    assert {c.estimator.name for c in runner.comparisons} == {"complementary"}
    assert [c.sensors for c in runner.comparisons] == list(COMBINATIONS)
    with pytest.raises(ValueError):
        runner.set_comparisons_enabled(True, "kalman")


def test_commands_switch_sensors_and_estimator():
    runner = EstimatorRunner()
    runner.set_sensor_enabled("mag", False)
    assert runner.sensors_enabled == {"gyr": True, "acc": True, "mag": False}
    runner.set_estimator("complementary")
    assert runner.estimator_name == "complementary" and runner.sensors_enabled["mag"] is False
    with pytest.raises(ValueError):
        runner.set_sensor_enabled("baro", True)
    assert runner.align_heading() is None           # no ORI yet
    _feed(runner, _still_samples(0.5))
    turned = runner.align_heading()
    assert turned is not None and math.isfinite(turned)

def test_run_offline_matches_filter_batch_on_sensor_rows():
    if not REALPHONE.is_dir():
        pytest.skip(f"shared real-phone logs not found at {REALPHONE}")
    log = read_log(REALPHONE / "tsrt14_lab2_calibration.txt")
    rows = run_offline(log)
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
    rows, acc_flags, mag_flags = [], [], []
    compared_rows: list[tuple[int, list]] = []          # sensor times: each comparison's quat
    phone_t, phone_q = [], []
    row_t, has_sample = None, False

    def commit():
        status = main.flags
        rows.append((row_t, main.quat.tolist(), status.acc_rejected, status.mag_rejected,
                     status.at_rest))
        if has_sample:
            compared_rows.append((row_t, [estimator.quat for estimator in compared]))

    for sample in samples:
        if row_t is not None and sample.t_ms != row_t:
            commit()
            has_sample = False
        if sample.tag == "ORI":
            phone_t.append(sample.t_ms)
            phone_q.append(sample.values)
        else:
            has_sample = True
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
    sums, counts = [], []
    for index in range(len(compared)):       # each comparison at the phone's time stamps
        same_instant = SameInstant()
        same_instant.add_phone(np.array(phone_t), np.array(phone_q))
        errors = same_instant.add_estimates(np.array([t for t, _ in compared_rows]),
                                            np.array([q[index] for _, q in compared_rows]))
        sums.append(np.sum(errors.error_deg ** 2, axis=0))
        counts.append(len(errors))
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
        _feed(runner, samples[start:start + size])
        start += size
    runner.finish()
    out = runner.take_rows()
    plot = runner.take_plot_samples()
    assert [(t, q, a, m, r) for t, q, a, m, r in zip(
        out.t_ms.tolist(), out.quat.tolist(), out.acc_rejected.tolist(),
        out.mag_rejected.tolist(), out.at_rest.tolist())] == rows
    assert plot["acc_rejected"].tolist() == acc_flags and plot["mag_rejected"].tolist() == mag_flags
    assert len(plot["t_gyr"]) == sum(s.tag == "GYR" for s in samples)
    assert [c.errors.count for c in runner.comparisons] == counts
    for comparison, expected in zip(runner.comparisons, sums):
        np.testing.assert_allclose(comparison.errors.squared, expected, rtol=1e-12)


def test_batch_path_equals_feeding_sample_by_sample_on_real_logs():
    if not REALPHONE.is_dir():
        pytest.skip(f"shared real-phone logs not found at {REALPHONE}")
    for path in sorted(REALPHONE.glob("*.txt")):
        log = read_log(path)
        samples = [Sample(t, FILTER_TAGS[code], tuple(values[:WIDTHS[code]])) for t, code, values
                   in zip(log.t_ms.tolist(), log.tag.tolist(), log.values.tolist())]
        rows, acc_flags, mag_flags, _, _ = _per_sample_reference(samples)
        runner = EstimatorRunner(collect_plot=True)
        for start in range(0, len(samples), 333):
            _feed(runner, samples[start:start + 333])
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
