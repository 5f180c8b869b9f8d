"""Your filter's process from the engine's side: start it, send it requests without ever waiting,
take its replies when they are there, notice when it is stuck or gone, and end it with whatever
it started.

:class:`FilterProcess` knows nothing of filters: it runs a command that speaks
app.engine.userfilter.protocol on its stdin (requests) and stdout (replies), and captures its
stderr (what the filter prints). Three threads of its own do the blocking I/O: a writer with an
unbounded queue (the sender bounds what it sends), a reader of replies and a reader of the
output; the caller's thread only appends to the queue and takes what the reader collected. The
Python host is ``python -m app.engine.userfilter.child`` (:func:`python_command`); an Octave
host is another command behind the same class.

Stuck: every request is answered by one reply; while a reply is owed and the child has sent
nothing (no reply, no progress frame) for a while, the child is inside one call of the user's
code (:meth:`FilterProcess.quiet_s`). :meth:`FilterProcess.ask_where` asks a POSIX child for its
stack (SIGUSR1, faulthandler), which arrives in :attr:`FilterProcess.stack`.

Ended: :meth:`FilterProcess.ended` gives the exit status (negative: the signal) once the replies
written before the end have been read. On POSIX the child leads a session of its own, and
:meth:`FilterProcess.close` kills that whole process group, so a filter that forks leaves nothing
behind and nothing waits for what it started.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any, Callable

import numpy as np

from app.engine.userfilter.protocol import FrameReader, ProtocolError, encode

POSIX = os.name == "posix"
MAX_OUTPUT_LINES = 200           # kept for the window's dock
MAX_LINE_CHARS = 1000
ENDED_GRACE_S = 0.5              # after the exit: replies still in the pipe are read first
_DUMP_START = re.compile(r"^(Stack|(Current thread|Thread) 0x[0-9a-fA-F]+)\s*"
                         r"\(most recent call first\):")
_DUMP_FRAME = re.compile(r'^  File "(.*)", line (\d+) in (.*)$')


def python_command() -> tuple[list[str], dict[str, str]]:
    """The Python host's command line and environment (this interpreter, this package on its
    path, unbuffered)."""
    root = str(Path(__file__).resolve().parents[3])
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in env.get("PYTHONPATH", "").split(
        os.pathsep) if p])
    env["PYTHONUNBUFFERED"] = "1"
    return [sys.executable, "-m", "app.engine.userfilter.child"], env


class FilterProcess:
    """A child speaking the frame protocol. on_output(line) gets each line it prints (in its
    output thread)."""

    def __init__(self, argv: list[str], env: dict[str, str] | None = None,
                 on_output: Callable[[str], None] | None = None) -> None:
        self.on_output = on_output
        self._lock = threading.Lock()
        self.changed = threading.Condition(self._lock)
        self._outgoing: deque[bytes] = deque()
        self._replies: deque[tuple[dict, dict[str, np.ndarray]]] = deque()
        self._owed: deque[str] = deque()
        self._quiet_since = time.monotonic()
        self._replies_closed = False
        self._exit_seen: float | None = None
        self._closing = False
        self.output: deque[str] = deque(maxlen=MAX_OUTPUT_LINES)
        self._partial_text = b""
        self.lines_total = 0
        self.stack: list[tuple[str, int, str]] | None = None
        self.error = ""                      # a protocol error: the child is not usable
        self.progress = 0                    # rows done of the request in progress (progress)
        self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, bufsize=0, env=env,
                                     start_new_session=POSIX, close_fds=True)
        self.pid = self.proc.pid
        self._threads = [threading.Thread(target=target, name=f"your filter {what} {self.pid}",
                                          daemon=True)
                         for target, what in ((self._write, "writer"), (self._read, "replies"),
                                              (self._read_output, "output"))]
        for thread in self._threads:
            thread.start()

    # -- sending (never waits) -----------------------------------------------------------------

    def request(self, header: dict[str, Any], arrays: dict[str, np.ndarray] | None = None) -> None:
        """Queue a request; its reply comes later (:meth:`take`)."""
        data = encode(header, arrays)
        with self.changed:
            if not self._owed:
                self._quiet_since = time.monotonic()
            self._owed.append(str(header["op"]))
            self._outgoing.append(data)
            self.changed.notify_all()

    def _write(self) -> None:
        fd = self.proc.stdin.fileno()
        while True:
            with self.changed:
                while not self._outgoing and not self._closing:
                    self.changed.wait()
                if self._closing:
                    return
                data = self._outgoing.popleft()
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view):]
            except OSError:          # the child is gone: its end is noticed by the readers
                return

    # -- receiving -----------------------------------------------------------------------------

    def _read(self) -> None:
        reader = FrameReader()
        fd = self.proc.stdout.fileno()
        try:
            while True:
                data = os.read(fd, 1 << 16)
                if not data:
                    break
                for item in reader.feed(data):
                    if item[0] == "text":
                        self._output_text(item[1])
                        continue
                    _, header, arrays = item
                    with self.changed:
                        self._quiet_since = time.monotonic()
                        if header.get("op") == "progress":
                            self.progress = int(header.get("done", 0))
                        else:
                            self.progress = 0
                            if self._owed:
                                self._owed.popleft()
                            self._replies.append((header, arrays))
                        self.changed.notify_all()
            self._output_text(reader.pending_text(), end=True)
        except ProtocolError as error:
            self.error = f"your filter's process spoke garbage: {error}"
        except (OSError, ValueError):
            pass
        finally:
            with self.changed:
                self._replies_closed = True
                self.changed.notify_all()

    def _read_output(self) -> None:
        fd = self.proc.stderr.fileno()
        partial = b""
        try:
            while True:
                data = os.read(fd, 1 << 16)
                if not data:
                    break
                *lines, partial = (partial + data).split(b"\n")
                for line in lines:
                    self._line(line)
                if len(partial) > MAX_LINE_CHARS * 4:
                    self._line(partial)
                    partial = b""
        except (OSError, ValueError):
            pass
        if partial:
            self._line(partial)

    def _output_text(self, data: bytes, end: bool = False) -> None:
        """Text between frames (an Octave host's prints): whole lines, however the pipe cut
        them (the rest of a line waits for its end, or for the end of the stream)."""
        *lines, self._partial_text = (self._partial_text + data).split(b"\n")
        if end and self._partial_text:
            lines.append(self._partial_text)
            self._partial_text = b""
        for line in lines:
            self._line(line)

    _in_dump = False

    def _line(self, raw: bytes) -> None:
        line = raw.decode("utf-8", errors="replace").rstrip("\r")
        if _DUMP_START.match(line):
            self._in_dump = True
            self._dump: list[tuple[str, int, str]] = []
            return
        if self._in_dump:
            frame = _DUMP_FRAME.match(line)
            if frame:
                self._dump.append((frame.group(1), int(frame.group(2)), frame.group(3)))
                with self.changed:
                    self.stack = list(self._dump)
                    self.changed.notify_all()
                return
            self._in_dump = False
            if not line.strip():
                return
        if len(line) > MAX_LINE_CHARS:
            line = line[:MAX_LINE_CHARS - 1] + "…"
        self.output.append(line)
        self.lines_total += 1
        if self.on_output is not None:
            self.on_output(line)

    def take(self) -> list[tuple[dict, dict[str, np.ndarray]]]:
        """The replies that arrived since the previous call, in order."""
        with self._lock:
            replies = list(self._replies)
            self._replies.clear()
        return replies

    def wait(self, timeout: float) -> None:
        """Wait (at most timeout) for a reply, a progress frame or the end of the replies."""
        with self.changed:
            if not self._replies and not self._replies_closed:
                self.changed.wait(timeout)

    # -- how it is doing ------------------------------------------------------------------------

    @property
    def owed(self) -> int:
        """Replies owed."""
        return len(self._owed)

    @property
    def owed_op(self) -> str | None:
        """The request the child is working on (the oldest one not answered)."""
        owed = self._owed
        return owed[0] if owed else None

    def quiet_s(self) -> float:
        """How long the child has sent nothing while it owes a reply (0: it owes none)."""
        with self._lock:
            return time.monotonic() - self._quiet_since if self._owed else 0.0

    def ended(self) -> int | None:
        """The child's exit status once it ended (negative: killed by that signal) and the
        replies it wrote before have been read; None while it runs."""
        code = self.proc.poll()
        if code is None:
            return None
        now = time.monotonic()
        if self._exit_seen is None:
            self._exit_seen = now
        if not self._replies_closed and now - self._exit_seen < ENDED_GRACE_S:
            return None
        return code

    def ask_where(self) -> bool:
        """Ask the child for the stack of its main thread (POSIX; it arrives in :attr:`stack`)."""
        if not hasattr(signal, "SIGUSR1") or self.proc.poll() is not None:
            return False
        try:
            os.kill(self.pid, signal.SIGUSR1)
        except OSError:
            return False
        return True

    # -- the end -----------------------------------------------------------------------------------

    def close(self, join_s: float = 2.0) -> None:
        """Kill the child and everything it started (its process group on POSIX), wait for it,
        stop the threads. Idempotent."""
        with self.changed:
            if self._closing:
                return
            self._closing = True
            self.changed.notify_all()
        try:
            if POSIX:
                os.killpg(self.pid, signal.SIGKILL)
            else:
                self.proc.kill()
        except OSError:
            pass
        try:
            self.proc.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            pass
        deadline = time.monotonic() + join_s
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))
        for stream in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            alive = any(t.is_alive() for t in self._threads)
            if stream is not None and not alive:
                try:
                    stream.close()
                except OSError:
                    pass

    @property
    def closed(self) -> bool:
        return self._closing
