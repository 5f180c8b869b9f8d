"""Replay: the engine's side of a replay (its passes, its index, its markers) and the engine's
replay lane (which replay plays, its passes and seeks, and how a change of the configuration
reaches them).

A replay pass always starts from the same state (the initial checkpoint of the set-up the
engine's configuration resolves to, :mod:`app.engine.processing.configuration`): at the start,
at every loop (each pass shows the same estimates) and as the base of every seek. For a recorded
session the set-up is the recorded one (the estimator, sensors and settings at the recording's
start, the recorded switches and changes at their sample positions, and the live engine's state
when the recording started mid-stream) with the user's overrides, one kind each; for a phone's
own log it is the engine's own set-up with the user's overrides. :class:`ReplayManager` says
which.

A background index (:mod:`app.engine.sessions.index`) keeps a checkpoint every second of data,
so a seek restores the nearest one before its target and replays at most one second, plotted but
neither recorded nor counted as new estimates; the configuration's changes apply at their sample
positions. When the configuration changes while replaying, the index is built again for the new
set-up and, for an override (a change of the whole pass), the engine re-synchronises at its
current position once the index is complete: a replay's estimates are always those of its
configuration (a seek anywhere then gives what playing there gives).

A user's change of the configuration (:meth:`ReplayLane.change`): while a replay plays and no
recording runs, it overrides its kind for the whole replay: it shows at once, the replay is
indexed again and the engine re-synchronises at the current line once the index is complete. On
a live stream, and while a recording runs, it applies from the current sample on (the recording
keeps it at its sample, so it replays exactly what was shown); a replay keeps it there too.
A recording holds what plays in one piece: while it runs, seeks and a return to the recording
wait for it to stop.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from collections import deque
from pathlib import Path
from typing import Any, Protocol

from app.engine.commands import ReplayControl
from app.engine.processing.checkpoints import Checkpoint
from app.engine.processing.configuration import Change, Config, Configuration, Setup
from app.engine.processing.pipeline import Pipeline
from app.engine.sessions.index import SessionIndex, SessionPlot
from app.engine.sessions.recording import RecordingLane
from app.engine.sessions.session import (Marker, Markers, SessionInfo, read_session,
                                         session_json_for, write_markers)
from app.stream.sources import LineReplaySource, Source

log = logging.getLogger("orientation_lab.engine")


class ReplayManager:
    """See the module docstring. source: the LineReplaySource; configuration: the engine's;
    session: its session.json (None for a phone's own log: markers in memory only); options:
    the engine's pipeline options (limits, orderer_options)."""

    def __init__(self, source: Any, configuration: Configuration,
                 session: SessionInfo | None = None, options: dict[str, Any] | None = None,
                 index: bool = True) -> None:
        self.source = source
        self.configuration = configuration
        self.index_enabled = bool(index)
        self.session = session
        self.options = dict(options or {})
        self.setup: Setup | None = None
        self.initial: Checkpoint | None = None
        self.index: SessionIndex | None = None
        self.retired: list[SessionIndex] = []
        self.resync = False
        self.markers: list[Marker] = list(session.markers) if session else []
        self.marker_error: str | None = None

    # -- set-up --------------------------------------------------------------------------------

    def begin(self, pipeline: Pipeline) -> Checkpoint:
        """A new pass of the configuration's set-up (made and indexed when it changed)."""
        setup = self.configuration.setup()
        if setup != self.setup:
            self.rebuild(pipeline, setup)
        return self.initial

    def rebuild(self, pipeline: Pipeline, setup: Setup) -> None:
        """Index the replay again for `setup` (in the background)."""
        if self.index is not None:
            self.index.cancel()
            self.retired = [index for index in self.retired if index.running] + [self.index]
        self.setup = setup
        self.initial = pipeline.initial_checkpoint(setup)
        self.index = SessionIndex(self.source, setup, self.options).start() \
            if self.index_enabled else None

    def refresh(self, pipeline: Pipeline, resync: bool) -> None:
        """The configuration changed: index again for its set-up; `resync`: re-synchronise at
        the current position once indexed (the whole pass changed)."""
        setup = self.configuration.setup()
        if setup != self.setup:
            self.rebuild(pipeline, setup)
        self.resync = self.resync or resync

    def apply(self, pipeline: Pipeline, checkpoint: Checkpoint) -> None:
        """Restore a checkpoint of the current set-up into the engine's pipeline."""
        pipeline.begin(checkpoint, self.setup.timeline if self.setup else ())

    def checkpoint_before(self, line: int) -> Checkpoint:
        """The latest checkpoint at or before `line` so far (the pass's start at worst)."""
        found = self.index.checkpoint_before(line) if self.index is not None else None
        return found if found is not None else self.initial

    def poll(self, hold: bool = False) -> bool:
        """True once, when the index for a changed set-up is complete (re-sync now); `hold`:
        not yet (a recording runs: it keeps what plays, in one piece)."""
        if hold:
            return False
        if self.resync and (self.index is None or self.index.complete or self.index.error):
            self.resync = False
            return True
        return False

    def stop(self, timeout: float = 10.0) -> None:
        """Cancel every index still building and wait for their threads (a thread left inside
        a compiled kernel when the interpreter exits aborts the process)."""
        indexes = self.retired + ([self.index] if self.index is not None else [])
        for index in indexes:
            index.cancel()
        deadline = time.monotonic() + timeout
        for index in indexes:
            index.wait(max(0.0, deadline - time.monotonic()))
        self.retired = []

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
        configuration = self.configuration
        return {"following_timeline": configuration.recorded and not (
                    configuration.overridden or configuration.added),
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


class ReplayEvents(Protocol):
    """What the replay lane tells the engine around it."""

    def jumped(self) -> None:
        """A seek moved the replay: what was read at the old position is not wanted, and your
        filter re-runs up to the new one."""

    def new_pass(self) -> None:
        """A pass begins (the start, a loop, a seek): what was read before is not going to be
        published."""

    def say(self, topic: str, text: str) -> None:
        """One line for the status bar."""


class ReplayLane:
    """The replay of the engine's source (when it plays one) and the changes of its
    configuration. session: the replayed recording's session.json (None: none); index: build a
    replay's index in the background."""

    def __init__(self, source: Source, pipeline: Pipeline, configuration: Configuration,
                 session: SessionInfo | None, markers: Markers, recordings: RecordingLane,
                 events: ReplayEvents, index: bool = True) -> None:
        self.source = source
        self.pipeline = pipeline
        self.configuration = configuration
        self.session = session
        self.markers = markers
        self.recordings = recordings
        self.events = events
        self.index = bool(index)
        self.manager: ReplayManager | None = None
        self.target: tuple[int, int] | None = None   # a seek's target and start line
        # seeks done: (perf_counter when the state reached the target, lines replayed)
        self.seeks: deque[tuple[float, int]] = deque(maxlen=1000)

    # -- which replay ----------------------------------------------------------------------------

    def playing(self) -> LineReplaySource | None:
        """The replay being played (the demo until a phone takes over), else None."""
        return self.source.played()

    @property
    def shown(self) -> ReplayManager | None:
        """The manager of the replay being played (None while none plays)."""
        return self.manager if self.playing() is not None else None

    @property
    def seeking(self) -> bool:
        """A seek re-runs the lines up to its target (its rows were not shown)."""
        return self.target is not None

    def info(self, replay: dict[str, Any] | None) -> dict[str, Any] | None:
        """Snapshot.replay: the source's replay info with the timeline's and the index's."""
        manager = self.shown
        if replay is not None and manager is not None:
            return {**replay, **manager.info()}
        return replay

    # -- passes ----------------------------------------------------------------------------------

    def connected(self) -> None:
        """A stream starts: a replay's first pass, or a phone took over (no replay any more)."""
        source = self.playing()
        if source is None:
            self.off()
            self.pipeline.restart()
            return
        self._begin_pass(source)
        if getattr(source, "torn_lines", 0):
            self.pipeline.count_damaged("torn last line (the recording was cut off)",
                                        "torn last line")

    def restarted(self, kind: str) -> None:
        """A loop or a source's own seek: every pass of a replay starts from the same state
        (each loop shows the same estimates, a seek re-runs its lines from the start)."""
        source = self.playing()
        if source is not None:
            self._begin_pass(source)
        else:
            self.pipeline.restart(continue_time=kind == "loop")

    def _begin_pass(self, source: LineReplaySource) -> None:
        manager = self.manager
        if manager is None or manager.source is not source:
            if manager is not None:
                manager.stop()
            pipeline = self.pipeline
            session = self.session if self._session_matches(source) else None
            manager = self.manager = ReplayManager(
                source, self.configuration, session,
                {"limits": pipeline.limits, "orderer_options": pipeline.orderer_options},
                index=self.index)
            self.markers.replace(manager.markers)
        pipeline = self.pipeline
        before = Config.of(pipeline.runner)
        checkpoint = manager.begin(pipeline)
        pipeline.restore(checkpoint)
        if self.recordings.active:
            # the pass starts with the configuration of its start: the recording keeps the
            # changes from where the previous pass ended
            for change in before.changes_to(Config.of(pipeline.runner), 0):
                self.recordings.event(change.kind, **change.event_data())
        pipeline.continue_with(manager.setup.timeline)
        self.events.new_pass()

    def _session_matches(self, source: LineReplaySource) -> bool:
        session = self.session
        path = getattr(source, "path", None)
        return session is not None and path is not None and \
            Path(session.path).parent == Path(path).parent

    def off(self) -> None:
        """A phone took over from the demo: no replay any more; the configuration goes on
        from what runs now."""
        if self.manager is not None:
            self.manager.stop()
            self.manager = None
            self.markers.replace([])
        if self.configuration.replaying:
            self.configuration.go_live(Config.of(self.pipeline.runner))
            self.pipeline.use_timeline(self.configuration.changes())

    def stop(self) -> None:
        if self.manager is not None:
            self.manager.stop()

    # -- seeks -----------------------------------------------------------------------------------

    def seek(self, target: int) -> bool:
        """Go to line `target` of the replay: restore the latest checkpoint before it, replay
        the lines from there (at most a second of them once indexed). False: not a replay."""
        source, manager = self.playing(), self.manager
        if source is None or manager is None:
            return False
        target = max(0, min(int(target), source.line_count))
        checkpoint = manager.checkpoint_before(target)
        self.events.new_pass()
        self.pipeline.cut()
        manager.apply(self.pipeline, checkpoint)
        source.jump(checkpoint.line, target)
        self.events.jumped()            # YOURS re-runs the log up to here in the background
        self.target = (target, checkpoint.line)
        self.recordings.unwatch()        # the lines up to the target were not watched
        if checkpoint.line >= target:
            self._done()
        return True

    def fed(self) -> None:
        """After lines were fed (and nothing read waits): is a seek's target reached?"""
        source = self.playing()
        if self.target is not None and source is not None and \
                source.lines_out >= self.target[0]:
            self._done()

    def _done(self) -> None:
        """A seek reached its target: (when, lines replayed) for the benchmarks."""
        target, start = self.target
        self.seeks.append((time.perf_counter(), target - start))
        self.pipeline.flush_output()     # the re-sync: plotted, not recorded
        self.target = None
        self.recordings.watch()

    def tick(self) -> None:
        """Once a pass: the index of a changed set-up is ready: be where it says at the current
        line (not while a recording runs)."""
        if self.manager is not None and self.manager.poll(hold=self.recordings.active):
            source = self.playing()
            if source is not None:
                self.seek(source.line_index)

    # -- the configuration -------------------------------------------------------------------------

    def change(self, change: Change) -> None:
        """A user's change of the configuration (see the module docstring): a replay's override
        of its kind, else a change from the current sample on."""
        configuration, pipeline = self.configuration, self.pipeline
        replaying = self.playing() is not None
        kind = change.kind_overridden
        if kind == "comparisons" and change.name is None:      # None: the one running now
            change = dataclasses.replace(change, name=pipeline.runner.comparison_estimator)
        if replaying and kind is not None and not self.recordings.active:
            configuration.override(kind, change.value)
            self._follow_configuration(resync=True)
            return
        configuration.add(change.at(pipeline.fed))
        pipeline.use_timeline(configuration.changes())     # applies it now, recorded
        if replaying and self.manager is not None:
            self.manager.refresh(pipeline, resync=False)

    def set_follow(self, enabled: bool) -> None:
        """SetFollowTimeline: back to the recording (True), or every kind yours at the values
        running now (False)."""
        configuration = self.configuration
        if self.manager is None or self.playing() is None or not configuration.recorded:
            self.events.say("timeline", "only a recorded session has a timeline to follow")
            return
        if self.recordings.active:
            self.events.say("timeline", "stop the recording first: it keeps what plays, "
                                        "in one piece")
            return
        if enabled:
            if not configuration.follow_recording():
                return
        else:
            configuration.override_all(configuration.at(self.pipeline.fed))
        self._follow_configuration(resync=True)

    def _follow_configuration(self, resync: bool) -> None:
        """The configuration changed for the whole replay: what runs now follows it at once,
        the index is built again and the engine re-synchronises once it is ready."""
        configuration, pipeline = self.configuration, self.pipeline
        now = configuration.at(pipeline.fed)
        for change in Config.of(pipeline.runner).changes_to(now, pipeline.fed):
            pipeline.apply_change(change)
        pipeline.use_timeline(configuration.changes())
        if self.manager is not None:
            self.manager.refresh(pipeline, resync)
        self.events.say("timeline", f"replay: {configuration.summary()}"
                        + (" (re-computing it)" if resync else ""))

    def control(self, command: ReplayControl) -> bool:
        """ReplayControl: the seeks here (from a checkpoint; not while recording), the rest by
        the source."""
        source = self.playing()
        if source is None or self.manager is None:
            self.source.control(command)
            return False
        target = command.seek_line
        if command.seek_s is not None:
            target = source.line_at(command.seek_s)
        step = command.step or 0
        if step < 0:
            target = max(0, source.line_index + step)
        rest = dataclasses.replace(command, seek_s=None, seek_line=None,
                                   step=step if step > 0 else None)
        if target is not None and self.recordings.active:
            self.events.say("seek", "stop the recording to jump: it keeps what plays, in one "
                                    "piece")
            target = None
        moved = target is not None and self.seek(target)
        source.control(rest)
        return moved
