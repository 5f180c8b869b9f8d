"""The engine's command table: each command type and its handler(engine, command), which
returns True when the command moved a replay (a seek: what was read before is dropped). A
command is looked up along its class's bases, so a subclass is handled as its base."""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable
from typing import Any

from app.engine.commands import (AddMarker, AlignHeading, LoadUserFilter, ReplayControl,
                                 ResetFilter, SetConsistencyEnabled, SetFollowTimeline,
                                 SetForward, SetMarkerLabel, StartRecording, StopRecording,
                                 UnloadUserFilter)
from app.engine.filter_commands import SETUP_HANDLERS, SetupContext
from app.stream.events import CONNECTION_COMMANDS

Handler = Callable[[Any, Any], bool]


@dataclasses.dataclass(frozen=True)
class Mark:
    """wait_idle's command: set when the engine reaches it."""

    event: threading.Event


def _setup(engine: Any, command: Any) -> bool:
    """A sensor switch, estimator, settings or comparisons command (refused: nothing changes)."""
    context = SetupContext(engine._runner, engine._record_event,
                           lambda text: engine._health.warn("command", text, force=True),
                           engine.recording, engine.pipeline.fed_total)
    if not SETUP_HANDLERS[type(command)](context, command):
        return False
    return engine._setup_changed()


def _align_heading(engine: Any, command: AlignHeading) -> bool:
    turned = engine._runner.align_heading()
    if turned is None:
        engine._health.warn("align", "align heading: no PHONE orientation (ORI) yet",
                            force=True)
    else:
        engine._record_event("align_heading", turned_deg=round(turned, 2))
        engine._health.warn("align", f"heading aligned with PHONE: OWN turned by "
                                     f"{turned:+.1f}° about up", force=True)
    return False


def _reset(engine: Any, command: ResetFilter) -> None:
    engine._runner.reset()
    engine._record_event("reset")


def _never_moves(action: Callable[[Any, Any], None]) -> Handler:
    """The handler of a command that never moves a replay."""
    def handler(engine: Any, command: Any) -> bool:
        action(engine, command)
        return False
    return handler


TABLE: dict[type, Handler] = {
    ReplayControl: lambda engine, command: engine._replay_control(command),
    **{kind: _setup for kind in SETUP_HANDLERS},
    ResetFilter: _never_moves(_reset),
    AlignHeading: _align_heading,
    StartRecording: _never_moves(lambda engine, command: engine._start_recording(command)),
    StopRecording: _never_moves(lambda engine, _: engine._stop_recording()),
    AddMarker: _never_moves(lambda engine, command: engine._add_marker(command.label)),
    SetMarkerLabel: _never_moves(
        lambda engine, command: engine._set_marker_label(command.id, command.label)),
    SetFollowTimeline: lambda engine, command: engine._set_follow(command.enabled),
    **{kind: _never_moves(lambda engine, command: engine.source.control(command))
       for kind in CONNECTION_COMMANDS},
    LoadUserFilter: _never_moves(lambda engine, command: engine._user.load(command.path)),
    UnloadUserFilter: _never_moves(lambda engine, _: engine._user.unload()),
    SetConsistencyEnabled: _never_moves(
        lambda engine, command: engine._runner.set_consistency_enabled(command.enabled)),
    SetForward: _never_moves(lambda engine, command: engine._set_forward(command.target)),
    Mark: _never_moves(lambda engine, command: engine._marks.append(command.event)),
}


def handler_of(command: Any) -> Handler | None:
    """The handler of `command`'s type or of its nearest base in the table; None if none."""
    for kind in type(command).__mro__:
        handler = TABLE.get(kind)
        if handler is not None:
            return handler
    return None
