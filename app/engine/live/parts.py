"""The engine's parts as one typed bundle, and the snapshot composed from them.

:class:`Engine <app.engine.live.worker.Engine>` makes each part once and hands them, through
:class:`EngineParts`, to the code that works on several of them: the command handlers
(:func:`app.engine.live.worker.handler_of`) and :func:`engine_snapshot`. Each part owns its
state: the processing (:class:`~app.engine.processing.pipeline.Pipeline`, whose runner runs the
filters), the configuration over time
(:class:`~app.engine.processing.configuration.Configuration`), the replay lane, the recording
lane, the markers, your filter's host, the stream's health, the publisher and the output, the
connection (:class:`Connection`), the forward (:class:`Forward`) and the failures. Nothing
outside the engine's own module reads the engine's private attributes.

Forwarding the phone's lines to another receiver (``--forward``, the window's Forward menu):
:class:`Forward` holds the one the engine runs and switches it on, over or off, as the engine's
SetForward command does.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.engine.config import ConfigError, forward_target
from app.engine.errors import FailureLog
from app.engine.live.publisher import EngineOutput, Publisher
from app.engine.processing.configuration import Configuration
from app.engine.processing.health import HealthTracker
from app.engine.processing.pipeline import Pipeline
from app.engine.sessions.recording import RecordingLane
from app.engine.sessions.replay import ReplayLane
from app.engine.sessions.session import Markers
from app.engine.snapshot import Comparison, FilterStatus, Snapshot, StreamHealth
from app.engine.userfilter.host import UserFilterHost
from app.stream.forwarder import LineForwarder
from app.stream.sources import Source


@dataclass
class Connection:
    """The stream's connection as the engine last saw it: "waiting", "connected",
    "disconnected", "replaying", "finished" or "stopped", and the phone's address."""

    state: str = "waiting"
    peer: str | None = None


@dataclass(frozen=True)
class EngineParts:
    """Every part of one engine, by name (see the module docstring)."""

    source: Source
    pipeline: Pipeline
    configuration: Configuration
    replay: ReplayLane
    recordings: RecordingLane
    markers: Markers
    user: UserFilterHost
    health: HealthTracker
    publisher: Publisher
    output: EngineOutput
    connection: Connection
    forward: Forward
    failures: FailureLog

    def say(self, topic: str, text: str) -> None:
        """One line for the status bar, now."""
        self.health.warn(topic, text, force=True)


def engine_snapshot(parts: EngineParts, now: float, preparing: bool = False) -> Snapshot:
    """What the engine shows now (`now`: perf_counter, for the rates): its main estimate,
    lights, comparisons, stream health, replay, configuration, failures, markers, your filter,
    recording; preparing: the kernels are being compiled or loaded."""
    pipeline = parts.pipeline
    runner, replays = pipeline.runner, parts.replay
    info = parts.source.info()
    manager = replays.shown
    main, cov, phone = runner.main, runner.main.cov, runner.phone_quat
    rows = [Comparison(c.name, c.estimator.quat, tuple(c.errors.rmse().tolist()),
                       tuple(c.errors.latest.tolist()), c.errors.count)
            for c in runner.comparisons]
    yours = parts.user.comparison_row()
    if yours is not None:
        rows.append(yours)
    status = FilterStatus(sensors_enabled=main.enabled, flags=main.flags,
                          diagnostics=main.diagnostics, estimator=runner.estimator_name,
                          initialised=main.initialised, settings=runner.settings)
    return Snapshot(
        t_ms=runner.latest_t_ms, own_quat=main.quat,
        own_cov=None if cov is None else np.array(cov)[:4, :4],
        phone_quat=None if phone is None else np.array(phone), status=status,
        comparisons=rows, comparison_estimator=runner.comparison_estimator,
        t0_ms=pipeline.t0_ms, health=stream_health(parts, now, info),
        replay=replays.info(info.get("replay")), failures=list(parts.failures.items),
        markers=tuple(parts.markers.items), preparing=preparing,
        user=parts.user.status(), recording=parts.recordings.status(),
        session_plot=manager.plot if manager is not None else None,
        session_samples=runner.session_samples,
        configuration=parts.configuration.view(pipeline.fed))


def stream_health(parts: EngineParts, now: float, info: dict[str, Any]) -> StreamHealth:
    """The stream's health: the source's `info`, the parser's and the orderer's counts, the
    connection, the recording and the forward."""
    state = info.get("connection_state", "waiting")
    connection = parts.connection
    if parts.source.capabilities.reconnect:
        state = connection.state if state != "waiting" else "waiting"
    pipeline = parts.pipeline
    health = parts.health.health(now, info, pipeline.parser, pipeline.orderer,
                                 pipeline.order_retired, state, connection.peer,
                                 parts.recordings.text())
    forwarder = parts.forward.current
    if forwarder is not None:
        health.forward = forwarder.status()
    return health


def switch_forward(current: LineForwarder | None, target: str | None,
                   live: bool) -> tuple[LineForwarder | None, str, bool]:
    """Stop `current` (never waiting for its thread, which may be inside a send of up to 5 s)
    and start a forward to `target` ("HOST:PORT"; None: none). Returns (the forwarder now,
    the status line, whether it changed: a bad target changes nothing). live: the source is
    the phone (otherwise there is nothing to forward yet, and the line says so)."""
    try:
        address = forward_target(target) if target else None
    except ConfigError as error:
        return current, (f"forward to {target!r}: "
                         f"{str(error).replace('--forward: ', '')}"), False
    if current is not None:
        threading.Thread(target=current.stop, name="forward-stop", daemon=True).start()
    if address is None:
        return None, "forwarding stopped", True
    forwarder = LineForwarder(*address)
    forwarder.start()
    note = "" if live else " (the phone's lines only: nothing to forward while not streaming " \
                           "live)"
    return forwarder, f"forwarding the phone's lines to {address[0]}:{address[1]}{note}", True


class Forward:
    """The forward the engine runs: :attr:`current` (None: none)."""

    def __init__(self, current: LineForwarder | None = None) -> None:
        self.current = current

    def switch(self, target: str | None, live: bool) -> tuple[str, bool]:
        """SetForward: see :func:`switch_forward`; (the status line, whether it changed)."""
        self.current, line, changed = switch_forward(self.current, target, live)
        return line, changed

    def target(self) -> str | None:
        """"HOST:PORT" of the running forward (None: none)."""
        current = self.current
        return None if current is None else f"{current.host}:{current.port}"
