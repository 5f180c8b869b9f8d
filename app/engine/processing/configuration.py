"""The filter's configuration over time: one model that every consumer reads.

For every sample position of the stream the engine runs (a live stream, or a pass of a replay)
the :class:`Configuration` says which sensors are switched in, which estimator OWN runs, with
which settings, and whether (and with which estimator) the sensor combinations run. Positions
count the samples fed to the estimators since the pass started (``Pipeline.fed``); a
:class:`Change` at position ``k`` applies after ``k`` samples, i.e. before the sample with
index ``k``.

Layers, one kind of change each:

* the **recorded** layer: a replayed recording's set-up at its start and its timeline (the
  switches, estimator, settings and comparisons changes, resets and heading alignments at the
  sample positions where they happened live); for a phone's own log or a live stream, the
  engine's own set-up and no changes;
* **your overrides**, one per kind (:data:`KINDS`: each sensor's switch, the estimator, the
  settings, the comparisons): a replay's whole pass runs with your value of that kind, from
  its start; the recorded changes of that kind are set aside and every other kind stays as
  recorded;
* **your changes at a moment** (:meth:`Configuration.add`): on a live stream, and while a
  replay is being recorded, a change applies from the sample where it was made on, as the
  recording keeps it.

:meth:`Configuration.setup` resolves the layers into a :class:`Setup`, what a pass applies:
the configuration at its start and the changes at their positions. The live engine, a replay's
passes, seeks and index, Tune's re-runs and the auto-tune, your filter's catch-up, recordings
and exports all run a Setup through :func:`apply_change`, so they agree sample for sample.
"""

from __future__ import annotations

import bisect
import dataclasses
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import ekf
from ekf import SENSORS
from app.engine.sessions.session import SessionInfo, settings_from_dict

#: What an override replaces, one kind each: a sensor's switch, the estimator, the settings,
#: the comparisons.
KINDS = (*SENSORS, "estimator", "settings", "comparisons")
KIND_NAMES = {"gyr": "gyroscope", "acc": "accelerometer", "mag": "magnetometer",
              "estimator": "estimator", "settings": "settings", "comparisons": "combinations"}
#: The changes a timeline holds (session.json's filter events).
CHANGE_KINDS = ("sensor", "estimator", "settings", "comparisons", "reset", "align_heading")
LIVE_CHANGES_KEPT = 10_000     # a live stream's changes kept (older ones fold into its start)


@dataclass(frozen=True)
class Config:
    """The configuration at one sample: OWN's estimator, the sensors switched in, the settings,
    whether the 7 sensor combinations run and which estimator they run."""

    estimator: str = "ekf"
    sensors: tuple[str, ...] = SENSORS
    settings: ekf.EKFSettings = field(default_factory=lambda: ekf.PRESETS["default"])
    comparisons: bool = True
    comparison_estimator: str = "ekf"

    @classmethod
    def of(cls, runner: Any) -> Config:
        """What an :class:`~app.engine.processing.runner.EstimatorRunner` runs now."""
        enabled = runner.sensors_enabled
        return cls(runner.estimator_name, tuple(s for s in SENSORS if enabled[s]),
                   runner.settings, bool(runner.comparisons), runner.comparison_estimator)

    def value(self, kind: str) -> Any:
        """This configuration's value of an override kind (KINDS)."""
        if kind in SENSORS:
            return kind in self.sensors
        if kind == "comparisons":
            return (self.comparisons, self.comparison_estimator)
        return getattr(self, kind)

    def with_value(self, kind: str, value: Any) -> Config:
        if kind in SENSORS:
            on = set(self.sensors) | {kind} if value else set(self.sensors) - {kind}
            return dataclasses.replace(self, sensors=tuple(s for s in SENSORS if s in on))
        if kind == "comparisons":
            enabled, estimator = value
            return dataclasses.replace(self, comparisons=bool(enabled),
                                       comparison_estimator=estimator or
                                       self.comparison_estimator)
        return dataclasses.replace(self, **{kind: value})

    def apply(self, change: Change) -> Config:
        """The configuration after `change` (a reset or an alignment changes none of it)."""
        kind = change.kind_overridden
        return self if kind is None else self.with_value(kind, change.value)

    def changes_to(self, other: Config, sample: int) -> list[Change]:
        """The changes that turn this configuration into `other`, at `sample`."""
        out = []
        for kind in KINDS:
            if self.value(kind) != other.value(kind):
                out.append(Change.of(kind, other.value(kind), sample))
        return out


@dataclass(frozen=True)
class Change:
    """One change at a sample position. kind: one of CHANGE_KINDS; sensor and enabled (a
    switch); name (the estimator; the comparisons' estimator, None: keep it); enabled (the
    comparisons on/off); settings; note: what a recording's timeline entry keeps beside it
    ((key, value) pairs: the settings' source and profile name); calibration: the calibration
    profile new settings came from (session.json keeps it under "calibration")."""

    sample: int
    kind: str
    sensor: str | None = None
    enabled: bool | None = None
    name: str | None = None
    settings: ekf.EKFSettings | None = None
    note: tuple[tuple[str, Any], ...] = ()
    calibration: Any = field(default=None, compare=False)

    @classmethod
    def of(cls, kind: str, value: Any, sample: int = 0, note: Iterable = ()) -> Change:
        """The change that sets an override kind (KINDS) to `value`."""
        note = tuple(note)
        if kind in SENSORS:
            return cls(sample, "sensor", sensor=kind, enabled=bool(value), note=note)
        if kind == "estimator":
            return cls(sample, "estimator", name=value, note=note)
        if kind == "settings":
            return cls(sample, "settings", settings=value, note=note)
        if kind == "comparisons":
            enabled, estimator = value
            return cls(sample, "comparisons", enabled=bool(enabled), name=estimator, note=note)
        raise ValueError(f"unknown kind of configuration {kind!r}")

    @property
    def kind_overridden(self) -> str | None:
        """The override kind (KINDS) that sets this change aside; None for a reset or an
        alignment, which no override replaces."""
        if self.kind == "sensor":
            return self.sensor
        return self.kind if self.kind in ("estimator", "settings", "comparisons") else None

    @property
    def value(self) -> Any:
        """The value of its kind after this change."""
        if self.kind == "sensor":
            return bool(self.enabled)
        if self.kind == "estimator":
            return self.name
        if self.kind == "settings":
            return self.settings
        if self.kind == "comparisons":
            return (bool(self.enabled), self.name)
        return None

    def at(self, sample: int) -> Change:
        return dataclasses.replace(self, sample=int(sample))

    @classmethod
    def from_event(cls, event: dict[str, Any]) -> Change | None:
        """A session.json timeline entry (app.engine.sessions.session: a filter event with its
        sample); None for an entry that changes nothing (settings without values)."""
        kind, sample = event.get("kind"), int(event["sample"])
        if kind == "sensor":
            return cls(sample, kind, sensor=event["sensor"], enabled=bool(event["enabled"]))
        if kind == "estimator":
            return cls(sample, kind, name=event["name"])
        if kind == "settings":
            settings = settings_from_dict(event.get("settings"))
            return None if settings is None else cls(sample, kind, settings=settings)
        if kind == "comparisons":
            return cls(sample, kind, enabled=bool(event.get("enabled", True)),
                       name=event.get("estimator"))
        if kind in ("reset", "align_heading"):
            return cls(sample, kind)
        return None

    def event_data(self) -> dict[str, Any]:
        """What a recording's timeline entry of this change holds (besides kind, time and
        sample)."""
        data: dict[str, Any] = {}
        if self.kind == "sensor":
            data = {"sensor": self.sensor, "enabled": bool(self.enabled)}
        elif self.kind == "estimator":
            data = {"name": self.name}
        elif self.kind == "settings":
            data = {"settings": self.settings.to_dict()}
        elif self.kind == "comparisons":
            data = {"enabled": bool(self.enabled), "estimator": self.name}
        return {**data, **dict(self.note)}


def apply_change(runner: Any, change: Change) -> dict[str, Any]:
    """Apply `change` to an :class:`~app.engine.processing.runner.EstimatorRunner`; what happened,
    for the recording (an alignment: the angle turned, None without PHONE's orientation)."""
    kind = change.kind
    if kind == "sensor":
        runner.set_sensor_enabled(change.sensor, bool(change.enabled))
    elif kind == "estimator":
        runner.set_estimator(change.name)
    elif kind == "settings":
        runner.set_settings(change.settings)
    elif kind == "comparisons":
        runner.set_comparisons_enabled(bool(change.enabled), change.name)
    elif kind == "reset":
        runner.reset()
    elif kind == "align_heading":
        turned = runner.align_heading()
        return {"turned_deg": None if turned is None else round(turned, 2)}
    return {}


@dataclass(frozen=True)
class Setup:
    """What a pass applies: the configuration at its start (estimator, sensors switched in,
    settings (None: the default preset), comparisons and their estimator), the changes at
    their sample positions (`timeline`, in order) and, for a recording that started
    mid-stream, the live engine's state then (`start_state`, session.json's; identified by
    `start_state_id` in comparisons)."""

    estimator: str = "ekf"
    sensors: tuple[str, ...] = SENSORS
    settings: ekf.EKFSettings | None = None
    comparisons: bool = True
    comparison_estimator: str = "ekf"
    timeline: tuple[Change, ...] = ()
    start_state: Any = field(default=None, compare=False)
    start_state_id: int = 0

    @classmethod
    def of(cls, start: Config, timeline: Iterable[Change] = (), start_state: Any = None
           ) -> Setup:
        return cls(start.estimator, tuple(start.sensors), start.settings, start.comparisons,
                   start.comparison_estimator, tuple(timeline), start_state,
                   id(start_state) if start_state is not None else 0)

    @property
    def start(self) -> Config:
        return Config(self.estimator, tuple(self.sensors),
                      self.settings if self.settings is not None else ekf.PRESETS["default"],
                      self.comparisons, self.comparison_estimator)

    def at(self, sample: int) -> Config:
        """The configuration for the sample with index `sample`."""
        config = self.start
        for change in self.timeline:
            if change.sample > sample:
                break
            config = config.apply(change)
        return config

    def overridden(self, kind: str, value: Any) -> Setup:
        """This set-up with `value` for kind (KINDS) over the whole pass: the same operation
        as a user's override (the auto-tune's candidates are settings overrides)."""
        start = self.start.with_value(kind, value)
        timeline = tuple(c for c in self.timeline if c.kind_overridden != kind)
        return dataclasses.replace(Setup.of(start, timeline, self.start_state),
                                   start_state_id=self.start_state_id)

    def until(self, samples: int) -> Setup:
        """The changes of the first `samples` samples only (a run that stops there)."""
        return dataclasses.replace(self, timeline=tuple(c for c in self.timeline
                                                        if c.sample <= samples))


def recorded_setup(session: SessionInfo | None, own: Config) -> Setup:
    """The recorded layer of a replay: a recording's set-up at its start (where session.json
    says; `own` where it does not), its timeline and start state; `own` alone for a log
    without a session.json."""
    if session is None:
        return Setup.of(own)
    start = own
    if session.estimator:
        start = start.with_value("estimator", session.estimator)
    if isinstance(session.sensors, dict):
        start = dataclasses.replace(start, sensors=tuple(
            s for s in SENSORS if session.sensors.get(s, True)))
    if session.settings is not None:
        start = start.with_value("settings", session.settings)
    comparisons = session.comparisons if isinstance(session.comparisons, dict) else {}
    start = start.with_value("comparisons", (comparisons.get("enabled", start.comparisons),
                                             comparisons.get("estimator")))
    changes = [Change.from_event(event) for event in session.filter_events]
    return Setup.of(start, [c for c in changes if c is not None], session.start_state)


@dataclass(frozen=True)
class ConfigurationView:
    """The configuration as the snapshot carries it (plain data, never changed once handed
    out): `version` counts its changes; `replaying` and `recorded` (a recorded session is
    replayed: there is a recording to go back to); `setup` what the pass applies; `current`
    the configuration at the engine's position; `overridden` the kinds (KINDS) that are yours
    over the whole replay, `added` your changes at a moment; `summary` one line saying what of
    the recording is yours; `path` the replayed log (None: live)."""

    version: int = 0
    replaying: bool = False
    recorded: bool = False
    setup: Setup = field(default_factory=Setup)
    current: Config = field(default_factory=Config)
    overridden: tuple[str, ...] = ()
    added: int = 0
    summary: str = ""
    path: str | None = None

    @property
    def yours(self) -> bool:
        """Something of the recording is overridden: "back to the recording" can undo it."""
        return bool(self.overridden or self.added)


def summary_line(overridden: Iterable[str], added: int) -> str:
    """"settings, gyroscope switch: yours; other switches, estimator, combinations: recorded"."""
    yours = set(overridden)
    switches_yours = [s for s in SENSORS if s in yours]
    switches_recorded = [s for s in SENSORS if s not in yours]
    mine = [KIND_NAMES[k] for k in ("estimator", "settings", "comparisons") if k in yours]
    theirs = [KIND_NAMES[k] for k in ("estimator", "settings", "comparisons") if k not in yours]
    if len(switches_yours) == len(SENSORS):
        mine.insert(0, "switches")
    elif switches_yours:
        mine.insert(0, " and ".join(KIND_NAMES[s] for s in switches_yours) + " switch"
                    + ("es" if len(switches_yours) > 1 else ""))
    if not switches_yours:
        theirs.insert(0, "switches")
    elif switches_recorded:
        theirs.insert(0, "other switches")
    parts = []
    if mine:
        parts.append(f"{', '.join(mine)}: yours")
    if theirs:
        parts.append(f"{', '.join(theirs)}: recorded")
    if added == 1:
        parts.append("1 change of yours at its moment")
    elif added:
        parts.append(f"{added} changes of yours at their moment")
    return "; ".join(parts) if mine or added else "everything as recorded"


class Configuration:
    """The engine's configuration over time (see the module docstring). One object per engine,
    owned by it and handed to the parts that read or change it; all calls come from the
    engine's thread (the snapshot carries a :class:`ConfigurationView`).

    own: the engine's own set-up (its estimator, sensors, settings, comparisons) for a stream
    without a recorded one; session: the replayed recording's session.json (None: none);
    replaying: the stream is a replay (a user's change is then an override)."""

    def __init__(self, own: Config, session: SessionInfo | None = None,
                 replaying: bool = False, path: str | None = None) -> None:
        self.version = 0
        self._base = recorded_setup(session, own)
        self._recorded = session is not None
        self._replaying = bool(replaying)
        self._path = path
        self._overrides: dict[str, Any] = {}
        self._added: list[Change] = []
        self._view: ConfigurationView | None = None
        self._steps: tuple[list[int], list[Config]] = ([], [])

    # -- what it says ------------------------------------------------------------------------------

    @property
    def replaying(self) -> bool:
        return self._replaying

    @property
    def recorded(self) -> bool:
        """A recording's set-up is the base layer (there is a recording to go back to)."""
        return self._recorded

    @property
    def overridden(self) -> tuple[str, ...]:
        return tuple(k for k in KINDS if k in self._overrides)

    @property
    def added(self) -> tuple[Change, ...]:
        return tuple(self._added)

    def start(self) -> Config:
        """The configuration at the pass's start: the recorded one with your overrides."""
        config = self._base.start
        for kind, value in self._overrides.items():
            config = config.with_value(kind, value)
        return config

    def changes(self) -> tuple[Change, ...]:
        """The changes a pass applies, in sample order: the recorded ones of kinds not
        overridden, then yours at their moments (at an equal position after the recorded)."""
        kept = [c for c in self._base.timeline if c.kind_overridden not in self._overrides]
        return tuple(sorted(kept + self._added, key=lambda c: c.sample))

    def setup(self) -> Setup:
        setup = Setup.of(self.start(), self.changes(), self._base.start_state)
        return dataclasses.replace(setup, start_state_id=self._base.start_state_id)

    def at(self, sample: int) -> Config:
        """The configuration for the sample with index `sample` of the pass."""
        return self.setup().at(sample)

    def summary(self) -> str:
        """One line: what of the recording is yours (a log without a recording: what of the
        set-up it started with)."""
        if self._recorded:
            return summary_line(self._overrides, len(self._added))
        mine = [KIND_NAMES[k] + (" switch" if k in SENSORS else "") for k in self.overridden]
        return f"{', '.join(mine)}: yours, over the whole replay" if mine else \
            "the set-up it started with"

    def view(self, position: int) -> ConfigurationView:
        """The snapshot's view at the engine's position (the same object while nothing
        changed)."""
        view = self._view
        if view is None or view.version != self.version:
            setup = self.setup()
            self._steps = _steps(setup)
            view = None
        else:
            setup = view.setup
        samples, configs = self._steps
        current = configs[bisect.bisect_right(samples, position)]
        if view is not None and view.current == current:
            return view
        self._view = ConfigurationView(self.version, self._replaying, self._recorded, setup,
                                       current, self.overridden, len(self._added),
                                       self.summary(), self._path)
        return self._view

    # -- changes -----------------------------------------------------------------------------------

    def override(self, kind: str, value: Any) -> None:
        """Your value of `kind` for the whole pass; the recorded changes of that kind, and your
        earlier ones at a moment, are set aside."""
        if kind not in KINDS:
            raise ValueError(f"unknown kind of configuration {kind!r}")
        self._overrides[kind] = value
        self._added = [c for c in self._added if c.kind_overridden != kind]
        self._changed()

    def override_all(self, config: Config) -> None:
        """Every kind yours, at the values of `config`."""
        for kind in KINDS:
            self._overrides[kind] = config.value(kind)
        self._added = [c for c in self._added if c.kind_overridden is None]
        self._changed()

    def add(self, change: Change) -> None:
        """Your change at its moment (change.sample)."""
        self._added.append(change)
        if not self._replaying and len(self._added) > LIVE_CHANGES_KEPT:
            # a live stream's oldest changes become part of its start (never replayed)
            oldest = self._added.pop(0)
            self._base = Setup.of(self._base.start.apply(oldest), self._base.timeline,
                                  self._base.start_state)
        self._changed()

    def follow_recording(self) -> bool:
        """Back to the recording: none of yours any more. True when something was yours."""
        if not self._overrides and not self._added:
            return False
        self._overrides.clear()
        self._added.clear()
        self._changed()
        return True

    def go_live(self, current: Config) -> None:
        """A phone took over from a replay (the demo): its set-up is the one running now."""
        self._base = Setup.of(current)
        self._recorded = False
        self._replaying = False
        self._path = None
        self._overrides.clear()
        self._added.clear()
        self._changed()

    def _changed(self) -> None:
        self.version += 1


def _steps(setup: Setup) -> tuple[list[int], list[Config]]:
    """The positions where the configuration changes and the configuration before the first
    and after each (configs[bisect_right(samples, k)] is the one at sample k)."""
    samples, configs = [], [setup.start]
    for change in setup.timeline:
        samples.append(change.sample)
        configs.append(configs[-1].apply(change))
    return samples, configs


def changes_due(changes: tuple[Change, ...], applied: tuple[Change, ...], fed: int) -> int:
    """How many of `changes` (a new list for a pass at position `fed`) count as applied: those
    before the position, and those at it that were applied already (`applied`: the old list's
    applied ones)."""
    count = 0
    for change in changes:
        if change.sample < fed or (change.sample == fed and change in applied):
            count += 1
        else:
            break
    return count


def setup_for_log(view: ConfigurationView | None, log: str | Path | None,
                  settings: ekf.EKFSettings | None = None) -> Setup:
    """The configuration a re-run of `log` applies (Tune's A/B run and the auto-tune): the
    replayed pass's, its changes at their positions, when `log` is the log the engine replays;
    otherwise the configuration running now, over the whole log. Without a view (a test
    double) the settings given, the rest the defaults."""
    if view is None:
        return Setup(settings=settings)
    return replayed_setup(view, log) or Setup.of(view.current)


def replayed_setup(view: ConfigurationView | None, log: str | Path | None) -> Setup | None:
    """The view's configuration over time when `log` is the log the engine replays (an export
    of it holds what the replay shows), else None."""
    if view is None or log is None or view.path is None or not _same_file(log, view.path):
        return None
    return view.setup


def _same_file(a: str | Path, b: str | Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False
