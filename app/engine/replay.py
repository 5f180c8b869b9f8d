"""The engine's side of a replay: its passes, its index, its markers.

A replay pass always starts from the same state (the initial checkpoint of the set-up the
engine's configuration resolves to, :mod:`app.engine.configuration`): at the start, at every
loop (each pass shows the same estimates) and as the base of every seek. For a recorded session
the set-up is the recorded one (the estimator, sensors and settings at the recording's start,
the recorded switches and changes at their sample positions, and the live engine's state when
the recording started mid-stream) with the user's overrides, one kind each; for a phone's own
log it is the engine's own set-up with the user's overrides.

When the configuration changes while replaying, the index is built again for the new set-up
and, for an override (a change of the whole pass), the engine re-synchronises at its current
position once the index is complete: a replay's estimates are always those of its
configuration (a seek anywhere then gives what playing there gives).
"""

from __future__ import annotations

import logging
import time
from typing import Any

from app.engine.checkpoints import Checkpoint
from app.engine.configuration import Configuration, Setup
from app.engine.pipeline import Pipeline
from app.engine.session import Marker, SessionInfo, read_session, session_json_for, write_markers
from app.engine.session_index import SessionIndex, SessionPlot
from app.stream.sources import Source

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
