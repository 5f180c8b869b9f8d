"""Engine: replay through the thread gives run_offline's estimates; commands; snapshots."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from line_helpers import parses as _parses
from waiting import wait_for_snapshot

from app.engine.live.worker import Engine
from app.stream.logfile import read_log
from app.stream.recorder import Recorder
from app.stream.sources import LineReplaySource, LogFileSource
from app.engine.offline.filtering import run_offline
from app.engine.commands import (AlignHeading, ReplayControl, ResetFilter, SetComparisonsEnabled,
                                 SetEstimator, SetSensorEnabled)

REALPHONE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "realphone"


def _wait_state(engine: Engine, state: str, timeout: float = 40.0):
    return wait_for_snapshot(engine, lambda s: s.health.connection_state == state, timeout,
                             f"the engine to reach {state!r}")


def _log_lines(seconds: float, t0: int = 1000, turn_rate: float = 0.5,
               mag_until: int = 10**9) -> list[bytes]:
    """Flat phone at rest for 1 s, then turning about z at turn_rate rad/s; MAG at 50 Hz
    until sample number mag_until."""
    out = []
    for k in range(int(seconds * 100)):
        t = t0 + 10 * k
        rate = turn_rate if k > 100 else 0.0
        out += [f"{t}\tGYR\t0.0\t0.0\t{rate}\n".encode(), f"{t}\tACC\t0.0\t0.0\t9.81\n".encode(),
                f"{t + 3}\tORI\t1.0\t0.0\t0.0\t0.0\n".encode()]
        if k % 2 == 0 and k <= mag_until:
            out.append(f"{t}\tMAG\t0.0\t20.0\t-40.0\n".encode())
    return out


def test_replay_matches_run_offline_bit_for_bit(tmp_path):
    if not REALPHONE.is_dir():
        pytest.skip(f"shared real-phone logs not found at {REALPHONE}")
    path = REALPHONE / "sensorLog_20221024T182616_standstill.txt"
    engine = Engine(LogFileSource(path, speed=0), comparisons=False, record_rows=True,
                    recorder=Recorder(tmp_path / "rec"))
    with engine:
        final = _wait_state(engine, "finished")
    offline = run_offline(read_log(path))
    t_ms = np.concatenate([r.t_ms for r in engine.rows_log])
    quat = np.concatenate([r.quat for r in engine.rows_log])
    assert np.array_equal(t_ms, offline.t_ms) and np.array_equal(quat, offline.quat)
    assert (final.health.damaged, final.health.out_of_order) == (2, 420)
    assert final.health.damaged_reasons == {"value count": 2}       # two lines run together
    # the recording holds the lines that parse, verbatim: the file without its 2 damaged lines,
    # and it replays to the same estimates
    lines = path.read_bytes().splitlines(keepends=True)
    raw = (tmp_path / "rec" / "raw.txt").read_bytes()
    assert raw == b"".join(line for line in lines if _parses(line))
    assert len(raw.splitlines()) == len(lines) - 2
    again = run_offline(read_log(tmp_path / "rec" / "raw.txt"))
    assert np.array_equal(again.quat, offline.quat)



def test_poll_merges_plot_samples_and_fills_snapshot():
    lines = _log_lines(3.0, turn_rate=3.0, mag_until=100)   # 344 degrees of yaw without MAG
    engine = Engine(LineReplaySource(lines, "synthetic", speed=0), comparisons=True)
    with engine:
        _wait_state(engine, "finished")
        snapshot = engine.poll()
        assert snapshot is not None and engine.poll() is None      # nothing new since
    plot = snapshot.plot
    assert len(plot.t_gyr) == 300 and len(plot.t_acc) == 300 and len(plot.t_mag) == 51
    # OWN at our sensor times, PHONE at its own (3 ms later), in seconds since the start
    assert len(plot.t_est) == 300 and plot.own_euler_deg.shape == (300, 3)
    assert len(plot.t_ori) == 300 and plot.t_ori[0] == pytest.approx(0.003)
    assert plot.t_est[0] == 0.0 and np.all(np.diff(plot.t_est) > 0)
    assert snapshot.t0_ms == 1000
    yaw = plot.own_euler_deg[:, 0]
    assert yaw.max() - yaw.min() > 300 and np.abs(yaw).max() <= 180.0   # wrapped to ±180°
    assert np.sum(np.abs(np.diff(yaw)) > 180) == 1 and np.sum(np.abs(np.diff(yaw)) > 10) == 1
    # OWN turns at 3 rad/s, PHONE stays: the error grows, compared at PHONE's times
    assert len(plot.t_err) == 299 and plot.error_deg[:, 0].max() > 150
    assert snapshot.own_quat.shape == (4,) and snapshot.own_cov.shape == (4, 4)
    assert snapshot.phone_quat.tolist() == [1.0, 0.0, 0.0, 0.0]
    assert [c.name for c in snapshot.comparisons][0] == "gyr+acc+mag"
    health = snapshot.health
    assert health.rates_hz["GYR"] == pytest.approx(100.0) and health.rates_hz["MAG"] == 50.0
    assert health.lines_total == 951 and snapshot.replay["duration_s"] > 2.9


def test_commands_apply_in_the_engine_thread(tmp_path):
    recorder = Recorder(tmp_path / "rec")
    source = LineReplaySource(_log_lines(2.0), "synthetic", speed=0, paused=True)
    engine = Engine(source, comparisons=False, recorder=recorder)
    with engine:
        engine.send(SetSensorEnabled("mag", False))
        engine.send(SetEstimator("complementary"))
        engine.send(SetComparisonsEnabled(True))
        engine.send(ReplayControl(step=40))
        snapshot = wait_for_snapshot(engine, lambda s: s.health.lines_total == 40, 10,
                                     "the 40 stepped lines")
        assert snapshot.status.sensors_enabled["mag"] is False
        assert snapshot.status.estimator == "complementary" and len(snapshot.comparisons) == 7
        engine.send(AlignHeading())
        engine.send(ResetFilter())
        engine.send(ReplayControl(paused=False))
        _wait_state(engine, "finished")
    timeline = [e["kind"] for e in recorder.session["timeline"]]
    assert timeline[:3] == ["connected", "sensor", "estimator"] and "reset" in timeline
    engine.stop()                                   # idempotent


def test_simulated_session_through_tcp_equals_run_offline_and_is_recorded(tmp_path):
    from ekf.simulate import simulate

    from app.stream.emulator import PhoneEmulator
    from app.stream.protocol import Sample, format_line
    from app.stream.sources import TcpSource
    session = simulate(duration_s=20.0, rates_hz={"gyr": 200.0, "acc": 200.0, "mag": 100.0,
                                                  "ori": 100.0}, seed=4)
    lines = [(format_line(Sample(t, tag, values)) + "\n").encode()
             for t, tag, values in session.iter_rows()]
    path = tmp_path / "simulated.txt"
    path.write_bytes(b"".join(lines))
    engine = Engine(TcpSource("127.0.0.1", 0), comparisons=True, record_rows=True,
                    recorder=Recorder(tmp_path / "rec"))
    with engine:
        with PhoneEmulator("127.0.0.1", engine.source.port) as phone:
            for start in range(0, len(lines), 777):      # many chunks, cut anywhere
                phone.send(b"".join(lines[start:start + 777])[:-3])
                phone.send(lines[min(len(lines), start + 777) - 1][-3:])
        _wait_state(engine, "disconnected")
        wait_for_snapshot(engine, lambda s: s.health.lines_total >= len(lines), 20,
                          "every line counted")
    offline = run_offline(read_log(path))
    t_ms = np.concatenate([r.t_ms for r in engine.rows_log])
    quat = np.concatenate([r.quat for r in engine.rows_log])
    assert np.array_equal(t_ms, offline.t_ms) and np.array_equal(quat, offline.quat)
    assert (tmp_path / "rec" / "raw.txt").read_bytes() == path.read_bytes()
    assert len(engine.latencies_s) > 0


def test_a_paced_replay_starts_at_its_beginning_once_the_kernels_are_ready(tmp_path,
                                                                           monkeypatch):
    """The first start compiles the kernels in the engine's thread; meanwhile the snapshots say
    so, and the replay's clock starts only when they are ready, not at the engine's start."""
    import app.engine.live.worker as worker

    released = []
    # a warm-up that takes 1.5 s: the replay's clock must not start before it is over
    monkeypatch.setattr(worker, "warm_up", lambda: (time.sleep(1.5), released.append(1)))
    path = tmp_path / "log.txt"
    path.write_bytes(b"".join(_log_lines(20.0)))
    engine = Engine(LogFileSource(path, speed=1.0), comparisons=False)
    with engine:
        first = wait_for_snapshot(engine, lambda s: s.preparing, 10.0, "the preparing state")
        assert first.t_ms is None
        moving = wait_for_snapshot(engine, lambda s: s.t_ms is not None, 20.0, "samples")
        assert released and not moving.preparing
        assert moving.replay["position_s"] < 0.6        # not 1.5 s in: the clock waited
