"""Your MATLAB filter in a persistent GNU Octave, as the engine sees it: :class:`OctaveRemote`.

The same parent side as a Python filter's (app.engine.userfilter.remote: requests sent without
waiting, replies taken when they are there, the deadline, the end of the process), with Octave
as the process: ``octave-cli`` running the host in ``octave_host/`` on a private copy of the
folder (app.engine.userfilter.octave), speaking the same frames on its stdin and stdout. What
differs is said here: how the folder is read and hashed, where the copy lives and when it goes,
and the messages in MATLAB terms (Octave not installed, too old, stuck in the student's code,
ended).

Rows handed over while Octave works on a block, or within GATHER_S of the previous block, wait
and go together as the next block (one request, its reply split back into the blocks handed
over): Octave's cost per block (reading and writing a frame, the work after the loop, ~1-2 ms)
is paid at most 50 times a second rather than once per engine chunk, so a filter that keeps up
with the stream is never decimated for it.

Octave cannot tell where it is while it runs (no signal makes it print its stack), so a call
that does not return is named by the deadline alone: the row's time, not the line.
"""

from __future__ import annotations

import itertools
import math
import os
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ekf.settings import EKFSettings
from app.engine.errors import UserProblem
from app.engine.userfilter.code import UserFilterError
from app.engine.userfilter.octave import (MatlabFolder, OctaveNotFound, find_octave,
                                          is_matlab_filter, octave_command, private_copy)
from app.engine.userfilter.remote import BlockResult, RemoteFilter, exit_words

TOO_OLD = "OrientationLab:octaveTooOld"       # what the host prints before it exits (status 3)
GATHER_S = 0.02        # blocks handed over within this of the previous request go with the next
_blocks = itertools.count(-1, -1)      # the ids of blocks handed over (never a request id)


@dataclass
class _Held:
    """A block handed over and not sent yet (Octave is working on the previous one)."""

    block: int
    t_s: np.ndarray
    given: np.ndarray
    values: np.ndarray
    epoch: int
    at: float
    innovations: bool


@dataclass
class _Part:
    block: int
    rows: int
    at: float


def load_filter_process(path: str | Path, settings: EKFSettings,
                        **options: Any) -> RemoteFilter:
    """A user's filter started in the process for its language: a MATLAB filter (a folder of .m
    files, or a .m file in one) in Octave, a Python file in Python. UserFilterError when it
    cannot be started (options: RemoteFilter's)."""
    if is_matlab_filter(path):
        return OctaveRemote.load(path, settings, **options)
    return RemoteFilter.load(path, settings, **options)


class OctaveRemote(RemoteFilter):
    """A MATLAB filter's folder running in Octave (see the module docstring). The private copy
    of the folder belongs to this object: :meth:`close` removes it."""

    def __init__(self, path: str | Path, folder: MatlabFolder, settings: EKFSettings,
                 octave: Path, step_limit_s: float | None = None,
                 on_output: Callable[[str], None] | None = None,
                 deadline_s: float | None = None, load_deadline_s: float | None = None,
                 code_dir: Path | None = None) -> None:
        self.folder = folder
        self.octave = octave
        self._held: list[_Held] = []
        self._last_sent = -math.inf
        self._groups: dict[int, tuple[float, list[_Part]]] = {}   # request -> sent, its blocks
        self.code_dir = code_dir if code_dir is not None else private_copy(folder)
        argv = octave_command(octave, self.code_dir, folder.folder)
        env = dict(os.environ)

        def command() -> tuple[list[str], dict[str, str]]:
            return argv, env

        options: dict[str, Any] = {"on_output": on_output, "deadline_s": deadline_s,
                                   "load_deadline_s": load_deadline_s, "command": command}
        if step_limit_s is not None:
            options["step_limit_s"] = step_limit_s
        try:
            super().__init__(folder.folder, folder.source, settings, **options)
        except OSError as error:          # octave-cli vanished, or cannot be run
            self._remove_copy()
            raise UserFilterError(UserProblem(
                "load", f"{folder.name}: cannot run Octave ({octave}): "
                        f"{error.strerror or error}", file=str(folder.folder))) from None

    @classmethod
    def load(cls, path: str | Path, settings: EKFSettings, **options: Any) -> OctaveRemote:
        """Read the folder (or the folder of a .m file), find Octave and start it;
        UserFilterError when either cannot be done (one line: how to install Octave)."""
        try:
            folder = MatlabFolder(path)
        except OSError as error:
            path = Path(path)
            raise UserFilterError(UserProblem(
                "load", f"{path.name}: cannot read ({error.strerror or error})",
                file=str(path))) from None
        try:
            octave = find_octave()
        except OctaveNotFound as error:
            raise UserFilterError(UserProblem("load", f"{folder.name}: {error}", str(error),
                                              file=str(folder.folder))) from None
        return cls(path, folder, settings, octave, **options)

    def again(self, settings: EKFSettings | None = None) -> OctaveRemote:
        """A new Octave for the same folder bytes (after this one got stuck or ended); the new
        one owns a copy of its own."""
        return OctaveRemote(self.folder.folder, self.folder, settings or self.settings,
                            self.octave, self.step_limit_s, self.process.on_output,
                            self.deadline_s, self.load_deadline_s)

    # -- blocks: handed over one by one, sent together ----------------------------------------

    def send_rows(self, t_s: np.ndarray, given: np.ndarray, values: np.ndarray,
                  innovations: bool = True) -> int | None:
        """Hand rows over (as RemoteFilter.send_rows); they go at once when Octave is idle,
        else with the next block."""
        if not self.usable:
            return None
        block = next(_blocks)
        self._held.append(_Held(block, np.array(t_s, np.float64), np.array(given, bool),
                                np.array(values, np.float64), self.epoch, time.monotonic(),
                                bool(innovations)))
        self._flush()
        return block

    def _busy(self) -> bool:
        return any(RemoteFilter.awaiting(self, request) for request in self._groups)

    def _flush(self, force: bool = False) -> None:
        """Send the blocks held, as one request, when no other is being worked on (force:
        now, before a request that must come after them)."""
        held = [h for h in self._held if h.epoch == self.epoch]
        if not held or not self.usable:
            return
        if not force and (self._busy() or time.monotonic() - self._last_sent < GATHER_S):
            return
        self._held = []
        request = super().send_rows(np.concatenate([h.t_s for h in held]),
                                    np.concatenate([h.given for h in held]),
                                    np.concatenate([h.values for h in held]),
                                    any(h.innovations for h in held))
        self._last_sent = time.monotonic()
        if request is not None:
            self._groups[request] = (self._last_sent,
                                     [_Part(h.block, len(h.t_s), h.at) for h in held])

    def poll(self) -> list[BlockResult]:
        results = []
        for result in super().poll():
            group = self._groups.pop(result.id, None)
            results += [result] if group is None else _split(result, group[1], group[0])
        for request in [r for r in self._groups if not RemoteFilter.awaiting(self, r)]:
            del self._groups[request]             # an old epoch's, or the process is gone
        self._flush()
        return results

    def wait(self, timeout: float) -> None:
        """Someone waits for results (`filter`, `evaluate`): what is held goes now."""
        if not self._busy():
            self._flush(force=True)
        super().wait(timeout)

    def awaiting(self, block: int) -> bool:
        if any(h.block == block and h.epoch == self.epoch for h in self._held):
            return self.usable
        return any(RemoteFilter.awaiting(self, request) for request, (_, parts) in
                   self._groups.items() if any(p.block == block for p in parts))

    @property
    def in_flight_rows(self) -> int:
        return super().in_flight_rows + sum(len(h.t_s) for h in self._held)

    def reset(self, settings: EKFSettings | None = None, fresh: bool = False,
              new_epoch: bool = False) -> None:
        if new_epoch:
            self._held = []
        else:
            self._flush(force=True)               # rows handed over before it go first
        super().reset(settings, fresh, new_epoch)

    def ask(self, op: str, arrays: dict[str, np.ndarray] | None = None) -> dict:
        self._flush(force=True)
        return super().ask(op, arrays)

    def close(self) -> None:
        super().close()
        self._remove_copy()

    def _remove_copy(self) -> None:
        shutil.rmtree(self.code_dir, ignore_errors=True)

    # -- in MATLAB terms ------------------------------------------------------------------------

    def _ended_message(self, error: str, code: int | None) -> str:
        if error:
            return (f"{self.name}: Octave spoke garbage ({error}): paused; save a .m file to "
                    "restart it")
        if any(TOO_OLD in line for line in self.process.output):
            version = next(line for line in self.process.output if TOO_OLD in line)
            return f"{self.name}: {version.split(TOO_OLD, 1)[1].strip()} ({self.octave})"
        return (f"{self.name}: Octave ended ({exit_words(code)}): paused; save a .m file to "
                "restart it")

    def _stuck_message(self, what: str, where: str, limit: float) -> str:
        if what == "returned from step":
            what = "come back from your functions"
        return (f"{self.name}: Octave has not {what} for {limit:g} s (an endless loop?): "
                "paused; save a .m file to restart it")

    def _ask_where(self) -> None:
        """Octave has no way to print where it is while it runs (SIGUSR1 would only make it
        warn): the deadline alone says it is stuck."""


def _split(result: BlockResult, parts: list[_Part], sent: float) -> list[BlockResult]:
    """A reply to blocks sent together (at `sent`), as the results of each; each one's lag from
    when it was handed over."""
    out = []
    start = 0
    last = len(parts) - 1
    for index, part in enumerate(parts):
        end = start + part.rows
        paused_at = result.paused_at
        if paused_at >= 0:
            paused_at = max(0, paused_at - start) if paused_at < end else -1
        last_out = result.last_out
        last_out = -1 if last_out < start else min(last_out, end - 1) - start
        t_s = result.t_s[start:end]
        innovations = [item for item in result.innovations
                       if len(t_s) and t_s[0] <= item[0] <= t_s[-1]]
        out.append(replace(result, id=part.block, t_s=t_s, given=result.given[start:end],
                           q=result.q[start:end], flags=result.flags[start:end],
                           paused_at=paused_at, last_out=last_out,
                           P=result.P if index == last else None, innovations=innovations,
                           lag_s=result.lag_s + max(0.0, sent - part.at)))
        start = end
    return out
