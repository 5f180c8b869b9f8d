"""The engine's command table: each command type and its handler(engine, command), which
returns True when the command moved a replay (a seek: what was read before is dropped). A
command is looked up along its class's bases, so a subclass is handled as its base.

A handler hands its command to the part of the engine it is for: the runner (set-up, reset,
heading), the replay lane (seeks, the recorded timeline), the recording lane, the markers, your
filter's host, the source (connection commands) or the forward."""

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
from app.engine.forwarding import switch_forward
from app.stream.events import CONNECTION_COMMANDS

Handler = Callable[[Any, Any], bool]


@dataclasses.dataclass(frozen=True)
class Mark:
    """wait_idle's command: set when the engine reaches it."""

    event: threading.Event


def _setup(engine: Any, command: Any) -> bool:
    """A sensor switch, estimator, settings or comparisons command (refused: nothing changes)."""
    context = SetupContext(engine._runner, engine.recording_lane.event,
                           lambda text: engine._health.warn("command", text, force=True),
                           engine.recording, engine.pipeline.fed_total)
    if not SETUP_HANDLERS[type(command)](context, command):
        return False
    return engine.replay_lane.setup_changed()


def _align_heading(engine: Any, command: AlignHeading) -> bool:
    turned = engine._runner.align_heading()
    if turned is None:
        engine._health.warn("align", "align heading: no PHONE orientation (ORI) yet",
                            force=True)
    else:
        engine.recording_lane.event("align_heading", turned_deg=round(turned, 2))
        engine._health.warn("align", f"heading aligned with PHONE: OWN turned by "
                                     f"{turned:+.1f}° about up", force=True)
    return False


def _reset(engine: Any, command: ResetFilter) -> None:
    engine._runner.reset()
    engine.recording_lane.event("reset")


def _start_recording(engine: Any, command: StartRecording) -> None:
    live = engine.source.capabilities.reconnect
    engine.recording_lane.start(command, engine.source.kind, engine._peer if live else None,
                                engine.output.flush)


def _stop_recording(engine: Any, command: StopRecording) -> None:
    if engine.recording_lane.stop(engine.output.flush, engine.publisher.latest.health):
        engine.replay_lane.recording_stopped()


def _add_marker(engine: Any, command: AddMarker) -> None:
    pipeline = engine.pipeline
    note = engine.markers.add(command.label, engine._runner.latest_t_ms, pipeline.t0_ms,
                              engine.recording, engine.replay_lane.shown, pipeline.fed_total)
    engine._health.warn("marker", note, force=True)


def _set_marker_label(engine: Any, command: SetMarkerLabel) -> None:
    note = engine.markers.set_label(command.id, command.label, engine.recording,
                                    engine.replay_lane.shown)
    if note and "(" in note:
        engine._health.warn("markers", note.strip(" ()"), force=True)


def _set_forward(engine: Any, command: SetForward) -> None:
    """Stop the running forward (if any), start one to the command's target (if given)."""
    engine.forwarder, line, changed = switch_forward(engine.forwarder, command.target,
                                                     engine.source.capabilities.forward)
    engine._health.warn("forward", line, force=True)
    if changed:
        forwarder = engine.forwarder
        engine.recording_lane.event("forward", target=None if forwarder is None else
                                    f"{forwarder.host}:{forwarder.port}")


def _never_moves(action: Callable[[Any, Any], None]) -> Handler:
    """The handler of a command that never moves a replay."""
    def handler(engine: Any, command: Any) -> bool:
        action(engine, command)
        return False
    return handler


TABLE: dict[type, Handler] = {
    ReplayControl: lambda engine, command: engine.replay_lane.control(command),
    **{kind: _setup for kind in SETUP_HANDLERS},
    ResetFilter: _never_moves(_reset),
    AlignHeading: _align_heading,
    StartRecording: _never_moves(_start_recording),
    StopRecording: _never_moves(_stop_recording),
    AddMarker: _never_moves(_add_marker),
    SetMarkerLabel: _never_moves(_set_marker_label),
    SetFollowTimeline: lambda engine, command: engine.replay_lane.set_follow(command.enabled),
    **{kind: _never_moves(lambda engine, command: engine.source.control(command))
       for kind in CONNECTION_COMMANDS},
    LoadUserFilter: _never_moves(lambda engine, command: engine._user.load(command.path)),
    UnloadUserFilter: _never_moves(lambda engine, _: engine._user.unload()),
    SetConsistencyEnabled: _never_moves(
        lambda engine, command: engine._runner.set_consistency_enabled(command.enabled)),
    SetForward: _never_moves(_set_forward),
    Mark: _never_moves(lambda engine, command: engine.publisher.add_mark(command.event)),
}


def handler_of(command: Any) -> Handler | None:
    """The handler of `command`'s type or of its nearest base in the table; None if none."""
    for kind in type(command).__mro__:
        handler = TABLE.get(kind)
        if handler is not None:
            return handler
    return None
