"""Your filter in a process of its own, as the engine sees it: :class:`RemoteFilter`.

It starts the process (app.engine.userfilter.process) with the file's bytes, sends it blocks of
rows and set-up requests without waiting, and turns the replies into :class:`BlockResult` and
its state: the problem that paused the filter (the user's, from the process, or the engine's:
stuck, ended), notes, steps not written yet, the time per call. Two consumers drive it, one at a
time: the live lane (app.engine.userfilter.lane, never waits) and the estimator
(app.engine.userfilter.filter, waits for each block, with the same deadline).

A reply belongs to an *epoch*: :meth:`RemoteFilter.reset` starts a new one (a new Filter object
in the process) and replies to blocks sent before it are dropped, so rows handed over before a
seek never show after it.

The deadline: a process that owes a reply and has sent nothing for DEADLINE_S (LOAD_DEADLINE_S
while it loads the file or makes a Filter object) is in one call of the user's code that does
not return (``time.sleep``, ``input`` on a terminal, ``plt.show()``, a socket). The filter is
paused and says so in one line, with the line it is stuck at when the process can tell
(POSIX); the process is left as it is until the filter is unloaded or reloaded, or the program
ends (:meth:`RemoteFilter.close` kills it and whatever it started).
"""

from __future__ import annotations

import hashlib
import itertools
import math
import signal
import statistics
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ekf.settings import EKFSettings
from app.engine.errors import UserProblem
from app.engine.userfilter import code as user_code
from app.engine.userfilter.code import MAX_MESSAGE, UserFilterError
from app.engine.userfilter.process import FilterProcess, python_command
from app.engine.userfilter.protocol import (INNOVATION_SENSORS, PROBLEM_FIELDS,
                                            settings_to_wire)
from app.engine.userfilter.watchdog import DEFAULT_LIMIT_S

DEADLINE_S = 5.0             # a call of your code that has not returned for this long: paused
LOAD_DEADLINE_S = 12.0       # loading the file or Filter() (its own limit: 10 s of Python code)
RECENT_WEIGHT = 0.02         # of the latest call in the running time per call
COST_BLOCKS = 16             # the process's time per row: the median of this many blocks
_WHAT = {"rows": "returned from step", "start": "finished loading",
         "reset": "returned from Filter()", "snapshot": "let its state be copied",
         "restore": "let its state be restored"}


def filter_settings(settings: EKFSettings) -> dict[str, Any]:
    """The ``settings`` a Filter's constructor gets (numpy arrays, the course's names): g,
    g0 = (0, 0, g), m0 (ENU, or None: take it from a reading), Rw, Ra, Rm (3x3), gyr_bias (3,),
    the gates acc_gate, mag_gate, mag_alpha (tasks 8 and 11), and "ekf": every setting as a
    dict (docs/filter.md, "Settings")."""
    s = settings
    return {
        "g": float(s.g), "g0": np.array([0.0, 0.0, float(s.g)]),
        "m0": None if s.m0 is None else np.array(s.m0, dtype=float),
        "Rw": np.array(s.gyr_noise_cov, dtype=float), "Ra": np.array(s.acc_noise_cov, dtype=float),
        "Rm": np.array(s.mag_noise_cov, dtype=float),
        "gyr_bias": np.array(s.gyr_bias, dtype=float),
        "acc_gate": float(s.acc_gate), "mag_gate": float(s.mag_gate),
        "mag_alpha": float(s.mag_alpha), "ekf": s.to_dict(),
    }


def _one_line(text: str) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= MAX_MESSAGE else text[:MAX_MESSAGE - 1] + "…"


def _problem(wire: dict[str, Any] | None) -> UserProblem | None:
    if not wire:
        return None
    return UserProblem(**{key: wire.get(key) for key in PROBLEM_FIELDS})


def exit_words(code: int) -> str:
    """"exit status 3" or "signal 11, SIGSEGV"."""
    if code >= 0:
        return f"exit status {code}"
    try:
        return f"signal {-code}, {signal.Signals(-code).name}"
    except ValueError:
        return f"signal {-code}"


@dataclass
class BlockResult:
    """One block's rows after the user's filter: t_s (n,) and given (n, 3) as sent; q (n, 4)
    the latest output after each row (NaN: none yet); flags (n, 3) int8 the latest output's
    acc_disturbed, mag_disturbed, standstill (-1: not reported); paused_at: the row where it
    paused (-1: it did not); last_out: the row of the latest output (-1: none in the block); P
    the latest output's covariance of q (None: none); innovations (t, sensor, nu, S, accepted);
    lag_s: from handing the block over to taking its result."""

    id: int
    t_s: np.ndarray
    given: np.ndarray
    q: np.ndarray
    flags: np.ndarray
    paused_at: int = -1
    last_out: int = -1
    P: np.ndarray | None = None
    innovations: list[tuple] = field(default_factory=list)
    lag_s: float = 0.0


@dataclass
class _Sent:
    t_s: np.ndarray
    given: np.ndarray
    epoch: int
    at: float


class RemoteFilter:
    """Your filter file running in a process of its own (see the module docstring).

    Made from the file's bytes (:meth:`load` reads them; the SHA-256 is of exactly the bytes the
    process runs). on_output(line): each line the filter prints, from the output thread."""

    _ids = itertools.count(1)

    def __init__(self, path: str | Path, source: bytes, settings: EKFSettings,
                 step_limit_s: float = DEFAULT_LIMIT_S,
                 on_output: Callable[[str], None] | None = None,
                 deadline_s: float | None = None, load_deadline_s: float | None = None,
                 command: Callable[[], tuple[list[str], dict[str, str]]] = python_command
                 ) -> None:
        self.path = Path(path).expanduser().resolve()
        self.name = self.path.name
        self.source = source
        self.sha256 = hashlib.sha256(source).hexdigest()
        self.settings = settings
        self.step_limit_s = step_limit_s
        self.deadline_s = DEADLINE_S if deadline_s is None else deadline_s
        self.load_deadline_s = LOAD_DEADLINE_S if load_deadline_s is None else load_deadline_s
        self.command = command
        self.epoch = 0
        self.started = False              # the start reply arrived
        self.load_problem: UserProblem | None = None
        self._child_problem: UserProblem | None = None
        self.engine_problem: UserProblem | None = None     # stuck, ended
        self.missing: list[str] = []
        self.notes: list[str] = []
        self.calls = 0
        self.seconds = 0.0
        self.time_per_call_s = math.nan
        self._sent: dict[int, _Sent] = {}
        self.answers: dict[str, dict] = {}       # snapshot and restore replies, by request
        self._row_costs: deque[float] = deque(maxlen=COST_BLOCKS)
        self._stuck_op: str | None = None
        argv, env = command()
        self.process = FilterProcess(argv, env, on_output)
        self.process.request({"op": "start", "path": str(self.path), "name": self.name,
                              "settings": settings_to_wire(filter_settings(settings)),
                              "step_limit_s": step_limit_s,
                              "load_limit_s": user_code.LOAD_LIMIT_S},
                             {"source": np.frombuffer(source, np.uint8)})

    @classmethod
    def load(cls, path: str | Path, settings: EKFSettings, **options: Any) -> RemoteFilter:
        """Read the file and start its process; UserFilterError when it cannot be read. (A
        filter in either language: app.engine.userfilter.octave_remote.load_filter_process.)"""
        path = Path(path).expanduser().resolve()
        try:
            source = path.read_bytes()
        except OSError as error:
            raise UserFilterError(UserProblem(
                "load", f"{path.name}: cannot read ({error.strerror or error})",
                file=str(path))) from None
        return cls(path, source, settings, **options)

    def again(self, settings: EKFSettings | None = None) -> RemoteFilter:
        """A new process for the same bytes (after this one got stuck or ended)."""
        return RemoteFilter(self.path, self.source, settings or self.settings, self.step_limit_s,
                            self.process.on_output, self.deadline_s, self.load_deadline_s,
                            self.command)

    # -- state -------------------------------------------------------------------------------

    @property
    def problem(self) -> UserProblem | None:
        """Why the filter is paused (None: it is not)."""
        return self.engine_problem or self.load_problem or self._child_problem

    @property
    def paused(self) -> bool:
        return self.problem is not None

    @property
    def usable(self) -> bool:
        """The process can take requests (not stuck, not ended, not closed)."""
        return self.engine_problem is None and not self.process.closed

    def awaiting(self, block: int) -> bool:
        """Whether the result of `block` can still come (sent in this epoch, process usable)."""
        sent = self._sent.get(block)
        return sent is not None and sent.epoch == self.epoch and self.usable

    @property
    def cost_per_row_s(self) -> float:
        """The process's time per row (your step and what the process does around it): the
        median of the latest blocks, so one block slowed by the machine moves it little (NaN:
        none yet)."""
        return statistics.median(self._row_costs) if self._row_costs else math.nan

    @property
    def in_flight_rows(self) -> int:
        return sum(len(sent.t_s) for sent in self._sent.values())

    @property
    def output(self) -> list[str]:
        return list(self.process.output)

    # -- requests (never wait) ------------------------------------------------------------------

    def send_rows(self, t_s: np.ndarray, given: np.ndarray, values: np.ndarray,
                  innovations: bool = True) -> int | None:
        """Hand rows over: t_s (n,) [s], given (n, 3) bool (gyr, acc, mag given to the filter),
        values (n, 9); the block's id (None: not sent, the process is not usable). innovations
        False: nobody shows the innovations of these rows (a host may skip computing them)."""
        if not self.usable:
            return None
        block = next(self._ids)
        t_s = np.ascontiguousarray(t_s, dtype=np.float64)
        given = np.ascontiguousarray(given, dtype=bool)
        self._sent[block] = _Sent(t_s, given, self.epoch, time.monotonic())
        self.process.request({"op": "rows", "id": block, "epoch": self.epoch,
                              "innovations": bool(innovations)},
                             {"t": t_s, "given": given.astype(np.uint8),
                              "values": np.ascontiguousarray(values, dtype=np.float64)})
        return block

    def reset(self, settings: EKFSettings | None = None, fresh: bool = False,
              new_epoch: bool = False) -> None:
        """A new Filter object (with new settings) from the next rows on; fresh: forget the
        user's problem too; new_epoch: rows handed over before it give no results."""
        if settings is not None:
            self.settings = settings
        if new_epoch:
            self.epoch += 1
        if fresh:
            self._child_problem = None
        if not self.usable:
            return
        self.process.request({"op": "reset", "epoch": self.epoch, "fresh": bool(fresh),
                              "settings": None if settings is None
                              else settings_to_wire(filter_settings(settings))})

    # -- replies ------------------------------------------------------------------------------

    def poll(self) -> list[BlockResult]:
        """The results that arrived (of the current epoch), the state brought up to date, and
        the deadline and the process's end checked. Never waits."""
        results = []
        now = time.monotonic()
        for header, arrays in self.process.take():
            op = header.get("op")
            if op == "rows":
                result = self._rows(header, arrays, now)
                if result is not None:
                    results.append(result)
            elif op == "start":
                self.started = True
                problem = _problem(header.get("problem"))
                if problem is not None and problem.kind == "load":
                    self.load_problem = problem
                else:
                    self._child_problem = problem
                self._take_state(header)
            elif op == "reset":
                if header.get("epoch") == self.epoch:
                    self._child_problem = _problem(header.get("problem"))
                self._take_state(header)
            else:                                 # snapshot, restore: for the one who asked
                if op == "restore":
                    self._child_problem = _problem(header.get("problem"))
                    self._take_state(header)
                self.answers[str(op)] = {**header, **arrays}
        self._check(now)
        return results

    def _take_state(self, header: dict) -> None:
        self.missing = list(header.get("missing") or [])
        self.notes = list(header.get("notes") or [])

    def _rows(self, header: dict, arrays: dict, now: float) -> BlockResult | None:
        sent = self._sent.pop(int(header["id"]), None)
        run, seconds = int(header.get("run", 0)), float(header.get("seconds", 0.0))
        if run:
            self.calls += run
            self.seconds += seconds
            mean = seconds / run
            recent = self.time_per_call_s
            self.time_per_call_s = mean if math.isnan(recent) else (
                recent + (1.0 - (1.0 - RECENT_WEIGHT) ** run) * (mean - recent))
        if sent is not None and len(sent.t_s) and "elapsed" in header:
            self._row_costs.append(float(header["elapsed"]) / len(sent.t_s))
        if sent is None or header.get("epoch") != self.epoch or sent.epoch != self.epoch:
            return None
        self._child_problem = _problem(header.get("problem"))
        self._take_state(header)
        innovations = []
        if "inn_row" in arrays:
            for row, sensor, nu, S, accepted in zip(
                    arrays["inn_row"].tolist(), arrays["inn_sensor"].tolist(), arrays["inn_nu"],
                    arrays["inn_S"], arrays["inn_accepted"].tolist()):
                k = int(np.sum(np.isfinite(nu)))
                innovations.append((float(sent.t_s[row]), INNOVATION_SENSORS[sensor],
                                    nu[:k].copy(), S[:k, :k].copy(), bool(accepted)))
        return BlockResult(int(header["id"]), sent.t_s, sent.given, arrays["q"].copy(),
                           arrays["flags"].copy(), int(header.get("paused_at", -1)),
                           int(header.get("last_out", -1)),
                           arrays["P"].copy() if "P" in arrays else None, innovations,
                           now - sent.at)

    def _check(self, now: float) -> None:
        """The deadline and the end of the process."""
        if self.engine_problem is not None:
            if self._stuck_op is not None and self.engine_problem.line is None:
                self._say_stuck()                 # the stack may have arrived meanwhile
            return
        if self.process.closed:
            return
        error = self.process.error
        code = self.process.ended()
        if error or code is not None:
            self.engine_problem = UserProblem(
                "ended", _one_line(self._ended_message(error, code)),
                "\n".join(self.process.output), str(self.path), None, None, self._at())
            return
        op = self.process.owed_op
        if op is None:
            return
        limit = self.load_deadline_s if op in ("start", "reset") else self.deadline_s
        if self.process.quiet_s() > limit:
            self._stuck_op = op
            self._stuck_limit = limit
            self._ask_where()
            self._say_stuck()

    def _say_stuck(self) -> None:
        where, line, function = self.name, None, None
        stack = self.process.stack or []
        mine = [frame for frame in stack if _same(frame[0], self.path)]
        if mine:
            file, line, function = mine[0]
            where = f"{self.name}:{line} in {function}"
        what = _WHAT.get(self._stuck_op, "answered")
        details = ("Where it is (most recent call first):\n" + "".join(
            f'  File "{f}", line {n}, in {fn}\n' for f, n, fn in stack)) if stack else ""
        self.engine_problem = UserProblem(
            "stuck", _one_line(self._stuck_message(what, where, self._stuck_limit)),
            details, str(self.path), line, function, self._at())

    # -- what a host of another language says differently (app.engine.userfilter.octave_remote) --

    def _ended_message(self, error: str, code: int | None) -> str:
        how = error or (f"your filter ended the process it runs in ({exit_words(code)}: "
                        "os._exit() or a crash in its code)")
        return f"{self.name}: {how}: paused; save the file to reload"

    def _stuck_message(self, what: str, where: str, limit: float) -> str:
        return (f"your filter has not {what} for {limit:g} s ({where}): paused; save the file to "
                "reload")

    def _ask_where(self) -> None:
        """Ask the process for the line it is at (a Python host prints its stack)."""
        self.process.ask_where()

    def _at(self) -> float | None:
        """The phone time of the row the process is at (None: not in a block)."""
        if not self._sent:
            return None
        oldest = self._sent[min(self._sent)]
        return float(oldest.t_s[min(self.process.progress, len(oldest.t_s) - 1)]) \
            if len(oldest.t_s) else None

    # -- waiting (the estimator's side) --------------------------------------------------------

    def wait(self, timeout: float) -> None:
        """Wait at most `timeout` for the process to say something."""
        self.process.wait(timeout)

    def settle(self, timeout: float = 1.0) -> None:
        """Blocking callers: when the filter got stuck, give its stack `timeout` to arrive, so
        the problem names the line."""
        deadline = time.monotonic() + timeout
        while (self._stuck_op is not None and self.process.stack is None
               and time.monotonic() < deadline and self.process.proc.poll() is None):
            self.wait(0.05)
        self.poll()

    def ask(self, op: str, arrays: dict[str, np.ndarray] | None = None) -> dict:
        """A snapshot or restore request, waited for (with the deadline); its reply's header
        and arrays. ValueError when the process is not usable or stops being so."""
        if not self.usable:
            raise ValueError(f"{self.name}: its process is not running")
        self.answers.pop(op, None)
        self.process.request({"op": op}, arrays)
        while op not in self.answers:
            if not self.usable:
                raise ValueError(self.problem.message if self.problem else
                                 f"{self.name}: its process is not running")
            self.wait(0.1)
            self.poll()
        return self.answers.pop(op)

    def close(self) -> None:
        """Kill the process and whatever it started."""
        self.process.close()


def _same(filename: str, path: Path) -> bool:
    try:
        return Path(filename).resolve() == path
    except (OSError, ValueError):
        return False
