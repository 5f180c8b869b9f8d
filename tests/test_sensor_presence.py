"""Which sensors a stream delivers: the engine counts each tag's samples per session
(Snapshot.session_samples) and absent_sensors() names a sensor that has sent nothing after
NO_SENSOR_AFTER_MS of the session (a phone without a gyroscope: {"gyr"})."""

from __future__ import annotations

import numpy as np

from waiting import wait_for_snapshot

from app.engine.processing.runner import EstimatorRunner
from app.engine.snapshot import NO_SENSOR_AFTER_MS, Snapshot, absent_sensors, absent_text
from app.engine.live.worker import Engine
from app.stream.sources import LineReplaySource


def _lines(seconds: float, t0: int = 1000, gyr_from_s: float | None = None) -> list[bytes]:
    """A flat phone at rest: ACC and ORI at 100 Hz, MAG at 50 Hz; GYR at 100 Hz from
    gyr_from_s on (None: never, a phone without a gyroscope)."""
    out = []
    for k in range(int(seconds * 100)):
        t = t0 + 10 * k
        if gyr_from_s is not None and k >= gyr_from_s * 100:
            out.append(f"{t}\tGYR\t0.0\t0.0\t0.0\n".encode())
        out += [f"{t}\tACC\t0.0\t0.0\t9.81\n".encode(), f"{t + 3}\tORI\t1.0\t0.0\t0.0\t0.0\n".encode()]
        if k % 2 == 0:
            out.append(f"{t}\tMAG\t0.0\t20.0\t-40.0\n".encode())
    return out


def _finished(lines: list[bytes]) -> Snapshot:
    engine = Engine(LineReplaySource(lines, "synthetic", speed=0), comparisons=True)
    with engine:
        return wait_for_snapshot(engine, lambda s: s.health.connection_state == "finished", 40.0,
                                 "the replay to finish")


def test_a_stream_without_a_gyroscope_says_so():
    snapshot = _finished(_lines(3.0))
    assert snapshot.session_samples == {"gyr": 0, "acc": 300, "mag": 150, "ori": 300}
    assert absent_sensors(snapshot) == {"gyr"}
    assert absent_text("gyr") == "no gyroscope in this stream"


def test_a_gyroscope_that_arrives_later_is_no_longer_absent():
    snapshot = _finished(_lines(4.0, gyr_from_s=3.0))
    assert snapshot.session_samples["gyr"] == 100
    assert absent_sensors(snapshot) == frozenset()


def test_nothing_is_absent_before_the_session_has_run_long_enough():
    snapshot = Snapshot(t_ms=1000 + NO_SENSOR_AFTER_MS - 10, t0_ms=1000,
                        session_samples={"gyr": 0, "acc": 150, "mag": 75, "ori": 150})
    assert absent_sensors(snapshot) == frozenset()
    snapshot.t_ms = 1000 + NO_SENSOR_AFTER_MS
    assert absent_sensors(snapshot) == {"gyr"}
    # ORI only: no sensor at all; counts not known (a test double): nothing said
    snapshot.session_samples = {"gyr": 0, "acc": 0, "mag": 0, "ori": 200}
    assert absent_sensors(snapshot) == {"gyr", "acc", "mag"}
    snapshot.session_samples = {}
    assert absent_sensors(snapshot) == frozenset()


def test_the_counts_follow_checkpoints_and_start_afresh_with_a_new_session():
    runner = EstimatorRunner("ekf")
    t = 1000 + 10 * np.arange(100, dtype=np.int64)
    tags = np.tile(np.array([1, 2, 3]), 100)            # ACC, MAG, ORI: no GYR
    times = np.repeat(t, 3)
    values = np.tile(np.array([[0.0, 0.0, 9.81, 0.0], [0.0, 20.0, -40.0, 0.0],
                               [1.0, 0.0, 0.0, 0.0]]), (100, 1))
    runner.feed_arrays(times, tags, values)
    assert runner.session_samples == {"gyr": 0, "acc": 100, "mag": 100, "ori": 100}
    saved = runner.snapshot()
    runner.feed_arrays(np.array([2000, 2000]), np.array([0, 1]),
                       np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 9.81, 0.0]]))
    assert runner.session_samples["gyr"] == 1
    runner.restore(saved)                               # a replay's seek back
    assert runner.session_samples == {"gyr": 0, "acc": 100, "mag": 100, "ori": 100}
    runner.new_session()                                # another phone: nothing seen yet
    assert set(runner.session_samples.values()) == {0}
    # a recording's start_state written before the counts were kept
    old = {key: value for key, value in saved.items() if key != "tag_counts"}
    runner.restore(old)
    assert set(runner.session_samples.values()) == {0}
