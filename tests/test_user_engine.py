"""Your filter in the live engine (YOURS): beside ours without changing ours; its errors pause only
it; a slow one is decimated instead of holding up the engine; saving the file reloads it (a
replay is re-run up to now, a live stream continues from now); commands; the session record.

Your filter runs in a process of its own and its results come back later than ours: a test that
looks at YOURS at the end waits until it has answered every row (_settled)."""

from __future__ import annotations

import hashlib
import json
import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from waiting import wait_for_snapshot

from app.engine.commands import (LoadUserFilter, ReplayControl, SetConsistencyEnabled,
                                 UnloadUserFilter)
from app.engine.config import open_log
from app.engine.offline.filtering import filter_log
from app.engine.userfilter.filter import UserFilterEstimator
from app.engine.live.worker import Engine
from app.stream.emulator import PhoneEmulator
from app.stream.recorder import Recorder
from app.stream.sources import LogFileSource, TcpSource
from user_filters import FILTERS, log_lines, save_again, write_filter

COURSE_EKF = Path(__file__).resolve().parents[1] / "examples" / "course_ekf.py"


def _wait(engine: Engine, predicate, timeout: float = 30.0):
    """Poll snapshots until predicate(snapshot) holds; returns that snapshot."""
    return wait_for_snapshot(engine, predicate, timeout,
                             describe=lambda s: f"user status: {s.user}")


def _log(tmp_path: Path, seconds: float = 3.0, rate_hz: float = 100.0) -> Path:
    path = tmp_path / "log.txt"
    path.write_bytes(b"".join(log_lines(seconds, rate_hz)))
    return path


def _finished(snapshot) -> bool:
    return snapshot.health.connection_state == "finished"


def _running(snapshot) -> bool:
    return snapshot.user is not None and snapshot.user.state == "running"


def _settled(snapshot) -> bool:
    """Your filter has answered every row handed to it (and is not loading or catching up)."""
    user = snapshot.user
    return (user is not None and user.state not in ("loading", "catching up")
            and user.backlog_rows == 0)


def _plots(engine: Engine) -> dict[str, np.ndarray]:
    chunks = []
    while (snapshot := engine.poll()) is not None:
        chunks.append(snapshot.plot)
    return {name: np.concatenate([getattr(c, name) for c in chunks])
            for name in ("t_est", "t_user", "user_euler_deg", "t_user_err", "user_error_deg",
                         "innovation_source")}


def test_yours_runs_beside_ours_and_leaves_ours_alone(tmp_path):
    log = _log(tmp_path)
    runs = {}
    for name in (None, "turned"):
        user = None if name is None else write_filter(tmp_path, name)
        engine = Engine(LogFileSource(log, speed=5), record_rows=True, user_filter=user)
        with engine:
            # every row reaches your filter: the last ones may still be on their way when the
            # source has finished and the lane's backlog is empty
            final = _wait(engine, lambda s: _finished(s) and (
                user is None or (_settled(s) and s.user.steps == 300)))
            plots = _plots(engine)
        runs[name] = (np.concatenate([r.quat for r in engine.rows_log]), final, plots)
    assert np.array_equal(runs[None][0], runs["turned"][0])       # ours: bit for bit the same
    _, final, plots = runs["turned"]
    user = final.user
    assert user.state == "running" and user.name == "turned.py" and user.problem is None
    assert user.quat == pytest.approx([math.cos(0.5), 0, 0, math.sin(0.5)])
    assert user.sha256 == hashlib.sha256((tmp_path / "turned.py").read_bytes()).hexdigest()
    assert user.time_per_sample_s < 1e-3 and user.steps == 300 and not user.slow
    assert [c.name for c in final.comparisons][-1] == "YOURS (turned.py)"
    # against PHONE at PHONE's times: turned 1 rad about up, so all of it is heading
    assert final.comparisons[-1].rmse_deg == pytest.approx(
        (math.degrees(1.0), math.degrees(1.0), 0.0), abs=1e-6)
    assert len(plots["t_user"]) == len(plots["t_est"]) == 300
    assert np.nanmax(np.abs(plots["user_euler_deg"][:, 0] - math.degrees(1.0))) < 1e-6
    assert len(plots["t_user_err"]) > 250
    assert np.nanmax(np.abs(plots["user_error_deg"][:, 0] - math.degrees(1.0))) < 1e-6


@pytest.mark.parametrize("name, message, at", [
    ("raises", "raises.py:11 in update: ValueError", 1.51),
    ("nan", "q is not finite", 1.51),
    ("shape", "q has shape (3,)", 1.0),
    ("endless", "in step: UserCodeTimeout: step() ran for more than 1 s", 1.51),
])
def test_an_error_pauses_only_your_filter(tmp_path, name, message, at):
    log = _log(tmp_path)
    engine = Engine(LogFileSource(log, speed=5), record_rows=True,
                    user_filter=write_filter(tmp_path, name))
    with engine:
        final = _wait(engine, lambda s: _finished(s) and s.user is not None
                      and s.user.state == "paused")
    user = final.user
    assert user.state == "paused" and message in user.problem.message
    assert user.problem.t_s == pytest.approx(at)
    assert not engine.failures and not engine.stopped_by_failure   # not an engine failure
    quat = np.concatenate([r.quat for r in engine.rows_log])
    ours = filter_log(open_log(log))
    assert len(np.concatenate([r.t_ms for r in engine.rows_log])) == 300
    assert np.array_equal(quat[np.concatenate([r.has_sample for r in engine.rows_log])],
                          ours.quat)
    assert len(final.comparisons) == 8                     # the 7 combinations go on, and YOURS
    yours = final.comparisons[-1].rmse_deg[0]               # flat until it stopped, then none
    assert yours == pytest.approx(0.0, abs=1e-6) if at > 1.0 else math.isnan(yours)


def test_a_slow_filter_is_flagged_and_decimated_not_waited_for(tmp_path):
    log = _log(tmp_path, seconds=4.0, rate_hz=500.0)      # 2000 rows at 500 Hz, real time
    engine = Engine(LogFileSource(log, speed=1), comparisons=False,
                    user_filter=write_filter(tmp_path, "slow"))
    started = time.monotonic()
    seen = []
    with engine:
        final = _wait(engine, lambda s: seen.append(s.user) or _finished(s), timeout=20)
    elapsed = time.monotonic() - started
    assert elapsed < 6.0                                     # the stream's pace, not 2000 x 3 ms
    assert final.health.lines_total == 2000 * 3 + 1000
    slow = [u for u in seen if u is not None and u.slow]
    assert slow, "never flagged slow"
    # its own process sleeps 3 ms a row while 2 ms of rows arrive: at most 2/3 of them
    assert min(u.used_fraction for u in slow) < 0.8
    assert 0.0025 < final.user.time_per_sample_s < 0.02       # shown: the time per sample
    assert final.user.steps < 1800 and final.user.problem is None
    # what is handed over is bounded by its speed: once the rows that came while it loaded
    # are done, YOURS lags by a fraction of a second (the last 2 s)
    assert final.user.lag_s < 1.0


def test_saving_the_file_reloads_it_and_re_runs_the_replay_up_to_now(tmp_path):
    log = _log(tmp_path)
    path = write_filter(tmp_path, "mine", FILTERS["flat"])
    engine = Engine(LogFileSource(log, speed=0), user_filter=path)
    with engine:
        _wait(engine, lambda s: _finished(s) and _running(s))
        save_again(path, COURSE_EKF.read_text())
        final = _wait(engine, lambda s: s.user.generation == 2 and _running(s)
                      and s.user.history is not None)
    user = final.user
    assert "reloaded: re-ran" in user.message and user.sha256 == hashlib.sha256(
        path.read_bytes()).hexdigest()
    offline = filter_log(open_log(log), UserFilterEstimator(COURSE_EKF))
    assert np.array_equal(user.quat, offline.quat[-1])      # the whole log, with the new code
    assert len(user.history.t_ms) == 300
    assert np.nanmax(user.history.error_deg[:, 0]) > 20      # the course EKF turns, flat did not


def test_a_paused_filter_runs_again_once_the_file_is_saved(tmp_path):
    log = _log(tmp_path)
    path = write_filter(tmp_path, "mine", FILTERS["raises"])
    engine = Engine(LogFileSource(log, speed=0), user_filter=path)
    with engine:
        _wait(engine, lambda s: s.user is not None and s.user.state == "paused")
        save_again(path, FILTERS["turned"])
        final = _wait(engine, lambda s: s.user.generation == 2 and _running(s)
                      and s.user.history is not None)
    assert final.user.problem is None
    assert final.user.quat == pytest.approx([math.cos(0.5), 0, 0, math.sin(0.5)])


def test_a_file_that_does_not_load_is_shown_and_watched(tmp_path):
    log = _log(tmp_path, seconds=1.0)
    path = write_filter(tmp_path, "mine", "class Filter:\n    def step(self, t, gyr, acc, mag)\n")
    engine = Engine(LogFileSource(log, speed=0, loop=True), user_filter=path)
    with engine:
        first = _wait(engine, lambda s: s.user is not None and s.user.state == "failed to load")
        save_again(path, FILTERS["flat"])
        _wait(engine, _running)
    assert first.user.problem.message.startswith("mine.py:2: SyntaxError")
    assert not engine.failures


def test_on_a_live_stream_the_new_code_continues_from_now(tmp_path):
    path = write_filter(tmp_path, "mine", FILTERS["flat"])
    engine = Engine(TcpSource("127.0.0.1", 0), comparisons=False, user_filter=path)
    stop = threading.Event()
    with engine:
        phone = PhoneEmulator("127.0.0.1", engine.source.port).connect()
        sender = threading.Thread(target=phone.stream_lines,
                                  args=(log_lines(60.0), 1.0, False, stop), daemon=True)
        sender.start()
        _wait(engine, lambda s: _running(s) and s.user.steps > 20)
        save_again(path, FILTERS["turned"])
        final = _wait(engine, lambda s: s.user.generation == 2 and s.user.steps > 5)
        stop.set()
        sender.join(5)
        phone.close()
    assert "live stream, your filter continues from now" in final.user.message
    assert final.user.quat == pytest.approx([math.cos(0.5), 0, 0, math.sin(0.5)])


def test_load_and_unload_commands_and_the_session_record(tmp_path):
    log = _log(tmp_path, seconds=2.0)
    path = write_filter(tmp_path, "flat")
    recorder = Recorder(tmp_path / "session")
    engine = Engine(LogFileSource(log, speed=0), recorder=recorder)
    with engine:
        _wait(engine, _finished)
        assert engine.snapshot_now().user is None
        engine.send(LoadUserFilter(str(path)))
        engine.send(SetConsistencyEnabled(True))
        _wait(engine, lambda s: _running(s) and s.user.history is not None)
        engine.send(UnloadUserFilter())
        _wait(engine, lambda s: s.user is None and len(s.comparisons) == 7)
    entries = [e for e in json.loads((tmp_path / "session" / "session.json").read_text())
               ["timeline"] if e["kind"] == "user_filter"]
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    assert [(e["action"], e["name"], e["sha256"]) for e in entries] == [
        ("load", "flat.py", digest), ("unload", "flat.py", digest)]


def test_our_innovations_are_published_while_asked_for(tmp_path):
    log = _log(tmp_path)
    engine = Engine(LogFileSource(log, speed=5), comparisons=False)
    engine.send(SetConsistencyEnabled(True))
    with engine:
        _wait(engine, _finished)
        plots = _plots(engine)
    assert len(plots["innovation_source"]) > 400                  # acc and mag updates: OWN


def test_after_a_seek_your_filter_catches_up_in_the_background(tmp_path):
    log = _log(tmp_path, seconds=10.0)
    engine = Engine(LogFileSource(log, speed=1), comparisons=False,
                    user_filter=write_filter(tmp_path, "flat"))
    with engine:
        _wait(engine, lambda s: _running(s) and s.user.steps > 30)
        engine.send(ReplayControl(seek_s=8.0))
        final = _wait(engine, lambda s: s.replay and s.replay["position_s"] > 8.2 and _running(s)
                      and s.user.steps > 850, timeout=10)
    assert final.user.used_fraction == 1.0           # re-synced rows were all run, none skipped


def test_the_re_run_reads_a_log_as_the_engine_feeds_it(realphone_dir):
    """Same samples in the same order as the live engine's runner gets them (damaged and
    out-of-order lines included), so a re-run up to sample N is the live run up to N."""
    from app.engine.userfilter.host import ordered_log
    path = realphone_dir / "sensorLog_20221024T182616_standstill.txt"   # 2 damaged, 420 late
    t_ms, tag, values = ordered_log(path)
    fed = []
    engine = Engine(LogFileSource(path, speed=0), comparisons=False)
    original = engine.runner.feed_arrays

    def spy(t, g, v):
        fed.append((t.copy(), g.copy(), v.copy()))
        return original(t, g, v)

    engine.runner.feed_arrays = spy
    with engine:
        _wait(engine, _finished)
    live = [np.concatenate([f[i] for f in fed]) for i in range(3)]
    assert np.array_equal(live[0], t_ms) and np.array_equal(live[1], tag)
    assert np.array_equal(live[2], values, equal_nan=True)


def test_after_a_seek_yours_is_where_playing_would_have_brought_it(tmp_path):
    """A seek restores our estimators from a checkpoint; yours is not in a checkpoint, so it
    re-runs the log up to there: after the seek it is where playing through would have brought
    it (the same as running it over the whole log offline)."""
    log = _log(tmp_path, seconds=4.0, rate_hz=100.0)
    user = write_filter(tmp_path, "integrating", """
        import numpy as np
        class Filter:
            def __init__(self):
                self.q = np.array([1.0, 0.0, 0.0, 0.0])
                self.t = None
            def step(self, t, gyr, acc, mag):
                if gyr is not None and self.t is not None:
                    half = 0.5 * (t - self.t) * np.asarray(gyr)
                    w, v = self.q[0], self.q[1:]
                    self.q = np.concatenate([[w - v @ half], w * half + v + np.cross(half, v)])
                    self.q /= np.linalg.norm(self.q)
                self.t = t
                return self.q
    """)
    offline = UserFilterEstimator(user)
    filter_log(open_log(log), offline)
    engine = Engine(LogFileSource(log, speed=2), comparisons=False, user_filter=user)
    with engine:
        _wait(engine, lambda s: _running(s) and s.replay and s.replay["position_s"] > 3.0)
        engine.send(ReplayControl(seek_s=1.0))
        _wait(engine, lambda s: s.replay and s.replay["position_s"] < 2.0)
        final = _wait(engine, lambda s: _finished(s) and _running(s) and _settled(s)
                      and s.user.steps > 250)
    assert final.user.used_fraction == 1.0            # nothing decimated
    assert final.user.quat == pytest.approx(offline.quat, abs=1e-12)
    assert "after the seek" in final.user.message
