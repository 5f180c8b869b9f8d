"""Your MATLAB filter in the live engine (YOURS from Octave): the solved course filter in .m runs
beside ours on a replayed phone log and gives the built-in `course` estimates to 1e-9, with its
row in the comparisons and its innovations in the consistency view; an error or Octave ending
pauses only YOURS, and saving a .m file starts it again (a replay re-run up to now)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import ekf
from waiting import wait_for_snapshot

from app.engine.commands import SetConsistencyEnabled
from app.engine.config import open_log
from app.engine.offline.filtering import filter_log
from app.engine.snapshot import INNOVATION_SOURCES
from app.engine.live.worker import Engine
from app.stream.sources import LogFileSource
from matlab_filters import COURSE_M, BROKEN, matlab_filter, needs_octave, save_m

pytestmark = [needs_octave, pytest.mark.shared]

COURSE = ekf.PRESETS["course"]


def _wait(engine, predicate, timeout=60.0):
    return wait_for_snapshot(engine, predicate, timeout, describe=lambda s: f"user: {s.user}")


def _finished(snapshot) -> bool:
    return snapshot.health.connection_state == "finished"


def _settled(snapshot) -> bool:
    user = snapshot.user
    return (_finished(snapshot) and user is not None
            and user.state not in ("loading", "catching up") and user.backlog_rows == 0)


def _first_seconds(source, target, seconds: float):
    """The lines of a phone log up to `seconds` after its first time stamp."""
    lines = source.read_bytes().splitlines(keepends=True)
    t0 = int(lines[0].split(b"\t")[0])
    target.write_bytes(b"".join(line for line in lines
                                if int(line.split(b"\t")[0]) - t0 <= seconds * 1000))
    return target


@pytest.fixture
def log(realphone_dir, tmp_path):
    return _first_seconds(realphone_dir / "tsrt14_lab2_rotation.txt", tmp_path / "log.txt", 6.0)


def test_yours_from_octave_is_the_course_filter_live(log):
    engine = Engine(LogFileSource(log, speed=1), settings=COURSE, estimator="course",
                    user_filter=str(COURSE_M))
    engine.send(SetConsistencyEnabled(True))
    chunks = []
    with engine:
        final = _wait(engine, _settled)
        while (snapshot := engine.poll()) is not None:
            chunks.append(snapshot.plot)
    ours = filter_log(open_log(log), "course")
    user = final.user
    assert user.state == "running" and user.problem is None and user.name == "course"
    assert user.steps == len(ours.t_ms) and user.used_fraction == 1.0      # every row, live
    assert np.max(np.abs(user.quat - ours.quat[-1])) < 1e-9
    plot = {name: np.concatenate([getattr(c, name) for c in chunks])
            for name in ("t_user", "user_euler_deg", "innovation_source")}
    assert np.array_equal(np.round(plot["t_user"] * 1000), ours.t_ms - ours.t_ms[0])
    euler = np.degrees(ekf.quaternion.to_euler(ours.quat))
    assert np.max(np.abs((plot["user_euler_deg"] - euler + 180) % 360 - 180)) < 1e-7
    assert final.comparisons[-1].name == "YOURS (course)"
    assert 0.0 < final.comparisons[-1].rmse_deg[0] < 30.0          # against PHONE
    yours = INNOVATION_SOURCES.index("YOURS")
    assert np.count_nonzero(plot["innovation_source"] == yours) > len(ours.t_ms)


def test_an_error_pauses_only_yours_and_saving_starts_it_again(tmp_path, log):
    folder = matlab_filter(tmp_path, "runtime")
    engine = Engine(LogFileSource(log, speed=0), settings=COURSE, estimator="course",
                    user_filter=str(folder), record_rows=True)
    with engine:
        paused = _wait(engine, lambda s: _finished(s) and s.user is not None
                       and s.user.state == "paused")
        save_m(folder / "mu_g.m", (COURSE_M / "mu_g.m").read_text())
        final = _wait(engine, lambda s: s.user.generation == 2 and _settled(s)
                      and s.user.history is not None)
    assert paused.user.problem.message.startswith("mu_g.m:4 in mu_g: operator *: nonconformant")
    assert paused.user.problem.line == 4
    assert not engine.failures
    ours = filter_log(open_log(log), "course")
    own = np.concatenate([r.quat for r in engine.rows_log])
    has = np.concatenate([r.has_sample for r in engine.rows_log])
    assert np.array_equal(own[has], ours.quat)                   # OWN went on, untouched
    assert final.user.problem is None and "reloaded: re-ran" in final.user.message
    assert np.max(np.abs(final.user.quat - ours.quat[-1])) < 1e-9


def test_octave_ending_pauses_yours_and_a_save_restarts_it(tmp_path, log):
    folder = matlab_filter(tmp_path, "crash")
    engine = Engine(LogFileSource(log, speed=0), settings=COURSE, estimator="course",
                    user_filter=str(folder))
    with engine:
        paused = _wait(engine, lambda s: s.user is not None and s.user.state == "paused")
        save_m(folder / "mu_m.m", (COURSE_M / "mu_m.m").read_text())
        final = _wait(engine, lambda s: s.user.generation == 2 and _settled(s)
                      and s.user.history is not None)
    assert paused.user.problem.message == ("course: Octave ended (exit status 7): paused; save "
                                           "a .m file to restart it")
    assert final.user.state == "running" and not engine.failures
    assert math.isfinite(final.comparisons[-1].rmse_deg[0])
    assert BROKEN["crash"][0] == "mu_m.m"
