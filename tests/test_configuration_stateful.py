"""The configuration over time, driven by random user actions (issue 51): a hypothesis
RuleBasedStateMachine plays a recorded session in the engine and, at random, switches sensors,
edits settings (the settings panel and Tune send the same command), changes the estimator,
seeks, plays a stretch, records, loads and unloads your filter, and goes back to the recording
or overrides all of it.

The test keeps its own model of the configuration (the recorded timeline, the user's overrides
of one kind each, the user's changes at a moment while recording) and checks after every step:

* the engine runs the model's configuration at its position (its status), and its state there
  is that of a run of the model's configuration from the start (an independent reference run);
* every consumer sees the same configuration: the snapshot's, the replay's index, Tune's;
* Tune's re-run of the session is the model's run, row for row (so it is the replay's);
* your filter gets None exactly for the sensors switched off where it steps (every object of it
  since the latest change of the whole replay);
* a recording made during the sequence replays to the estimates it recorded.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings, strategies as st
from hypothesis.stateful import (RuleBasedStateMachine, invariant, precondition, rule,
                                 run_state_machine_as_test)

from waiting import wait_for_snapshot, wait_until

import ekf
from ekf.simulate import simulate
from app.engine.commands import (LoadUserFilter, ReplayControl, SetEstimator, SetFollowTimeline,
                                 SetSensorEnabled, SetSettings, StartRecording, StopRecording,
                                 UnloadUserFilter)
from app.engine.processing.configuration import setup_for_log
from app.engine.offline.filtering import csv_lines
from app.engine.processing.pipeline import Pipeline
from app.engine.offline.refilter import read_replayed, refilter
from app.engine.processing.runner import EstimatorRunner, Rows
from app.engine.live.worker import Engine
from app.stream.protocol import Sample, format_line
from app.stream.sources import LogFileSource

SENSORS = ekf.SENSORS
DEFAULT = ekf.PRESETS["default"]
SETTINGS = {
    "default": DEFAULT,
    "acc 2": dataclasses.replace(DEFAULT, acc_noise_cov=[[2.0, 0, 0], [0, 2.0, 0], [0, 0, 2.0]]),
    "gyr x10": dataclasses.replace(DEFAULT, gyr_noise_cov=[[3e-3, 0, 0], [0, 3e-3, 0],
                                                           [0, 0, 3e-3]]),
    "course": ekf.PRESETS["course"],
}
ESTIMATORS = ("ekf", "course", "complementary")
# the recording's own timeline: (sample, kind, value); kinds are the model's (a sensor, the
# estimator, the settings)
RECORDED = ((800, "gyr", False), (1400, "settings", "acc 2"), (2000, "gyr", True),
            (2600, "estimator", "course"))

GIVEN_LOG_FILTER = """
import os
LOG = {log!r}
class Filter:
    def __init__(self, settings=None):
        self.name = os.urandom(6).hex()
        with open(LOG, "a") as out:
            out.write(f"{{self.name}} new\\n")
    def step(self, t, gyr, acc, mag):
        with open(LOG, "a") as out:
            out.write(f"{{self.name}} {{round(t * 1000)}} {{int(gyr is not None)}}"
                      f"{{int(acc is not None)}}{{int(mag is not None)}}\\n")
        return [1.0, 0.0, 0.0, 0.0]
"""


# ---- the recorded session and what a run of a configuration gives -----------------------------

@dataclasses.dataclass(frozen=True)
class Session:
    folder: Path
    raw: Path
    t_ms: np.ndarray          # the ordered samples the engine feeds, in order
    tag: np.ndarray
    values: np.ndarray


def make_session(folder: Path) -> Session:
    folder.mkdir(parents=True, exist_ok=True)
    data = simulate(duration_s=10.0, rates_hz={"gyr": 100.0, "acc": 100.0, "mag": 50.0,
                                               "ori": 100.0}, seed=21)
    raw = folder / "raw.txt"
    raw.write_bytes(b"".join((format_line(Sample(t, tag, values)) + "\n").encode()
                             for t, tag, values in data.iter_rows()))
    timeline = []
    for sample, kind, value in RECORDED:
        if kind in SENSORS:
            timeline.append({"kind": "sensor", "sensor": kind, "enabled": value})
        elif kind == "estimator":
            timeline.append({"kind": "estimator", "name": value})
        else:
            timeline.append({"kind": "settings", "settings": SETTINGS[value].to_dict()})
        timeline[-1].update(t_ms=None, sample=sample)
    (folder / "session.json").write_text(json.dumps(
        {"format": 2, "timeline": timeline, "comparisons": {"enabled": False}}))
    pieces = []
    pipeline = Pipeline(EstimatorRunner())
    pipeline.on_ordered = lambda t, tag, values: pieces.append((t, tag, values))
    pipeline.feed_bytes(raw.read_bytes())
    pipeline.end_of_stream(partial_line_damaged=False)
    t_ms, tag, values = (np.concatenate(column) for column in zip(*pieces))
    return Session(folder, raw, t_ms, tag, values)


class Model:
    """The configuration over time as the user sees it: the recorded timeline, overrides of one
    kind each (a sensor's switch, the estimator, the settings) and changes at a moment."""

    def __init__(self) -> None:
        self.overrides: dict[str, object] = {}
        self.added: list[tuple[int, str, object]] = []

    def override(self, kind: str, value: object) -> None:
        self.overrides[kind] = value
        self.added = [a for a in self.added if a[1] != kind]

    def changes(self) -> list[tuple[int, str, object]]:
        recorded = [c for c in RECORDED if c[1] not in self.overrides]
        return sorted(recorded + self.added, key=lambda c: c[0])

    def start(self) -> dict[str, object]:
        config = {"gyr": True, "acc": True, "mag": True, "estimator": "ekf",
                  "settings": "default"}
        config.update(self.overrides)
        return config

    def at(self, position: int) -> dict[str, object]:
        config = self.start()
        for sample, kind, value in self.changes():
            if sample > position:
                break
            config[kind] = value
        return config


def apply(runner: EstimatorRunner, kind: str, value: object) -> None:
    if kind in SENSORS:
        runner.set_sensor_enabled(kind, bool(value))
    elif kind == "estimator":
        runner.set_estimator(value)
    else:
        runner.set_settings(SETTINGS[value])


def model_run(session: Session, model: Model, position: int | None = None) -> EstimatorRunner:
    """A fresh runner through the model's configuration, up to `position` samples (None: all)."""
    start = model.start()
    sensors = tuple(s for s in SENSORS if start[s])
    runner = EstimatorRunner(start["estimator"], SETTINGS[start["settings"]], sensors or SENSORS)
    for sensor in SENSORS:
        runner.set_sensor_enabled(sensor, bool(start[sensor]))
    end = len(session.t_ms) if position is None else position
    fed = 0
    for sample, kind, value in model.changes():
        if sample > end:
            break
        runner.feed_arrays(session.t_ms[fed:sample], session.tag[fed:sample],
                           session.values[fed:sample])
        fed = max(fed, sample)
        apply(runner, kind, value)
    runner.feed_arrays(session.t_ms[fed:end], session.tag[fed:end], session.values[fed:end])
    return runner


def expected_given(session: Session, model: Model) -> dict[int, set[str]]:
    """Per sample time, the sensors your filter must get there."""
    out: dict[int, set[str]] = {}
    changes = model.changes()
    config, k = model.start(), 0
    for position, (t_ms, tag) in enumerate(zip(session.t_ms.tolist(), session.tag.tolist())):
        while k < len(changes) and changes[k][0] <= position:
            config[changes[k][1]] = changes[k][2]
            k += 1
        if tag < 3:
            given = out.setdefault(t_ms, set())
            if config[SENSORS[tag]]:
                given.add(SENSORS[tag])
    return out


def replayed_rows(folder: Path) -> list[str]:
    engine = Engine(LogFileSource(folder / "raw.txt", speed=0), record_rows=True, index=False)
    with engine:
        wait_for_snapshot(engine, lambda s: s.health.connection_state == "finished", 60,
                          "the recording's replay to end")
    return csv_lines(Rows.concatenate(engine.rows_log))


# ---- the machine ------------------------------------------------------------------------------

class ConfigurationMachine(RuleBasedStateMachine):
    def __init__(self, session: Session, prepared) -> None:
        super().__init__()
        self.session, self.prepared = session, prepared
        self.scratch = Path(tempfile.mkdtemp(prefix="configuration-machine-"))
        self.model = Model()
        self.recording: Path | None = None
        self.recordings = 0
        self.filter_loaded = False
        self.retired: set[str] = set()          # your filter's objects from before a change
        self.given_log = self.scratch / "given.txt"
        self.filter_path = self.scratch / "given_filter.py"
        self.filter_path.write_text(GIVEN_LOG_FILTER.format(log=str(self.given_log)))
        self.source = LogFileSource(session.raw, speed=0, paused=True)
        self.engine = Engine(self.source, comparisons=False)
        self.engine.start()
        wait_for_snapshot(self.engine, lambda s: s.replay and s.replay.get("indexed"), 60,
                          "the replay indexed")

    def teardown(self) -> None:
        self.engine.stop()
        shutil.rmtree(self.scratch, ignore_errors=True)

    # -- helpers ---------------------------------------------------------------------------------

    @property
    def position(self) -> int:
        return self.engine.pipeline.fed

    def send(self, command, whole_replay: bool = False) -> None:
        """The command, applied; whole_replay: it changes the whole replay (or starts your
        filter afresh): your filter's objects so far belong to what was before."""
        before = set(self.filter_steps()) if whole_replay else set()
        self.engine.send(command)
        self.settle()
        self.retired |= before

    def filter_steps(self) -> dict[str, list[tuple[int, str]]]:
        """Your filter's steps, by filter object: (t_ms, "101": gyr, acc, mag given)."""
        steps: dict[str, list[tuple[int, str]]] = {}
        if self.given_log.exists():
            for line in self.given_log.read_text().splitlines():
                name, t_ms, *given = line.split()
                entry = steps.setdefault(name, [])
                if given:
                    entry.append((int(t_ms), given[0]))
        return steps

    def settle(self) -> None:
        """Every command applied, a change of the whole replay indexed and re-synchronised,
        your filter caught up."""
        engine = self.engine
        assert engine.wait_idle(60)
        if engine.replay_lane.manager.resync or not engine.snapshot_now().replay.get("indexed"):
            wait_until(lambda: not engine.replay_lane.manager.resync
                       and engine.snapshot_now().replay.get("indexed"), 60, what="indexed")
            assert engine.wait_idle(60)
        if self.filter_loaded:
            wait_until(lambda: engine.snapshot_now().user.state == "running"
                       and not engine.snapshot_now().user.backlog_rows, 60,
                       what="your filter caught up")

    def change(self, kind: str, value: object, command) -> None:
        """A user's change: an override of its kind, or (while recording) at this moment."""
        if self.recording is None:
            self.model.override(kind, value)
        else:
            self.model.added.append((self.position, kind, value))
        self.send(command, whole_replay=self.recording is None)

    # -- the user's actions ------------------------------------------------------------------------

    @rule(sensor=st.sampled_from(SENSORS))
    def toggle_sensor(self, sensor: str) -> None:
        enabled = not self.engine.snapshot_now().status.sensors_enabled[sensor]
        self.change(sensor, enabled, SetSensorEnabled(sensor, enabled))

    @rule(name=st.sampled_from(sorted(SETTINGS)), source=st.sampled_from(("panel", "tune")))
    def edit_settings(self, name: str, source: str) -> None:
        """The settings panel and Tune's send the same command."""
        self.change("settings", name, SetSettings(SETTINGS[name], source=source))

    @rule(name=st.sampled_from(ESTIMATORS))
    def choose_estimator(self, name: str) -> None:
        self.change("estimator", name, SetEstimator(name))

    @rule(fraction=st.floats(0.0, 1.0))
    def seek(self, fraction: float) -> None:
        self.send(ReplayControl(seek_s=fraction * self.source.duration_s), whole_replay=True)

    @rule(lines=st.integers(1, 2500))
    def play_a_stretch(self, lines: int) -> None:
        self.send(ReplayControl(step=lines))

    @precondition(lambda self: self.recording is None)
    @rule()
    def start_recording(self) -> None:
        self.recordings += 1
        self.recording = self.scratch / f"recording-{self.recordings}"
        self.send(StartRecording(str(self.recording)))

    @precondition(lambda self: self.recording is not None)
    @rule()
    def stop_recording(self) -> None:
        folder, self.recording = self.recording, None
        self.send(StopRecording())
        recorded = (folder / "estimates.csv").read_text().splitlines()[1:]
        if not (folder / "raw.txt").read_bytes():
            assert recorded == []
            return
        replayed = replayed_rows(folder)
        assert replayed[:len(recorded)] == recorded
        assert len(replayed) - len(recorded) < 100     # the samples held when it stopped

    @precondition(lambda self: not self.filter_loaded)
    @rule()
    def load_your_filter(self) -> None:
        self.filter_loaded = True
        self.send(LoadUserFilter(str(self.filter_path)), whole_replay=True)

    @precondition(lambda self: self.filter_loaded)
    @rule()
    def unload_your_filter(self) -> None:
        self.filter_loaded = False
        self.send(UnloadUserFilter(), whole_replay=True)

    @rule()
    def back_to_the_recording(self) -> None:
        if self.recording is None:
            self.model.overrides.clear()
            self.model.added.clear()
        self.send(SetFollowTimeline(True), whole_replay=True)

    @rule()
    def all_of_it_yours(self) -> None:
        if self.recording is None:
            now = self.model.at(self.position)
            for kind in (*SENSORS, "estimator", "settings"):
                self.model.override(kind, now[kind])
        self.send(SetFollowTimeline(False), whole_replay=True)

    # -- what must hold after every step -----------------------------------------------------------

    @invariant()
    def the_engine_runs_the_models_configuration(self) -> None:
        position = self.position
        want = self.model.at(position)
        status = self.engine.snapshot_now().status
        assert status.sensors_enabled == {s: bool(want[s]) for s in SENSORS}
        assert status.estimator == want["estimator"]
        assert status.settings == SETTINGS[want["settings"]]
        reference = model_run(self.session, self.model, position)
        runner = self.engine.runner
        where = (f"at sample {position} of {len(self.session.t_ms)}; overrides "
                 f"{self.model.overrides}, changes made {self.model.added}; replay "
                 f"{self.engine.snapshot_now().replay}")
        assert np.array_equal(runner.main.quat, reference.main.quat), where
        assert runner.latest_t_ms == reference.latest_t_ms, where

    @invariant()
    def every_consumer_sees_the_same_configuration(self) -> None:
        view = self.engine.snapshot_now().configuration
        index = self.engine.replay_lane.manager.setup
        tune = setup_for_log(view, self.session.raw)
        assert view.setup == index == tune
        for position in sorted({0, *(c[0] for c in self.model.changes()), self.position,
                                len(self.session.t_ms)}):
            want = self.model.at(position)
            got = view.setup.at(position)
            assert (got.estimator, got.settings) == (want["estimator"],
                                                     SETTINGS[want["settings"]])
            assert got.sensors == tuple(s for s in SENSORS if want[s])

    @invariant()
    def tunes_rerun_is_the_replay(self) -> None:
        view = self.engine.snapshot_now().configuration
        tune = refilter(self.prepared, None, setup=setup_for_log(view, self.session.raw)).rows
        reference = model_run(self.session, self.model)
        reference.finish()
        want = reference.take_rows()
        assert np.array_equal(tune.t_ms, want.t_ms) and np.array_equal(tune.quat, want.quat)

    @invariant()
    def your_filter_gets_none_exactly_for_the_sensors_switched_off(self) -> None:
        """Every step of your filter's objects since the latest change of the whole replay."""
        if not self.filter_loaded:
            return
        expected = expected_given(self.session, self.model)
        for name, steps in self.filter_steps().items():
            if name in self.retired:
                continue
            wrong = [(t, given, sorted(expected.get(t, ()))) for t, given in steps
                     if {s for s, flag in zip(SENSORS, given) if flag == "1"}
                     != expected.get(t, set())]
            assert wrong[:3] == []


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Session:
    return make_session(tmp_path_factory.mktemp("configuration") / "session")


def test_every_consumer_follows_one_configuration_through_random_user_actions(session):
    prepared = read_replayed(session.folder)
    run_state_machine_as_test(
        lambda: ConfigurationMachine(session, prepared),
        settings=settings(max_examples=5, stateful_step_count=10, deadline=None,
                          derandomize=True, database=None,
                          suppress_health_check=[HealthCheck.too_slow]))
