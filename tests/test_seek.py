"""Seek via checkpoints: the state after a seek is exactly the state of playing up to there
(forward, backward, after a loop), and a seek replays at most one second."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from waiting import wait_for_snapshot, wait_until

from ekf.settings import EKFSettings
from ekf.simulate import simulate
from app.engine.processing.checkpoints import comparison_vectors
from app.engine.commands import ReplayControl, SetSettings
from app.engine.processing.configuration import Setup
from app.engine.processing.pipeline import Pipeline
from app.engine.processing.runner import EstimatorRunner
from app.engine.sessions.index import SessionIndex
from app.engine.live.worker import Engine
from app.stream.protocol import Sample, format_line
from app.stream.sources import LineReplaySource, LogFileSource


@pytest.fixture(scope="module")
def lines() -> list[bytes]:
    session = simulate(duration_s=30.0, rates_hz={"gyr": 100.0, "acc": 100.0, "mag": 50.0,
                                                  "ori": 100.0}, seed=3)
    return [(format_line(Sample(t, tag, values)) + "\n").encode()
            for t, tag, values in session.iter_rows()]


def same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal bit for bit (NaN where NaN)."""
    return a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


def reference_state(data: bytes, setup: Setup = Setup()):
    """A pipeline fed `data` in one piece (no end of stream): the state of playing it."""
    pipeline = Pipeline(EstimatorRunner(collect_plot=True))
    pipeline.restore(pipeline.initial_checkpoint(setup))
    pipeline.feed_bytes(data)
    pipeline.take_output()
    return pipeline


def assert_same_state(engine: Engine, reference: Pipeline) -> None:
    got, want = engine.pipeline.checkpoint(0), reference.checkpoint(0)
    assert same(got.runner["main"].vector, want.runner["main"].vector)
    mine, theirs = comparison_vectors(got.runner), comparison_vectors(want.runner)
    assert len(mine) == len(theirs)
    for index, (a, b) in enumerate(zip(mine, theirs)):
        assert same(a, b), index
    for name in ("phone_quat", "latest_t_ms", "row_t", "row_has_sample"):
        assert got.runner[name] == want.runner[name], name
    assert np.array_equal(got.orderer["state"], want.orderer["state"])
    assert np.array_equal(got.orderer["keys"], want.orderer["keys"])
    assert (got.t0_ms, got.fed, got.parser) == (want.t0_ms, want.fed, want.parser)
    np.testing.assert_array_equal(engine.runner.main.quat, reference.runner.main.quat)
    # the comparisons' running errors: the same samples compared (sums to rounding)
    for mine, theirs in zip(engine.runner.comparisons, reference.runner.comparisons):
        assert mine.errors.count == theirs.errors.count
        np.testing.assert_allclose(mine.errors.rmse(), theirs.errors.rmse(), rtol=1e-12)


def wait_indexed(engine: Engine, timeout: float = 60.0) -> dict:
    return wait_for_snapshot(engine, lambda s: s.replay and s.replay.get("indexed"), timeout,
                             "the replay to be indexed").replay


def test_index_checkpoints_are_the_states_of_playing(lines):
    source = LineReplaySource(lines, "sim")
    index = SessionIndex(source, Setup())
    index.build()
    assert index.complete and len(index.store) >= 30
    for line in (0, source.line_at(7.0), source.line_at(19.5)):
        checkpoint = index.store.before(line)
        assert source.pace[line] - source.pace[checkpoint.line] <= 1.0 + 1e-9
        reference = reference_state(source.lines_between(0, checkpoint.line))
        assert same(checkpoint.runner["main"].vector,
                    reference.checkpoint(0).runner["main"].vector)
    assert index.plot.valid and index.plot.end_s == pytest.approx(30.0, abs=0.1)


def test_seek_forward_backward_and_step_give_the_state_of_playing(lines):
    source = LineReplaySource(lines, "sim", speed=1.0, paused=True)
    data = source.data
    with Engine(source, comparisons=True) as engine:
        wait_indexed(engine)
        for position in (12.34, 25.0, 3.21, 29.9, 0.0):         # forward, back, end, start
            engine.send(ReplayControl(seek_s=position))
            assert engine.wait_idle()
            target = source.line_at(position)
            assert source.line_index == target
            assert_same_state(engine, reference_state(data[:source.starts[target]]))
        engine.send(ReplayControl(step=37))                       # step forward (lines)
        assert engine.wait_idle()
        assert_same_state(engine, reference_state(data[:source.starts[37]]))
        engine.send(ReplayControl(step=-1))                       # one line back
        assert engine.wait_idle()
        assert source.line_index == 36
        assert_same_state(engine, reference_state(data[:source.starts[36]]))


def test_seek_then_loop_goes_on_and_each_pass_starts_afresh(lines):
    """The bug of issue 12: after a seek, the next wrap fast-forwarded to the old seek point
    and froze. Now the loop starts a pass like the first, and the replay goes on."""
    source = LineReplaySource(lines, "sim", speed=1.0, paused=True, loop=True)
    data = source.data
    with Engine(source, comparisons=True) as engine:
        wait_indexed(engine)
        engine.send(ReplayControl(seek_s=20.0))
        assert engine.wait_idle()
        left = source.line_count - source.line_index
        engine.send(ReplayControl(step=left + 500))             # through the wrap, 500 more
        assert engine.wait_idle()
        assert source.loops == 1 and source.line_index == 500
        assert_same_state(engine, reference_state(data[:source.starts[500]]))
        replay = engine.snapshot_now().replay
        assert replay["position_s"] == pytest.approx(source.pace[500])   # time into the log
        # and at full speed it keeps looping (no freeze)
        engine.send(ReplayControl(paused=False, speed=0.0))
        into: list[int] = []

        def looped_four_times() -> bool:
            if source.loops >= 4:
                return True
            snapshot = engine.snapshot_now()
            if snapshot.t_ms is not None and snapshot.t0_ms is not None:
                into.append(snapshot.t_ms - snapshot.t0_ms)
            return False
        wait_until(looped_four_times, 30, what="four loops", poll_s=0.01)
        assert into and max(into) <= 30_100          # time into the session, never beyond


def test_seek_before_the_index_is_ready_replays_from_the_start(lines):
    source = LineReplaySource(lines, "sim", paused=True)
    with Engine(source, comparisons=False, index=False) as engine:
        engine.send(ReplayControl(seek_s=15.0))
        assert engine.wait_idle()
        target = source.line_at(15.0)
        assert_same_state(engine, reference_state(source.data[:source.starts[target]],
                                                  Setup(comparisons=False)))


@pytest.mark.shared
def test_seek_on_a_real_log_with_late_blocks(realphone_dir):
    """The standstill log has a 0.9 s block written out of order and damaged lines: the
    orderer's held samples and the parser's state are part of every checkpoint."""
    path = realphone_dir / "sensorLog_20221024T182616_standstill.txt"
    source = LogFileSource(path, paused=True)
    with Engine(source, comparisons=True) as engine:
        wait_indexed(engine)
        for position in (9.0, 2.5, 14.2):
            engine.send(ReplayControl(seek_s=position))
            assert engine.wait_idle()
            target = source.line_at(position)
            assert_same_state(engine, reference_state(source.data[:source.starts[target]]))


def _session(tmp_path, lines, timeline):
    import json
    folder = tmp_path / "session"
    folder.mkdir()
    (folder / "raw.txt").write_bytes(b"".join(lines))
    (folder / "session.json").write_text(json.dumps({"format": 2, "timeline": timeline}))
    return folder


def reference_with(data: bytes, setup: Setup):
    pipeline = Pipeline(EstimatorRunner(collect_plot=True))
    pipeline.begin(pipeline.initial_checkpoint(setup), setup.timeline)
    pipeline.feed_bytes(data)
    pipeline.take_output()
    return pipeline


def test_seek_in_a_session_applies_its_recorded_timeline(lines, tmp_path):
    timeline = [{"kind": "sensor", "sensor": "mag", "enabled": False, "t_ms": None,
                 "sample": 3500},
                {"kind": "estimator", "name": "course", "t_ms": None, "sample": 6000}]
    folder = _session(tmp_path, lines, timeline)
    source = LogFileSource(folder / "raw.txt", paused=True)
    with Engine(source, comparisons=True) as engine:
        replay = wait_indexed(engine)
        assert replay["following_timeline"] and replay["has_timeline"]
        setup = engine.replay_lane.manager.setup
        assert [c.kind for c in setup.timeline] == ["sensor", "estimator"]
        for position in (25.0, 8.0, 2.0):            # after both events, between, before
            engine.send(ReplayControl(seek_s=position))
            assert engine.wait_idle()
            target = source.line_at(position)
            assert_same_state(engine, reference_with(source.data[:source.starts[target]], setup))
        engine.send(ReplayControl(seek_s=25.0))
        assert engine.wait_idle()
        status = engine.snapshot_now().status
        assert status.estimator == "course" and status.sensors_enabled["mag"] is False


def test_a_user_switch_while_replaying_overrides_that_switch_only_once_indexed(lines, tmp_path):
    from app.engine.commands import SetSensorEnabled
    from app.engine.processing.configuration import Change
    folder = _session(tmp_path, lines, [{"kind": "sensor", "sensor": "mag", "enabled": False,
                                         "t_ms": None, "sample": 3500}])
    source = LogFileSource(folder / "raw.txt", paused=True)
    with Engine(source, comparisons=False) as engine:
        wait_indexed(engine)
        engine.send(ReplayControl(seek_s=15.0))
        assert engine.wait_idle()
        engine.send(SetSensorEnabled("acc", False))          # yours, for the whole replay
        assert engine.wait_idle()                            # applied: indexing again
        wait_until(lambda: not engine.replay_lane.manager.resync
                   and engine.snapshot_now().replay["indexed"], 30, what="indexed again")
        assert engine.wait_idle()
        snapshot = engine.snapshot_now()
        assert not snapshot.replay["following_timeline"]
        assert snapshot.configuration.overridden == ("acc",)
        assert snapshot.configuration.summary == \
            "accelerometer switch: yours; other switches, estimator, settings, combinations: " \
            "recorded"
        assert any("accelerometer switch: yours" in w for w in snapshot.health.warnings)
        # acc out from the start; the recorded magnetometer switch stays where it was recorded
        setup = Setup("ekf", ("gyr", "mag"), None, comparisons=False,
                      timeline=(Change(3500, "sensor", sensor="mag", enabled=False),))
        target = source.line_at(15.0)
        assert source.line_index == target
        assert_same_state(engine, reference_with(source.data[:source.starts[target]], setup))


def test_stopping_the_engine_waits_for_every_index_it_started():
    session = simulate(duration_s=120.0, seed=5)
    long_lines = [(format_line(Sample(t, tag, values)) + "\n").encode()
                  for t, tag, values in session.iter_rows()]
    source = LineReplaySource(long_lines, "sim", paused=True)
    engine = Engine(source, comparisons=False)
    engine.start()
    wait_until(lambda: engine.snapshot_now().replay is not None, 60.0, "the replay to start")
    for noise in (0.2, 0.3, 0.4):        # each edit indexes the replay again
        engine.send(SetSettings(EKFSettings(acc_noise_cov=(noise * np.eye(3)).tolist())))
    assert engine.wait_idle()
    engine.stop()
    assert [t.name for t in threading.enumerate() if t.name == "session-index"] == []
