"""Your Filter object and its calls, inside your filter's own process (app.engine.userfilter.child).

:class:`FilterInstance` makes the user's ``Filter`` (with the settings when its constructor takes
them), calls its ``step`` once per row and keeps what the engine shows: the latest accepted
output, the problem that paused it, notes, the course steps not written yet, the time spent in
the user's code. Errors never escape: an exception in the user's code or a return value that
breaks the contract *pauses* it (:attr:`FilterInstance.problem` says where and what);
``NotImplementedError`` means "not written yet": that step (or that sample) is skipped and
noted. A call that does not come back within ``step_limit_s`` while running Python code (an
endless loop) is stopped at its line and pauses it like an exception
(app.engine.userfilter.watchdog); a call stuck in C code (``time.sleep``, a socket) is for the
engine to notice (app.engine.userfilter.process).

Lean on purpose: it imports numpy and this package's code, protocol and watchdog modules, nothing
of the engine, so the process starts quickly.
"""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from app.engine.errors import UserProblem
from app.engine.userfilter.code import (USER_ERRORS, BadOutput, FilterCode, Output,
                                        UserFilterError, instantiate, output_problem,
                                        parse_output, problem_from_exception)
from app.engine.userfilter.protocol import INNOVATION_SENSORS
from app.engine.userfilter.watchdog import DEFAULT_LIMIT_S, UserCodeTimeout, guard

MAX_NOTES = 20
_SENSOR_CODE = {name: code for code, name in enumerate(INNOVATION_SENSORS)}


class FilterInstance:
    """The user's Filter object made from `code` with `settings` (the dict a constructor gets)."""

    def __init__(self, code: FilterCode, settings: dict[str, Any],
                 step_limit_s: float = DEFAULT_LIMIT_S) -> None:
        self.code = code
        self.settings = settings
        self.problem: UserProblem | None = None
        self.notes: list[str] = []
        self.calls = 0
        self.seconds = 0.0
        self.step_limit_s = step_limit_s
        self._guard = guard(step_limit_s, "step()")
        self._pid = os.getpid()
        self.start()

    def start(self) -> None:
        """A new Filter object (its problem, if it raises, pauses it)."""
        self.out: Output | None = None
        self.filter: Any = None
        try:
            self.filter = instantiate(self.code, self.settings)
        except UserFilterError as error:
            self.problem = error.problem

    def restart(self, settings: dict[str, Any] | None = None, fresh: bool = False) -> None:
        """A new Filter object (with new settings); fresh: forget the problem that paused it."""
        if settings is not None:
            self.settings = settings
        problem = None if fresh else self.problem
        self.problem = None
        self.start()
        self.problem = self.problem or problem

    @property
    def paused(self) -> bool:
        return self.problem is not None or self.filter is None

    def _note(self, text: str) -> None:
        if text not in self.notes and len(self.notes) < MAX_NOTES:
            self.notes.append(text)

    def step(self, t: float, gyr: np.ndarray | None, acc: np.ndarray | None,
             mag: np.ndarray | None) -> Output | None:
        """Call the user's step; the output it returned, checked (None: none accepted: paused,
        skipped or an error, which then is :attr:`problem`)."""
        if self.paused:
            return None
        start = time.perf_counter()
        try:
            with self._guard:
                try:
                    result = self.filter.step(t, gyr, acc, mag)
                finally:
                    if os.getpid() != self._pid:   # a copy os.fork() made in step: not ours
                        os._exit(0)
        except UserCodeTimeout as error:
            self._guard.disarm()
            self._timed(start)
            self.problem = problem_from_exception(error, self.code.path, t)
            return None
        except NotImplementedError as error:
            self._timed(start)
            where = problem_from_exception(error, self.code.path, t)
            self.code.note_missing(where.function or "Filter.step", error)
            return None
        except USER_ERRORS as error:   # noqa: BLE001 (the user's code: anything)
            self._timed(start)
            self.problem = problem_from_exception(error, self.code.path, t)
            return None
        self._timed(start)
        try:
            out = parse_output(result, unnormalised_ok="mu_normalizeQ" in self.code.missing)
        except BadOutput as error:
            self.problem = output_problem(error, self.code, t)
            return None
        except USER_ERRORS as error:   # noqa: BLE001 (an object of the user's that misbehaves)
            self.problem = problem_from_exception(error, self.code.path, t, kind="output")
            return None
        self.out = out
        for note in out.notes:
            self._note(note)
        return out

    def _timed(self, start: float) -> None:
        self.calls += 1
        self.seconds += time.perf_counter() - start

    def run_block(self, t: np.ndarray, given: np.ndarray, values: np.ndarray,
                  after_row=None) -> dict[str, Any]:
        """Step the rows of a block (see app.engine.userfilter.protocol, ``rows``); after_row(k)
        is called after each row (the child's heartbeat). Returns the reply's header values and
        arrays."""
        started = time.perf_counter()
        n = len(t)
        columns = [values[:, 3 * i:3 * i + 3] for i in range(3)]
        gives = np.asarray(given, bool).tolist()
        times = np.asarray(t, float).tolist()
        outs: list[Output] = []              # the outputs in the block, in order
        which = np.full(n, -1, np.int64)     # the latest output after each row (-1: none yet)
        if self.out is not None:
            outs.append(self.out)
        inn_row, inn_sensor, inn_nu, inn_S, inn_accepted = [], [], [], [], []
        paused_at = 0 if self.paused else -1
        last_out = -1
        calls, seconds = self.calls, self.seconds
        for k in range(n):
            if paused_at < 0:
                g, a, m = gives[k]
                out = self.step(times[k], columns[0][k].copy() if g else None,
                                columns[1][k].copy() if a else None,
                                columns[2][k].copy() if m else None)
                if out is not None:
                    last_out = k
                    outs.append(out)
                    for sensor, (nu, S, accepted) in out.innovations.items():
                        if accepted is None:
                            disturbed = (out.acc_disturbed if sensor == "acc" else
                                         out.mag_disturbed if sensor == "mag" else None)
                            accepted = not disturbed
                        padded_nu = np.full(3, np.nan)
                        padded_S = np.full((3, 3), np.nan)
                        padded_nu[:len(nu)] = nu
                        padded_S[:len(nu), :len(nu)] = S
                        inn_row.append(k)
                        inn_sensor.append(_SENSOR_CODE[sensor])
                        inn_nu.append(padded_nu)
                        inn_S.append(padded_S)
                        inn_accepted.append(bool(accepted))
                elif self.paused:
                    paused_at = k
            which[k] = len(outs) - 1
            if after_row is not None:
                after_row(k)
        q = np.full((n, 4), np.nan)
        flags = np.full((n, 3), -1, np.int8)
        if outs:
            has = which >= 0
            q[has] = np.array([o.q for o in outs])[which[has]]
            flags[has] = np.array([[-1 if v is None else int(v) for v in
                                    (o.acc_disturbed, o.mag_disturbed, o.standstill)]
                                   for o in outs], np.int8)[which[has]]
        m = len(inn_row)
        arrays = {"q": q, "flags": flags,
                  "inn_row": np.array(inn_row, "<i4"), "inn_sensor": np.array(inn_sensor, "|i1"),
                  "inn_nu": np.array(inn_nu).reshape(m, 3),
                  "inn_S": np.array(inn_S).reshape(m, 3, 3),
                  "inn_accepted": np.array(inn_accepted, "|u1")}
        if self.out is not None and self.out.P is not None:
            arrays["P"] = np.ascontiguousarray(self.out.P[:4, :4], dtype=float)
        header = {"run": self.calls - calls, "seconds": self.seconds - seconds,
                  "elapsed": time.perf_counter() - started, "paused_at": paused_at,
                  "last_out": last_out}
        return {"header": header, "arrays": arrays}

    def state(self) -> dict[str, Any]:
        """What a snapshot keeps (the user's object and what is kept of it)."""
        return {"filter": self.filter, "out": self.out, "problem": self.problem}

    def set_state(self, state: dict[str, Any]) -> None:
        self.filter, self.out, self.problem = state["filter"], state["out"], state["problem"]
