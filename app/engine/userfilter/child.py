"""Your filter's own process: ``python -m app.engine.userfilter.child``, started by the engine
(app.engine.userfilter.process), speaking app.engine.userfilter.protocol.

Its stdin brings the requests and its stdout takes the replies; before anything of the user's
runs, both are moved to other descriptors, descriptor 0 becomes the null device and ``sys.stdin``
an object that says a filter has no keyboard, and descriptors 1 and 2 both go to the engine's
capture of what the filter prints. So ``print`` goes to the window's log and dock (or stderr on
the command line), ``input()`` fails at once with a message in the user's terms, and
``os.close(1)`` only closes the user's own output.

A copy of this process made by ``os.fork()`` in the user's code ends (``os._exit(0)``) when it
comes back into this module instead of answering requests meant for the original; the requests
and replies are closed in such a copy as soon as it is made. When the engine's process goes
away, this one ends too (it checks its parent every second).

On POSIX, ``SIGUSR1`` makes it write the stack of its main thread to the captured output
(faulthandler): the engine asks for it when a call does not return, to say at which line.
"""

from __future__ import annotations

import faulthandler
import io
import os
import pickle
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from app.engine.userfilter.code import UserFilterError, load_code
from app.engine.userfilter.instance import FilterInstance
from app.engine.userfilter.protocol import (PROGRESS_S, FrameReader, ProtocolError, encode,
                                            problem_to_wire, settings_from_wire)

NO_KEYBOARD = ("a filter has no keyboard: input() and sys.stdin are not available while your "
               "filter runs (it runs in a process of its own); give it values in the file or "
               "in settings")
_PID = os.getpid()


class NoKeyboard(io.TextIOBase):
    """sys.stdin of your filter's process: reading says why there is nothing to read."""

    def readable(self) -> bool:
        return True

    def read(self, size: int = -1) -> str:
        raise EOFError(NO_KEYBOARD)

    def readline(self, size: int = -1) -> str:   # type: ignore[override]
        raise EOFError(NO_KEYBOARD)

    def isatty(self) -> bool:
        return False

    def fileno(self) -> int:
        raise io.UnsupportedOperation(NO_KEYBOARD)


def _forked_copy() -> bool:
    return os.getpid() != _PID


class Child:
    """The request loop: one FilterInstance (after ``start``), replies in order."""

    def __init__(self, requests: int, replies: int) -> None:
        self.requests = requests
        self.replies = replies
        self.reader = FrameReader()
        self.pending: list[tuple] = []
        self.code = None
        self.instance: FilterInstance | None = None
        self.load_problem = None
        self.last_sent = time.monotonic()

    # -- the wire ----------------------------------------------------------------------------

    def send(self, header: dict[str, Any], arrays: dict | None = None) -> None:
        if _forked_copy():
            os._exit(0)
        data = memoryview(encode(header, arrays))
        while data:
            written = os.write(self.replies, data)
            data = data[written:]
        self.last_sent = time.monotonic()

    def receive(self) -> tuple[dict, dict] | None:
        """The next request (None: the engine closed the pipe)."""
        while not self.pending:
            data = os.read(self.requests, 1 << 16)
            if not data:
                return None
            for item in self.reader.feed(data):
                if item[0] == "frame":
                    self.pending.append(item[1:])
                else:
                    raise ProtocolError("text between requests")
        return self.pending.pop(0)

    def _heartbeat(self, done: int) -> None:
        if time.monotonic() - self.last_sent >= PROGRESS_S:
            self.send({"op": "progress", "done": done + 1})

    # -- requests ----------------------------------------------------------------------------

    def _state(self) -> dict[str, Any]:
        instance = self.instance
        problem = self.load_problem if instance is None else instance.problem
        return {"problem": problem_to_wire(problem),
                "missing": self.code.missing_steps() if self.code is not None else [],
                "notes": list(instance.notes) if instance is not None else []}

    def start(self, header: dict, arrays: dict) -> dict:
        from app.engine.userfilter import code as user_code
        user_code.LOAD_LIMIT_S = float(header.get("load_limit_s", user_code.LOAD_LIMIT_S))
        source = arrays["source"].tobytes()
        try:
            self.code = load_code(Path(header["path"]), source)
        except UserFilterError as error:
            self.load_problem = error.problem
        else:
            self.instance = FilterInstance(self.code, settings_from_wire(header["settings"]),
                                           float(header.get("step_limit_s", 1.0)))
        if _forked_copy():
            os._exit(0)
        return {"op": "start", **self._state()}

    def rows(self, header: dict, arrays: dict) -> tuple[dict, dict]:
        t = arrays["t"]
        if self.instance is None:
            n = len(t)
            return ({"op": "rows", "id": header["id"], "epoch": header["epoch"], "run": 0,
                     "seconds": 0.0, "paused_at": 0, "last_out": -1, **self._state()},
                    {"q": np.full((n, 4), np.nan), "flags": np.full((n, 3), -1, np.int8)})
        done = self.instance.run_block(t, arrays["given"], arrays["values"], self._heartbeat)
        if _forked_copy():
            os._exit(0)
        return ({"op": "rows", "id": header["id"], "epoch": header["epoch"], **done["header"],
                 **self._state()}, done["arrays"])

    def reset(self, header: dict) -> dict:
        if self.instance is not None:
            settings = header.get("settings")
            self.instance.restart(None if settings is None else settings_from_wire(settings),
                                  bool(header.get("fresh")))
            if _forked_copy():
                os._exit(0)
        return {"op": "reset", "epoch": header.get("epoch"), **self._state()}

    def snapshot(self) -> tuple[dict, dict]:
        if self.instance is None:
            return {"op": "snapshot", "error": "the file did not load"}, {}
        try:
            state = pickle.dumps(self.instance.state())
        except Exception as error:   # noqa: BLE001 (whatever the user's object holds)
            return {"op": "snapshot", "error": f"{type(error).__name__}: {error}"}, {}
        return {"op": "snapshot", "error": None}, {"state": np.frombuffer(state, np.uint8)}

    def restore(self, arrays: dict) -> dict:
        if self.instance is None:
            return {"op": "restore", "error": "the file did not load", **self._state()}
        try:
            self.instance.set_state(pickle.loads(arrays["state"].tobytes()))
        except Exception as error:   # noqa: BLE001 (the user's classes unpickle themselves)
            return {"op": "restore", "error": f"{type(error).__name__}: {error}",
                    **self._state()}
        return {"op": "restore", "error": None, **self._state()}

    def serve(self) -> None:
        while True:
            request = self.receive()
            if request is None:
                return
            header, arrays = request
            op = header.get("op")
            if op == "rows":
                self.send(*self.rows(header, arrays))
            elif op == "start":
                self.send(self.start(header, arrays))
            elif op == "reset":
                self.send(self.reset(header))
            elif op == "snapshot":
                self.send(*self.snapshot())
            elif op == "restore":
                self.send(self.restore(arrays))
            else:
                raise ProtocolError(f"unknown request {op!r}")


def _watch_parent(parent: int) -> None:
    while True:
        time.sleep(1.0)
        if os.getppid() != parent:
            os._exit(0)


def _text_stream(fd: int) -> io.TextIOWrapper:
    return io.TextIOWrapper(io.FileIO(fd, "w", closefd=False), encoding="utf-8",
                            errors="backslashreplace", line_buffering=True)


def main() -> None:
    requests, replies = os.dup(0), os.dup(1)
    os.set_inheritable(requests, False)
    os.set_inheritable(replies, False)
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    os.close(null)
    os.dup2(2, 1)
    sys.stdin = NoKeyboard()
    sys.stdout = _text_stream(1)
    sys.stderr = _text_stream(2)
    if hasattr(signal, "SIGUSR1"):
        stack_fd = os.dup(2)
        os.set_inheritable(stack_fd, False)
        faulthandler.register(signal.SIGUSR1, file=os.fdopen(stack_fd, "w"), all_threads=False)

    def forked() -> None:       # a copy made by the user's os.fork(): none of our pipes
        for fd in (requests, replies):
            try:
                os.close(fd)
            except OSError:
                pass

    if hasattr(os, "register_at_fork"):
        os.register_at_fork(after_in_child=forked)
    threading.Thread(target=_watch_parent, args=(os.getppid(),), name="parent watch",
                     daemon=True).start()
    status = 0
    try:
        Child(requests, replies).serve()
    except (BrokenPipeError, ProtocolError):
        pass
    except BaseException:       # noqa: BLE001 (ours: shown in the captured output)
        if not _forked_copy():
            import traceback
            traceback.print_exc()
        status = 1
    finally:
        if not _forked_copy():
            for stream in (sys.stdout, sys.stderr):
                try:
                    stream.flush()
                except (OSError, ValueError):
                    pass
    # not sys.exit: threads or atexit handlers of the user's code do not keep it alive
    os._exit(0 if _forked_copy() else status)


if __name__ == "__main__":
    main()
