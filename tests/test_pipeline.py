"""EstimatorRunner / run_offline: rows per distinct time, comparisons, commands."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import ekf
from app.io.logfile import read_log
from app.io.protocol import Sample
from app.pipeline import COMBINATIONS, EstimatorRunner, angle_deg, run_offline

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
