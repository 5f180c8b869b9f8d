"""Forwarding the phone's lines to another receiver (``--forward``, the window's Forward menu):
switching it on, over or off, as the engine's SetForward command does (:class:`Forward` holds
the one the engine runs)."""

from __future__ import annotations

import threading

from app.engine.config import ConfigError, forward_target
from app.stream.forwarder import LineForwarder


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
