"""The engine's command table: each command type and its handler(parts, command), which
returns True when the command moved a replay (a seek: what was read before is dropped). A
command is looked up along its class's bases, so a subclass is handled as its base.

A handler works on the engine's parts (:class:`~app.engine.parts.EngineParts`) and hands its
command to the part it is for: the configuration (set-up changes, through the replay lane,
which makes them overrides or changes at the current sample), the replay lane (seeks, back to
the recording), the recording lane, the markers, your filter's host, the source (connection
commands) or the forward."""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable
from typing import Any

from app.engine.commands import (AddMarker, LoadUserFilter, ReplayControl,
                                 SetConsistencyEnabled, SetFollowTimeline, SetForward,
                                 SetMarkerLabel, StartRecording, StopRecording, UnloadUserFilter)
from app.engine.filter_commands import SETUP_CHANGES
from app.engine.parts import EngineParts
from app.stream.events import CONNECTION_COMMANDS

Handler = Callable[[EngineParts, Any], bool]


@dataclasses.dataclass(frozen=True)
class Mark:
    """wait_idle's command: set when the engine reaches it."""

    event: threading.Event


def _setup(parts: EngineParts, command: Any) -> bool:
    """A set-up command: a change of the configuration (refused: nothing changes)."""
    change = SETUP_CHANGES[type(command)](command, lambda text: parts.say("command", text))
    if change is not None:
        parts.replay.change(change)
    return False


def _start_recording(parts: EngineParts, command: StartRecording) -> None:
    live = parts.source.capabilities.reconnect
    parts.recordings.start(command, parts.source.kind, parts.connection.peer if live else None,
                           parts.output.flush)


def _stop_recording(parts: EngineParts, command: StopRecording) -> None:
    parts.recordings.stop(parts.output.flush, parts.publisher.latest.health)


def _add_marker(parts: EngineParts, command: AddMarker) -> None:
    pipeline = parts.pipeline
    note = parts.markers.add(command.label, pipeline.runner.latest_t_ms, pipeline.t0_ms,
                             parts.recordings.current, parts.replay.shown, pipeline.fed_total)
    parts.say("marker", note)


def _set_marker_label(parts: EngineParts, command: SetMarkerLabel) -> None:
    note = parts.markers.set_label(command.id, command.label, parts.recordings.current,
                                   parts.replay.shown)
    if note and "(" in note:
        parts.say("markers", note.strip(" ()"))


def _set_forward(parts: EngineParts, command: SetForward) -> None:
    """Stop the running forward (if any), start one to the command's target (if given)."""
    line, changed = parts.forward.switch(command.target, parts.source.capabilities.forward)
    parts.say("forward", line)
    if changed:
        parts.recordings.event("forward", target=parts.forward.target())


def _never_moves(action: Callable[[EngineParts, Any], None]) -> Handler:
    """The handler of a command that never moves a replay."""
    def handler(parts: EngineParts, command: Any) -> bool:
        action(parts, command)
        return False
    return handler


TABLE: dict[type, Handler] = {
    ReplayControl: lambda parts, command: parts.replay.control(command),
    **{kind: _setup for kind in SETUP_CHANGES},
    StartRecording: _never_moves(_start_recording),
    StopRecording: _never_moves(_stop_recording),
    AddMarker: _never_moves(_add_marker),
    SetMarkerLabel: _never_moves(_set_marker_label),
    SetFollowTimeline: _never_moves(
        lambda parts, command: parts.replay.set_follow(command.enabled)),
    **{kind: _never_moves(lambda parts, command: parts.source.control(command))
       for kind in CONNECTION_COMMANDS},
    LoadUserFilter: _never_moves(lambda parts, command: parts.user.load(command.path)),
    UnloadUserFilter: _never_moves(lambda parts, _: parts.user.unload()),
    SetConsistencyEnabled: _never_moves(
        lambda parts, command: parts.pipeline.runner.set_consistency_enabled(command.enabled)),
    SetForward: _never_moves(_set_forward),
    Mark: _never_moves(lambda parts, command: parts.publisher.add_mark(command.event)),
}


def handler_of(command: Any) -> Handler | None:
    """The handler of `command`'s type or of its nearest base in the table; None if none."""
    for kind in type(command).__mro__:
        handler = TABLE.get(kind)
        if handler is not None:
            return handler
    return None
