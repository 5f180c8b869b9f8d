"""The engine's replay lane: which replay plays, its passes, its seeks and its set-up changes.

Every pass of a replay starts from the same state (its :class:`~app.engine.replay.ReplayManager`
says which); a background index keeps a checkpoint every second of data, so a seek restores
the nearest one before its target and replays at most one second, plotted but neither recorded
nor counted as new estimates; a recorded session's timeline is applied at its sample positions.
A set-up change while replaying indexes the replay again and re-synchronises at the current
line once the index is complete; while a recording runs the change applies from then on, as on
a live stream, and the whole replay follows once the recording stops.
"""

from __future__ import annotations

import dataclasses
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from app.engine.commands import ReplayControl
from app.engine.health import HealthTracker
from app.engine.markers import Markers
from app.engine.pipeline import Pipeline
from app.engine.publisher import Publisher
from app.engine.recording_lane import RecordingLane
from app.engine.replay import ReplayManager
from app.engine.session import SessionInfo
from app.stream.sources import LineReplaySource, Source


class ReplayLane:
    """The replay of the engine's source (when it plays one). session: the replayed
    recording's session.json (None: none); index: build a replay's index in the background;
    output(rows, piece): hands a seek's re-sync to the engine's consumers; on_jump(): the engine
    drops what it read at the old position (a seek)."""

    def __init__(self, source: Source, pipeline: Pipeline, session: SessionInfo | None,
                 index: bool, markers: Markers, recordings: RecordingLane, user: Any,
                 health: HealthTracker, publisher: Publisher,
                 output: Callable[[Any, Any], None], on_jump: Callable[[], None]) -> None:
        self.source = source
        self.pipeline = pipeline
        self.session = session
        self.index = bool(index)
        self.markers = markers
        self.recordings = recordings
        self.user = user
        self._health = health
        self.publisher = publisher
        self._output = output
        self._on_jump = on_jump
        self.manager: ReplayManager | None = None
        self.target: tuple[int, int] | None = None   # a seek's target and start line
        # seeks done: (perf_counter when the state reached the target, lines replayed)
        self.seeks: deque[tuple[float, int]] = deque(maxlen=1000)
        self._setup_deferred = False     # a set-up change during a recording of a replay

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
            self.pipeline.parser._count_bad("damaged", "torn last line (the recording was "
                                            "cut off)", "torn last line")

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
                source, session, {"limits": pipeline.limits,
                                  "orderer_options": pipeline.orderer_options},
                index=self.index)
            self.markers.replace(manager.markers)
        manager.apply(self.pipeline, manager.begin(self.pipeline))
        self.publisher.forget_arrivals()

    def _session_matches(self, source: LineReplaySource) -> bool:
        session = self.session
        path = getattr(source, "path", None)
        return session is not None and path is not None and \
            Path(session.path).parent == Path(path).parent

    def off(self) -> None:
        """A phone took over from the demo: no replay any more."""
        if self.manager is not None:
            self.manager.stop()
            self.manager = None
            self.markers.replace([])

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
        self._on_jump()
        self.publisher.forget_arrivals()
        self.pipeline.cut()
        manager.apply(self.pipeline, checkpoint)
        source.jump(checkpoint.line, target)
        self.user.on_seek()              # YOURS re-runs the log up to here in the background
        self.target = (target, checkpoint.line)
        self.recordings.unwatch()        # the lines up to the target were not watched
        if checkpoint.line >= target:
            self._done()
        return True

    def fed(self) -> None:
        """After lines were fed (and nothing read waits): is a seek's target reached?"""
        if self.target is not None and getattr(self.playing(), "_index", -1) >= self.target[0]:
            self._done()

    def _done(self) -> None:
        """A seek reached its target: (when, lines replayed) for the benchmarks."""
        target, start = self.target
        self.seeks.append((time.perf_counter(), target - start))
        self._output(*self.pipeline.take_output())   # the re-sync: plotted, not recorded
        self.target = None
        self.recordings.watch()

    def tick(self) -> None:
        """Once a pass: the index of a changed set-up is ready: be where it says at the current
        line."""
        if self.manager is not None and self.manager.poll():
            source = self.playing()
            if source is not None:
                self.seek(source.line_index)

    # -- commands --------------------------------------------------------------------------------

    def setup_changed(self) -> bool:
        """The user chose another set-up while replaying (index again, re-sync once indexed).
        While a recording runs it applies from now on, as on a live stream, so the recording
        replays exactly what was shown; the whole replay follows once the recording stops."""
        manager = self.manager
        if manager is None or self.playing() is None:
            return False
        if self.recordings.active:
            self._setup_deferred = True
            return False
        if manager.changed(self.pipeline):
            self._health.warn("timeline", "recorded timeline off: your choices apply to the "
                                          "whole replay (re-computing it)", force=True)
        return False

    def recording_stopped(self) -> None:
        """A set-up change made while recording now applies to the whole replay."""
        if self._setup_deferred:
            self._setup_deferred = False
            self.setup_changed()

    def set_follow(self, enabled: bool) -> bool:
        """SetFollowTimeline."""
        manager = self.manager
        if manager is None or manager.session is None:
            self._health.warn("timeline", "only a recorded session has a timeline to follow",
                              force=True)
            return False
        manager.set_follow(self.pipeline, enabled)
        self._health.warn("timeline", "following the recorded timeline" if manager.follow
                          else "recorded timeline off: your choices apply to the whole replay",
                          force=True)
        return False

    def control(self, command: ReplayControl) -> bool:
        """ReplayControl: the seeks here (from a checkpoint), the rest by the source."""
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
        moved = target is not None and self.seek(target)
        source.control(rest)
        return moved
