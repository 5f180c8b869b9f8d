"""The engine's side of a replay: its set-up, its index, its recorded timeline and markers.

A replay pass always starts from the same state (its set-up's initial checkpoint): at the start,
at every loop (each pass shows the same estimates) and as the base of every seek. The set-up is
the recorded one when the file is a recorded session and the user follows its timeline (the
default): the estimator, sensors and settings at the recording's start, the recorded switches
and changes at their sample positions, and the live engine's state when the recording started
mid-stream. Otherwise it is the window's own choices, applied from the start.

When the user changes the set-up while replaying (a sensor switch, the estimator, settings,
the comparisons, or following the timeline on/off), the recorded timeline is no longer
followed, the index is built again for the new set-up, and once it is complete the engine
re-synchronises at its current position: a replay's estimates are always those of its set-up
applied from the start (a seek anywhere then gives what playing there gives).
"""

from __future__ import annotations

import logging
from typing import Any

from app.engine.checkpoints import Checkpoint
from app.engine.pipeline import Pipeline, Setup
from app.engine.runner import SENSORS, EstimatorRunner
from app.engine.session import Marker, SessionInfo, read_session, session_json_for, write_markers
from app.engine.session_index import SessionIndex, SessionPlot
from app.stream.sources import Source

log = logging.getLogger("orientation_lab.engine")


class ReplayManager:
    """See the module docstring. source: the LineReplaySource; session: its session.json (None
    for a phone's own log); options: the engine's pipeline options (limits, orderer_options)."""

    def __init__(self, source: Any, session: SessionInfo | None,
                 options: dict[str, Any] | None = None, index: bool = True) -> None:
        self.source = source
        self.index_enabled = bool(index)
        self.session = session
        self.options = dict(options or {})
        self.follow = session is not None
        self.setup: Setup | None = None
        self.initial: Checkpoint | None = None
        self.index: SessionIndex | None = None
        self.resync = False
        self.markers: list[Marker] = list(session.markers) if session else []
        self.marker_error: str | None = None

    # -- set-up --------------------------------------------------------------------------------

    def setup_for(self, runner: EstimatorRunner) -> Setup:
        """The set-up a pass starts with: the recorded one (following a session's timeline) or
        the runner's current choices."""
        enabled = tuple(s for s in SENSORS if runner.sensors_enabled[s])
        current = Setup(runner.estimator_name, enabled, runner.settings, bool(runner.comparisons),
                        runner.comparison_estimator)
        info = self.session
        if not self.follow or info is None:
            return current
        sensors = current.sensors
        if isinstance(info.sensors, dict):
            sensors = tuple(s for s in SENSORS if info.sensors.get(s, True))
        comparisons = info.comparisons if isinstance(info.comparisons, dict) else {}
        return Setup(info.estimator or current.estimator, sensors,
                     info.settings or current.settings,
                     bool(comparisons.get("enabled", current.comparisons)),
                     comparisons.get("estimator") or current.comparison_estimator,
                     tuple(info.filter_events), info.start_state,
                     id(info) if info.start_state is not None else 0)

    def begin(self, pipeline: Pipeline) -> Checkpoint:
        """A new pass of the current set-up (made and indexed the first time)."""
        if self.setup is None:
            self.rebuild(pipeline, self.setup_for(pipeline.runner))
        return self.initial

    def rebuild(self, pipeline: Pipeline, setup: Setup) -> None:
        """Index the replay again for `setup` (in the background)."""
        if self.index is not None:
            self.index.cancel()
        self.setup = setup
        self.initial = pipeline.initial_checkpoint(setup)
        self.index = SessionIndex(self.source, setup, self.options).start() \
            if self.index_enabled else None

    def changed(self, pipeline: Pipeline) -> bool:
        """The user changed the set-up: stop following the timeline, index again, re-sync at
        the current position once indexed. True when the timeline was being followed."""
        was_following = self.follow and self.session is not None
        self.follow = False
        setup = self.setup_for(pipeline.runner)
        if setup != self.setup:
            self.rebuild(pipeline, setup)
            self.resync = True
        return was_following

    def set_follow(self, pipeline: Pipeline, follow: bool) -> None:
        self.follow = bool(follow) and self.session is not None
        setup = self.setup_for(pipeline.runner)
        if setup != self.setup:
            self.rebuild(pipeline, setup)
            self.resync = True

    def apply(self, pipeline: Pipeline, checkpoint: Checkpoint) -> None:
        """Restore a checkpoint of the current set-up into the engine's pipeline."""
        pipeline.restore(checkpoint)
        pipeline.timeline = self.setup.timeline if self.setup else ()

    def checkpoint_before(self, line: int) -> Checkpoint:
        """The latest checkpoint at or before `line` so far (the pass's start at worst)."""
        found = self.index.checkpoint_before(line) if self.index is not None else None
        return found if found is not None else self.initial

    def poll(self) -> bool:
        """True once, when the index for a changed set-up is complete (re-sync now)."""
        if self.resync and (self.index is None or self.index.complete or self.index.error):
            self.resync = False
            return True
        return False

    def stop(self) -> None:
        if self.index is not None:
            self.index.cancel()

    # -- what the window shows ----------------------------------------------------------------

    @property
    def plot(self) -> SessionPlot | None:
        """The whole session's plot data, once indexed (None for several sessions in one
        file: their times start again)."""
        index = self.index
        if index is None or not index.complete or not index.plot.valid:
            return None
        return index.plot

    def info(self) -> dict[str, Any]:
        index = self.index
        return {"following_timeline": self.follow and self.session is not None,
                "session_file": str(self.session.path) if self.session else None,
                "has_timeline": bool(self.session and self.session.filter_events),
                "indexed": bool(index and index.complete),
                "index_progress": 0.0 if index is None else float(index.progress),
                "index_seconds": 0.0 if index is None else float(index.elapsed_s),
                "index_error": None if index is None else index.error}

    # -- markers -------------------------------------------------------------------------------

    def save_markers(self) -> str | None:
        """Rewrite the replayed session's markers (atomically); a one-line problem or None.
        A phone's own log has no session.json: its markers stay in memory."""
        if self.session is None:
            return None
        try:
            write_markers(self.session.path, self.markers)
        except (OSError, ValueError) as error:
            return f"markers not saved in {self.session.path}: {getattr(error, 'strerror', None) or error}"
        return None


def session_for_source(source: Source) -> SessionInfo | None:
    """The session.json of a replayed recording (None for a phone's own log, or when it is
    unreadable: then the replay simply does not follow a timeline)."""
    path = getattr(source.played(), "path", None)
    found = session_json_for(path) if path is not None else None
    if found is None:
        return None
    try:
        return read_session(found)
    except ValueError as error:
        log.warning("%s", error)
        return None
