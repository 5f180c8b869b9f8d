"""Your own filter as an estimator: :class:`UserFilterEstimator` runs a user's ``Filter`` class in
a process of its own (app.engine.userfilter.remote) behind the ``ekf.Estimator`` protocol, so it
runs wherever an estimator runs: over a log in `filter` and `evaluate` (``--estimator
FILE.py``), in Tune's re-runs, in a replay's catch-up after a reload or a seek. The live engine
runs it through its lane instead (app.engine.userfilter.lane), which never waits for it.

The contract, from the user's side::

    class Filter:
        def __init__(self, settings=None): ...          # optional: the active settings
        def step(self, t, gyr, acc, mag):                # t [s] on the phone's clock; each
            ...                                          # sensor a (3,) array or None
            return q                                     # (w, x, y, z), sensor -> ENU
            # or {"q": q, "P": P, "acc_disturbed": bool, "mag_disturbed": bool,
            #     "standstill": bool, "innovations": {"acc": (nu, S), "mag": (nu, S)}}

Errors never escape: an exception in the user's code, a return value that breaks the contract,
a call that does not return, or the end of its process *pauses* the filter
(:attr:`UserFilterEstimator.problem` says where and what); ``NotImplementedError`` means "not
written yet": that step (or that sample) is skipped and noted (app.engine.userfilter.instance).

This estimator waits for each block of rows (every row is run), but never longer than the
deadline of app.engine.userfilter.remote: a filter stuck in one call pauses, and the rows after
it keep its last output. :meth:`UserFilterEstimator.close` ends the process (so does dropping
the estimator).
"""

from __future__ import annotations

import math
import sys
import threading
import weakref
from collections import deque
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
from numpy.typing import ArrayLike

import ekf
import ekf.quaternion as quat
from ekf import SENSORS
from ekf.estimator import batch_rows
from ekf.settings import EKFSettings, resolve_settings
from app.engine.errors import UserProblem
from app.engine.userfilter.code import UserFilterError, is_filter_file
from app.engine.userfilter.octave_remote import load_filter_process
from app.engine.userfilter.remote import BlockResult, RemoteFilter, filter_settings
from app.engine.userfilter.watchdog import DEFAULT_LIMIT_S

__all__ = ["UserFilterEstimator", "UserFilterError", "filter_settings", "is_filter_file",
           "estimator_for"]

BLOCK_ROWS = 4096            # rows per block of a run over a log
AHEAD = 2                    # blocks handed over before the first comes back
WAIT_SLICE_S = 0.1


def print_output(line: str) -> None:
    """What a filter prints, on the command line: stderr (stdout may be the CSV)."""
    print(line, file=sys.stderr, flush=True)


def _left_matrix(r: np.ndarray) -> np.ndarray:
    """L(r) with r ⊗ q = L(r) q."""
    w, x, y, z = r
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


def _nis(nu: np.ndarray, S: np.ndarray) -> float:
    try:
        return float(nu @ np.linalg.solve(S, nu))
    except np.linalg.LinAlgError:
        return math.nan


class UserFilterEstimator:
    """``ekf.Estimator`` around a user's Filter in its own process (a file path, or a
    :class:`RemoteFilter` the caller owns).

    Loading raises :class:`UserFilterError` when the file cannot be used at all (it does not
    load, or its loading never ends); everything later is caught: :attr:`problem` (None while
    running), :meth:`missing_steps`, :attr:`notes`, :attr:`time_per_call_s`. With
    :attr:`collect_innovations`, the returned innovations are kept in :attr:`innovations` as
    (t, sensor, nu, S, accepted) for the consistency view (bounded). on_progress(done, total)
    is called after each block of a long run; cancel (an Event) ends a wait early.
    """

    def __init__(self, source: str | Path | RemoteFilter,
                 settings: EKFSettings | str | None = None,
                 sensors: tuple[str, ...] | list[str] = SENSORS,
                 step_limit_s: float = DEFAULT_LIMIT_S,
                 on_output: Callable[[str], None] | None = print_output,
                 deadline_s: float | None = None) -> None:
        self.settings: EKFSettings = resolve_settings(settings)
        self._enabled = {s: s in tuple(sensors) for s in SENSORS}
        self.collect_innovations = False
        self.innovations: deque[tuple] = deque(maxlen=50_000)
        self.on_progress: Callable[[int, int], None] | None = None
        self.cancel: threading.Event | None = None
        self._heading = 0.0
        self._forget()
        self._t = math.nan
        if isinstance(source, RemoteFilter):
            self.remote, self._owner = source, False
        else:
            self.remote = load_filter_process(source, self.settings, step_limit_s=step_limit_s,
                                              on_output=on_output, deadline_s=deadline_s)
            self._owner = True
            weakref.finalize(self, self.remote.close)
            self.wait_started()
            remote = self.remote
            problem = remote.load_problem or (None if remote.started else remote.problem)
            if problem is not None:
                self.close()
                raise UserFilterError(problem)
        self.name = self.remote.name

    def _forget(self) -> None:
        self._q: np.ndarray | None = None       # the latest output (without the heading turn)
        self._P: np.ndarray | None = None
        self._lights = np.full(3, -1, np.int8)
        self._used = (False, False, False)
        self._nis: dict[str, float] = {}

    def wait_started(self) -> None:
        """Wait until the process has loaded the file or cannot (its deadline: the remote's)."""
        remote = self.remote
        self._wait(lambda: remote.started)

    def _wait(self, done: Callable[[], bool]) -> None:
        """Take results until done() (or the process is stuck or gone, or cancelled)."""
        remote = self.remote
        while True:
            for result in remote.poll():
                self._take(result)
            if not remote.usable:
                remote.settle()
                return
            if done() or (self.cancel is not None and self.cancel.is_set()):
                return
            remote.wait(WAIT_SLICE_S)

    def close(self) -> None:
        """End the filter's process (when this estimator started it)."""
        if self._owner:
            self.remote.close()

    def __enter__(self) -> UserFilterEstimator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- what the process says ------------------------------------------------------------------

    @property
    def problem(self) -> UserProblem | None:
        return self.remote.problem

    @property
    def paused(self) -> bool:
        return self.remote.paused

    @property
    def notes(self) -> list[str]:
        return list(self.remote.notes)

    def missing_steps(self) -> list[str]:
        return list(self.remote.missing)

    @property
    def time_per_call_s(self) -> float:
        return self.remote.time_per_call_s

    @property
    def calls(self) -> int:
        return self.remote.calls

    @property
    def seconds(self) -> float:
        return self.remote.seconds

    @property
    def sha256(self) -> str:
        return self.remote.sha256

    def _take(self, result: BlockResult) -> None:
        last = result.q[-1] if len(result.q) else None
        if last is not None and np.isfinite(last).all():
            self._q = last.copy()
            self._lights = result.flags[-1].copy()
            self._P = None if result.P is None else result.P.copy()
        if result.last_out >= 0:
            self._used = tuple(bool(v) for v in result.given[result.last_out])
            self._nis = {sensor: _nis(nu, S) for t, sensor, nu, S, _ in result.innovations
                         if t == result.t_s[result.last_out]}
        if self.collect_innovations:
            self.innovations.extend(result.innovations)

    # ---- Estimator: public state ----------------------------------------------------------------

    @property
    def quat(self) -> np.ndarray:
        if self._q is None:
            return quat.IDENTITY.copy()
        return self._turned(self._q)

    def _turned(self, q: np.ndarray) -> np.ndarray:
        if self._heading:
            q = quat.normalize(quat.multiply(quat.from_axis_angle([0, 0, 1], self._heading), q))
        return q.copy()

    @property
    def cov(self) -> np.ndarray | None:
        """P's quaternion block (4x4) when the filter returns P (turned with align_heading)."""
        if self._P is None:
            return None
        P = self._P.copy()
        if self._heading:
            L = _left_matrix(quat.from_axis_angle([0, 0, 1], self._heading))
            P = L @ P @ L.T
        return P

    @property
    def gyro_bias(self) -> np.ndarray:
        return np.asarray(self.settings.gyr_bias, float)

    @property
    def flags(self) -> ekf.Flags:
        g, a, m = self._used
        if self._q is None:
            return ekf.Flags(used_gyr=g, used_acc=a, used_mag=m)
        acc, mag, rest = (bool(v == 1) for v in self._lights)
        return ekf.Flags(acc_rejected=acc, mag_rejected=mag, at_rest=rest, used_gyr=g,
                         used_acc=a, used_mag=m)

    @property
    def lights(self) -> tuple[bool | None, bool | None, bool | None]:
        """acc_disturbed, mag_disturbed, standstill as the latest output reports them (None:
        not reported)."""
        return tuple(None if v < 0 else bool(v) for v in self._lights)

    @property
    def diagnostics(self) -> ekf.Diagnostics:
        s = self.settings
        d = ekf.Diagnostics(g=s.g, acc_gate=s.acc_gate, mag_gate=s.mag_gate)
        for sensor in ("acc", "mag"):
            if sensor in self._nis:
                setattr(d, f"{sensor}_nis", self._nis[sensor])
        return d

    @property
    def enabled(self) -> dict[str, bool]:
        return dict(self._enabled)

    @property
    def initialised(self) -> bool:
        return self._q is not None

    @property
    def time(self) -> float | None:
        return None if math.isnan(self._t) else self._t

    # ---- Estimator: control -----------------------------------------------------------------

    def set_enabled(self, gyr: bool | None = None, acc: bool | None = None,
                    mag: bool | None = None) -> None:
        """A switched-off sensor reaches the user's step as None."""
        for sensor, value in (("gyr", gyr), ("acc", acc), ("mag", mag)):
            if value is not None:
                self._enabled[sensor] = bool(value)

    def set_settings(self, settings: EKFSettings) -> None:
        """New settings restart the filter (its constructor is where it reads them)."""
        self.settings = settings
        self.remote.reset(settings)
        self._forget()

    def reset(self) -> None:
        """A new Filter object: the user's filter starts afresh from the next samples."""
        self.remote.reset()
        self._forget()

    def align_heading(self, q_ref: ArrayLike) -> None:
        """Turn the output about world up so its heading matches q_ref's (the user's state
        is the user's: the turn is applied to what it returns)."""
        if self._q is None:
            return
        self._heading += quat.heading_of(quat.multiply(np.asarray(q_ref, float),
                                                       quat.conjugate(self.quat)))

    # ---- Estimator: samples -----------------------------------------------------------------

    def step(self, t: float, gyr: ArrayLike | None = None, acc: ArrayLike | None = None,
             mag: ArrayLike | None = None) -> None:
        """Call the user's step with the samples at t (switched-off sensors as None)."""
        nan3 = np.full((1, 3), np.nan)
        rows = [nan3 if v is None else np.array(v, dtype=float).reshape(1, 3)
                for v in (gyr, acc, mag)]
        self._run(np.array([float(t)]), *rows)

    def run_batch(self, t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
                  mag: ArrayLike | None) -> ekf.BatchResult:
        """Rows as `step` would take them (a NaN row: no such sample)."""
        t, g, a, m = batch_rows(t_s, gyr, acc, mag)
        out_q, flags = self._run(t, g, a, m)
        bias = np.broadcast_to(self.gyro_bias, (len(t), 3)).copy()
        return ekf.BatchResult(t, out_q, flags[:, 0].copy(), flags[:, 1].copy(),
                               flags[:, 2].copy(), gyro_bias=bias)

    def _run(self, t: np.ndarray, g: np.ndarray, a: np.ndarray,
             m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every row through the process, AHEAD blocks at a time; (quat (n, 4), flags (n, 3))
        after each row, as the estimator's state reads then."""
        n = len(t)
        out_q = np.empty((n, 4))
        flags = np.zeros((n, 3), bool)
        if n == 0:
            return out_q, flags
        self._t = float(t[-1])
        values = np.concatenate([g, a, m], axis=1)
        on = np.array([self._enabled[s] for s in SENSORS])
        given = np.stack([~np.isnan(x).any(axis=1) for x in (g, a, m)], axis=1) & on
        starts = list(range(0, n, BLOCK_ROWS))
        sent: dict[int, int] = {}            # block id -> its first row
        done = 0
        remote = self.remote
        while done < n:
            while starts and len(sent) < AHEAD and remote.usable:
                start = starts.pop(0)
                end = min(n, start + BLOCK_ROWS)
                block = remote.send_rows(t[start:end], given[start:end], values[start:end],
                                         innovations=self.collect_innovations)
                if block is not None:
                    sent[block] = start
            if not sent:
                break                        # stuck or gone: the rest keeps the last output
            for result in remote.poll():
                start = sent.pop(result.id, None)
                self._take(result)
                if start is None:
                    continue
                self._fill(result, out_q[start:start + len(result.q)],
                           flags[start:start + len(result.q)])
                done = start + len(result.q)
                if self.on_progress is not None:
                    self.on_progress(done, n)
            if sent and (not remote.usable or (self.cancel is not None and self.cancel.is_set())):
                break
            if sent:
                remote.wait(WAIT_SLICE_S)
        if not remote.usable:
            remote.settle()
        if done < n:                         # never answered: the state as it stands
            out_q[done:] = self.quat
            f = self.flags
            flags[done:] = (f.acc_rejected, f.mag_rejected, f.at_rest)
        return out_q, flags

    def _fill(self, result: BlockResult, out_q: np.ndarray, flags: np.ndarray) -> None:
        q = result.q
        none = ~np.isfinite(q).all(axis=1)
        if none.any():
            q = q.copy()
            q[none] = quat.IDENTITY
        if self._heading:
            q = np.array([self._turned(row) if ok else row for row, ok in zip(q, ~none)])
        out_q[:] = q
        flags[:] = (result.flags == 1) & ~none[:, None]

    # ---- Estimator: snapshots -----------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        """The user's object (its state as bytes from its process) and what this wrapper keeps
        (ValueError if the user's object cannot be copied)."""
        reply = self.remote.ask("snapshot")
        if reply.get("error"):
            raise ValueError(f"{self.name}: its Filter object cannot be copied "
                             f"({reply['error']})")
        state = {"filter": reply["state"].tobytes(), "q": self._q, "P": self._P,
                 "lights": self._lights.copy(), "used": self._used, "nis": dict(self._nis),
                 "t": self._t, "heading": self._heading, "enabled": dict(self._enabled)}
        return {"estimator": self.name, "settings": self.settings, "state": state}

    def restore(self, snapshot: Mapping[str, Any]) -> None:
        if not isinstance(snapshot, Mapping) or set(snapshot) != {"estimator", "settings",
                                                                   "state"}:
            raise ValueError("a snapshot has the keys ['estimator', 'settings', 'state']")
        if snapshot["estimator"] != self.name:
            raise ValueError(f"a snapshot of estimator {snapshot['estimator']!r} cannot "
                             f"restore into {self.name!r}")
        state = dict(snapshot["state"])
        reply = self.remote.ask("restore", {"state": np.frombuffer(state["filter"], np.uint8)})
        if reply.get("error"):
            raise ValueError(f"{self.name}: its Filter object cannot be restored "
                             f"({reply['error']})")
        self.settings = snapshot["settings"]
        self._q = None if state["q"] is None else np.array(state["q"])
        self._P = None if state["P"] is None else np.array(state["P"])
        self._lights = np.array(state["lights"], np.int8)
        self._used, self._nis, self._t = tuple(state["used"]), dict(state["nis"]), state["t"]
        self._heading, self._enabled = state["heading"], dict(state["enabled"])


def estimator_for(name: str | ekf.Estimator, settings: EKFSettings | None = None,
                  sensors: tuple[str, ...] | list[str] = SENSORS) -> ekf.Estimator:
    """The estimator a name stands for: a built-in (ekf.ESTIMATORS, through ekf.make_estimator),
    a user's filter (FILE.py or a MATLAB filter; raises UserFilterError, a ConfigError naming the
    file and line, when it cannot be loaded), or an estimator object as it is."""
    if not isinstance(name, str):
        return name
    if name not in ekf.ESTIMATORS and is_filter_file(name):
        return UserFilterEstimator(name, settings, sensors)
    return ekf.make_estimator(name, settings, sensors)
