"""One model of the configuration over time (app.engine.processing.configuration): the recorded
layer, your overrides (one kind each) and your changes at a moment; and issue 51's first scenario
through the engine: a Tune edit in a replay keeps the recorded gyroscope switches, applies the
new settings everywhere, your filter gets no gyroscope exactly where OWN runs without it, and
Tune's re-run of the session is the replay, row for row."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from waiting import wait_for_snapshot, wait_until

import ekf
from ekf.simulate import simulate
from app.engine.commands import (LoadUserFilter, ReplayControl, SetEstimator, SetFollowTimeline,
                                 SetSensorEnabled, SetSettings)
from app.engine.processing.configuration import (Change, Config, Configuration, Setup,
                                                 setup_for_log, summary_line)
from app.engine.processing.pipeline import Pipeline
from app.engine.offline.refilter import read_replayed, refilter
from app.engine.processing.runner import EstimatorRunner, Rows
from app.engine.sessions.session import SessionInfo, read_session
from app.engine.live.worker import Engine
from app.stream.protocol import Sample, format_line
from app.stream.sources import LogFileSource

GYR_OFF, GYR_ON = 2000, 4000                # recorded: the gyroscope out between these samples
TUNED = dataclasses.replace(ekf.PRESETS["default"],
                            acc_noise_cov=[[2.0, 0, 0], [0, 2.0, 0], [0, 0, 2.0]])


# ---- the model ------------------------------------------------------------------------------

def recorded(*changes: Change) -> Configuration:
    """A replayed recording whose session.json holds these changes and nothing else."""
    timeline = [{"kind": c.kind, "t_ms": None, "sample": c.sample, **c.event_data()}
                for c in changes]
    return Configuration(Config(), SessionInfo(Path("session.json"), {}, timeline=timeline),
                         replaying=True)


def test_an_override_replaces_its_kind_only_and_the_way_back_restores_the_recording():
    gyr_off, gyr_on = Change(100, "sensor", sensor="gyr", enabled=False), \
        Change(200, "sensor", sensor="gyr", enabled=True)
    course = Change(300, "estimator", name="course")
    configuration = recorded(gyr_off, gyr_on, course)
    configuration.override("settings", TUNED)
    assert configuration.changes() == (gyr_off, gyr_on, course)      # switches stay recorded
    assert configuration.at(150) == Config("ekf", ("acc", "mag"), TUNED)
    assert configuration.at(250) == Config("ekf", ekf.SENSORS, TUNED)
    assert configuration.at(300).estimator == "course"
    configuration.override("gyr", True)                              # a switch: switches only
    assert configuration.changes() == (course,)
    assert configuration.at(150) == Config("ekf", ekf.SENSORS, TUNED)
    assert configuration.summary() == ("gyroscope switch, settings: yours; other switches, "
                                       "estimator, combinations: recorded")
    version = configuration.version
    assert configuration.follow_recording() and configuration.version > version
    assert configuration.changes() == (gyr_off, gyr_on, course) and not configuration.overridden
    assert configuration.summary() == "everything as recorded"
    assert not configuration.follow_recording()                      # nothing to undo


def test_changes_at_a_moment_stay_at_their_sample_until_an_override_of_their_kind():
    configuration = recorded(Change(100, "sensor", sensor="mag", enabled=False))
    configuration.add(Change(50, "sensor", sensor="acc", enabled=False))
    configuration.add(Change(100, "reset"))
    assert [c.kind for c in configuration.changes()] == ["sensor", "sensor", "reset"]
    assert configuration.at(60).sensors == ("gyr", "mag")
    assert configuration.at(100).sensors == ("gyr",)
    configuration.override("acc", True)
    assert configuration.at(60).sensors == ekf.SENSORS
    assert [c.kind for c in configuration.added] == ["reset"]        # not an override's kind
    assert "1 change of yours at its moment" in configuration.summary()


def test_the_summary_line_names_what_is_yours_and_what_is_recorded():
    assert summary_line(["settings"], 0) == \
        "settings: yours; switches, estimator, combinations: recorded"
    assert summary_line(["gyr", "acc", "mag", "estimator"], 2) == \
        ("switches, estimator: yours; settings, combinations: recorded; 2 changes of yours at "
         "their moment")


def test_a_setup_with_settings_overridden_is_what_the_override_gives():
    configuration = recorded(Change(10, "settings", settings=ekf.PRESETS["course"]),
                             Change(20, "sensor", sensor="mag", enabled=False))
    candidate = configuration.setup().overridden("settings", TUNED)
    configuration.override("settings", TUNED)
    assert candidate == configuration.setup()


# ---- issue 51, item 1 (and 2) through the engine ---------------------------------------------

@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A recorded session (24 s) whose gyroscope was switched off for a stretch."""
    folder = tmp_path_factory.mktemp("gyro-off") / "session"
    folder.mkdir()
    data = simulate(duration_s=24.0, rates_hz={"gyr": 100.0, "acc": 100.0, "mag": 50.0,
                                               "ori": 100.0}, seed=5)
    lines = [(format_line(Sample(t, tag, values)) + "\n").encode()
             for t, tag, values in data.iter_rows()]
    (folder / "raw.txt").write_bytes(b"".join(lines))
    timeline = [{"kind": "sensor", "sensor": "gyr", "enabled": False, "t_ms": None,
                 "sample": GYR_OFF},
                {"kind": "sensor", "sensor": "gyr", "enabled": True, "t_ms": None,
                 "sample": GYR_ON}]
    (folder / "session.json").write_text(json.dumps({"format": 2, "timeline": timeline,
                                                     "comparisons": {"enabled": False}}))
    return folder


GIVEN_LOG_FILTER = """
import os
LOG = {log!r}
class Filter:
    def __init__(self, settings=None):
        self.name = os.urandom(6).hex()
    def step(self, t, gyr, acc, mag):
        with open(LOG, "a") as out:
            out.write(f"{{self.name}} {{round(t * 1000)}} {{int(gyr is not None)}}"
                      f"{{int(acc is not None)}}{{int(mag is not None)}}\\n")
        return [1.0, 0.0, 0.0, 0.0]
"""


def user_filter(tmp_path) -> tuple:
    log = tmp_path / "given.txt"
    path = tmp_path / "given_filter.py"
    path.write_text(GIVEN_LOG_FILTER.format(log=str(log)))
    return path, log


def given_steps(log) -> dict[str, list[tuple[int, str]]]:
    """Your filter's steps by filter object: (t_ms, "101": gyr, acc, mag given)."""
    steps: dict[str, list[tuple[int, str]]] = {}
    for line in log.read_text().splitlines():
        name, t_ms, given = line.split()
        steps.setdefault(name, []).append((int(t_ms), given))
    return steps


def expected_given(prepared, setup: Setup) -> dict[int, set[str]]:
    """Per sample time: the sensors your filter must get there (a sample of it at that time,
    switched in at that sample's position)."""
    out: dict[int, set[str]] = {}
    for position, (t_ms, tag) in enumerate(zip(prepared.t_ms.tolist(),
                                               prepared.tag.tolist())):
        if tag < 3:
            sensor = ekf.SENSORS[tag]
            given = out.setdefault(t_ms, set())
            if sensor in setup.at(position).sensors:
                given.add(sensor)
    return out


def check_given(steps: list[tuple[int, str]], expected: dict[int, set[str]]) -> int:
    wrong = [(t, given, sorted(expected.get(t, set()))) for t, given in steps
             if {s for s, flag in zip(ekf.SENSORS, given) if flag == "1"}
             != expected.get(t, set())]
    assert wrong[:5] == []
    return len(steps)


def replay_rows(engine: Engine) -> Rows:
    """The whole replay from its start as the engine plays it now (its rows)."""
    engine.send(ReplayControl(seek_s=0.0))
    assert engine.wait_idle()
    engine.rows_log.clear()
    engine.send(ReplayControl(paused=False))
    wait_for_snapshot(engine, lambda s: s.replay and s.replay.get("finished"), 60,
                      "the replay's end")
    assert engine.wait_idle()
    return Rows.concatenate(engine.rows_log)


def resynced(engine: Engine) -> None:
    """After a change of the whole replay: until it is indexed again and the engine is where
    the new index says."""
    wait_until(lambda: not engine.replay_lane.manager.resync
               and engine.snapshot_now().replay["indexed"], 60, what="indexed again")
    assert engine.wait_idle()


def reference(data: bytes, setup: Setup) -> Pipeline:
    pipeline = Pipeline(EstimatorRunner(collect_plot=True))
    pipeline.begin(pipeline.initial_checkpoint(setup), setup.timeline)
    pipeline.feed_bytes(data)
    return pipeline


def test_a_tune_edit_keeps_the_recorded_gyroscope_and_applies_the_settings_everywhere(
        session, tmp_path):
    raw = session / "raw.txt"
    filter_path, given_log = user_filter(tmp_path)
    source = LogFileSource(raw, speed=0, paused=True)
    with Engine(source, comparisons=False, record_rows=True) as engine:
        wait_for_snapshot(engine, lambda s: s.replay and s.replay.get("indexed"), 60, "indexed")
        engine.send(LoadUserFilter(str(filter_path)))
        inside = source.line_at(8.5)                    # in the stretch without the gyroscope
        engine.send(ReplayControl(seek_line=inside))
        assert engine.wait_idle()
        assert engine.snapshot_now().status.sensors_enabled["gyr"] is False
        engine.send(SetSettings(TUNED, source="tune"))        # Tune: acc_noise_cov 2 + Enter
        assert engine.wait_idle()
        resynced(engine)
        snapshot = engine.snapshot_now()
        view = snapshot.configuration
        assert view.overridden == ("settings",) and snapshot.status.settings == TUNED
        assert view.summary == "settings: yours; switches, estimator, combinations: recorded"
        assert snapshot.status.sensors_enabled["gyr"] is False      # as recorded, here
        # the recording's gyroscope where it was recorded, the new settings everywhere
        setup = Setup("ekf", ekf.SENSORS, TUNED, comparisons=False, timeline=(
            Change(GYR_OFF, "sensor", sensor="gyr", enabled=False),
            Change(GYR_ON, "sensor", sensor="gyr", enabled=True)))
        assert view.setup == setup
        want = reference(source.data[:source.starts[inside]], setup)
        np.testing.assert_array_equal(engine.runner.main.quat, want.runner.main.quat)
        assert engine.pipeline.fed == want.fed and GYR_OFF < want.fed < GYR_ON
        # the whole replay now: its rows are Tune's re-run, row for row
        played = replay_rows(engine)
        wait_until(lambda: engine.snapshot_now().user.state == "running", 30,
                   what="your filter's catch-up")

        def through_the_replay() -> bool:
            """The object that played the pass (the last one made) reached the replay's end
            (its process answers after OWN)."""
            steps = given_steps(given_log)
            last = steps[list(steps)[-1]] if steps else []
            return bool(last) and last[-1][0] - last[0][0] > 15_000

        wait_until(through_the_replay, 30, what="your filter through the replay")
        seconds = (played.t_ms[-1] - played.t_ms[0]) / 1000.0
        assert seconds > 20.0
        prepared = read_replayed(session)
        tune = refilter(prepared, None, setup=setup_for_log(view, raw)).rows
        assert np.array_equal(tune.t_ms, played.t_ms)
        assert np.array_equal(tune.quat, played.quat)
        # your filter: no gyroscope exactly where OWN runs without it
        steps = given_steps(given_log)
        last = list(steps)[-1]                          # the object that played the pass
        expected = expected_given(prepared, setup)
        assert check_given(steps[last], expected) > 100      # (live, it may skip rows)
        assert any(given[0] == "0" for _, given in steps[last]) and \
            any(given[0] == "1" for _, given in steps[last])


def test_a_recording_of_a_replay_keeps_what_plays_and_the_way_back_to_the_recording(
        session, tmp_path):
    from app.engine.commands import StartRecording, StopRecording
    source = LogFileSource(session / "raw.txt", speed=0, paused=True)
    with Engine(source, comparisons=False) as engine:
        wait_for_snapshot(engine, lambda s: s.replay and s.replay.get("indexed"), 60, "indexed")
        engine.send(SetEstimator("course"))                  # yours, for the whole replay
        engine.send(ReplayControl(seek_s=5.0))
        assert engine.wait_idle()
        assert engine.snapshot_now().configuration.overridden == ("estimator",)
        engine.send(StartRecording(str(tmp_path / "rec")))
        engine.send(SetSensorEnabled("mag", False))          # recording: from now on
        engine.send(ReplayControl(seek_s=1.0))               # refused while recording
        engine.send(SetFollowTimeline(True))                 # refused while recording
        engine.send(ReplayControl(paused=False))
        wait_for_snapshot(engine, lambda s: s.replay.get("finished"), 60, "the end")
        engine.send(StopRecording())
        assert engine.wait_idle()
        snapshot = engine.snapshot_now()
        assert any("stop the recording to jump" in w for w in snapshot.health.warnings)
        assert any("stop the recording first" in w for w in snapshot.health.warnings)
        view = snapshot.configuration
        assert view.overridden == ("estimator",) and view.added == 1
        assert "estimator: yours" in view.summary and "1 change of yours" in view.summary
        engine.send(SetFollowTimeline(True))
        view = wait_for_snapshot(engine, lambda s: not s.configuration.yours, 30,
                                 "back to the recording").configuration
        assert view.summary == "everything as recorded"
        wait_until(lambda: engine.snapshot_now().status.estimator == "ekf", 30,
                   what="the recorded estimator")
    recording = read_session(tmp_path / "rec" / "session.json")
    assert recording.estimator == "course" and recording.start_state is not None
    # yours at the recording's start, then the replayed recording's own switches
    assert [(e["kind"], e.get("sensor"), e.get("enabled")) for e in recording.filter_events] \
        == [("sensor", "mag", False), ("sensor", "gyr", False), ("sensor", "gyr", True)]
    recorded = (tmp_path / "rec" / "estimates.csv").read_text().splitlines()[1:]
    assert len(recorded) > 2000
    replayed = _replayed_rows(tmp_path / "rec")
    assert replayed[:len(recorded)] == recorded and len(replayed) - len(recorded) < 100


def _replayed_rows(folder) -> list[str]:
    from app.engine.offline.filtering import csv_lines
    engine = Engine(LogFileSource(folder / "raw.txt", speed=0), record_rows=True, index=False)
    with engine:
        wait_for_snapshot(engine, lambda s: s.health.connection_state == "finished", 60,
                          "the replay's end")
    return csv_lines(Rows.concatenate(engine.rows_log))


def test_the_auto_tune_and_an_export_run_the_replays_configuration(session, tmp_path):
    from app.engine.tuning import autotune
    from app.engine.offline.export import export_session
    raw = session / "raw.txt"
    view = Configuration(Config(), read_session(session / "session.json"), replaying=True,
                         path=str(raw)).view(0)
    setup = setup_for_log(view, raw)
    assert [c.kind for c in setup.timeline] == ["sensor", "sensor"]
    prepared = read_replayed(session)
    # a candidate of the auto-tune is the replay with those settings (the switches recorded)
    target = autotune.Target(prepared, None, 1.0, setup=setup)
    want = refilter(prepared, None, setup=setup.overridden("settings", TUNED), skip_s=1.0)
    assert target.evaluate(TUNED) == want.summary
    assert autotune.Target(prepared, None, 1.0).evaluate(TUNED) != want.summary   # every sensor
    # the window's export of the session it replays: what the replay shows
    from app.engine.offline.export import load_session
    data = load_session(session, setup=setup.overridden("settings", TUNED))
    rows = want.rows
    index = np.searchsorted(rows.t_ms, data.t_ms)
    assert np.array_equal(rows.t_ms[index], data.t_ms) and len(data) > 2000
    assert np.array_equal(data.quat, rows.quat[index])
    recorded = load_session(session)                     # the command line's: as recorded
    assert not np.array_equal(recorded.quat, data.quat)
    out = tmp_path / "export.csv"
    assert "rows" in export_session(session, "csv", out, setup=setup)


def test_a_log_without_a_recording_says_what_is_yours_without_a_recording():
    configuration = Configuration(Config(), replaying=True)
    assert configuration.summary() == "the set-up it started with"
    configuration.override("gyr", False)
    configuration.override("settings", TUNED)
    assert configuration.summary() == "gyroscope switch, settings: yours, over the whole replay"
