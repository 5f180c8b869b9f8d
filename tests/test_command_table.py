"""The engine's command table: every command has a handler, an unknown one is reported."""

from __future__ import annotations

import dataclasses
import inspect

from app.engine import commands
from app.engine.live.worker import TABLE, handler_of
from app.engine.live.worker import Engine
from app.stream import events
from app.stream.sources import SimulatorSource
from waiting import wait_until


def _command_types():
    own = [kind for _, kind in inspect.getmembers(commands, inspect.isclass)
           if kind.__module__ == commands.__name__ and dataclasses.is_dataclass(kind)]
    return own + list(events.CONNECTION_COMMANDS) + [events.ReplayControl]


def test_every_command_type_has_a_handler():
    missing = [kind.__name__ for kind in _command_types() if kind not in TABLE]
    assert missing == []


def test_a_subclass_is_handled_as_its_base_and_a_stranger_has_no_handler():
    class Later(commands.ResetFilter):
        pass

    assert handler_of(Later()) is TABLE[commands.ResetFilter]
    assert handler_of(object()) is None


def test_an_unknown_command_is_reported_and_the_engine_runs_on():
    engine = Engine(SimulatorSource(duration_s=5.0, speed=0, loop=False), comparisons=False)
    with engine:
        engine.send("not a command")
        engine.send(commands.SetSensorEnabled("gyr", False))
        wait_until(lambda: any("unknown command 'not a command'" in text
                               for text in engine.snapshot_now().health.warnings),
                   timeout=60, what="the unknown command reported")
        assert engine.wait_idle(60)
        assert engine.running
        assert engine.snapshot_now().status.sensors_enabled["gyr"] is False
