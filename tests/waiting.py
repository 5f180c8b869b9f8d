"""Waiting in tests for something another thread does (the engine, a server, a recorder)."""

from __future__ import annotations

import socket
import time
from typing import Any, Callable, TypeVar

T = TypeVar("T")


def wait_until(condition: Callable[[], T], timeout: float = 30.0, what: str = "condition",
               poll_s: float = 0.02) -> T:
    """condition()'s first truthy value, polled every poll_s; AssertionError after timeout s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(poll_s)
    raise AssertionError(f"timed out waiting for {what}")


def wait_for_snapshot(engine, predicate: Callable[[Any], bool], timeout: float = 30.0,
                      what: str = "condition", describe: Callable[[Any], str] | None = None):
    """The engine's first snapshot for which predicate holds; AssertionError after timeout s
    (with describe(latest snapshot) in the message when given)."""
    def ready():
        snapshot = engine.snapshot_now()
        return snapshot if predicate(snapshot) else None
    try:
        return wait_until(ready, timeout, what)
    except AssertionError as error:
        if describe is None:
            raise
        raise AssertionError(f"{error}; {describe(engine.snapshot_now())}") from None


def wait_for_port(port: int, timeout: float = 20.0) -> None:
    """Until something accepts TCP connections on 127.0.0.1:port."""
    def listening() -> bool:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return True
        except OSError:
            return False
    wait_until(listening, timeout, f"a server listening on port {port}", poll_s=0.05)
