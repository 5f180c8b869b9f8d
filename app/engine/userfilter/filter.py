"""Your own filter as an estimator: :class:`UserFilterEstimator` wraps a user's ``Filter`` class
(see :mod:`app.engine.userfilter.code`) in the ``ekf.Estimator`` protocol, so it runs wherever an
estimator runs: beside ours in the live engine (YOURS), over a log in `filter` and `evaluate`
(``--estimator FILE.py``), in replays.

The contract, from the user's side::

    class Filter:
        def __init__(self, settings=None): ...          # optional: the active settings
        def step(self, t, gyr, acc, mag):                # t [s] on the phone's clock; each
            ...                                          # sensor a (3,) array or None
            return q                                     # (w, x, y, z), sensor -> ENU
            # or {"q": q, "P": P, "acc_disturbed": bool, "mag_disturbed": bool,
            #     "standstill": bool, "innovations": {"acc": (nu, S), "mag": (nu, S)}}

Errors never escape: an exception in the user's code or a return value that breaks the contract
*pauses* the filter (:attr:`UserFilterEstimator.problem` says where and what; loading the file
again un-pauses it); ``NotImplementedError`` means "not written yet": that step (or that sample)
is skipped and noted. Time in the user's code is measured per call; a call that does not come
back within ``step_limit_s`` (an endless loop) is stopped where it is and pauses the filter like
an exception (app.engine.userfilter.watchdog).

The user's code runs in this process with this process's rights: it is the user's own program.
"""

from __future__ import annotations

import copy
import math
import time
from collections import deque
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from numpy.typing import ArrayLike

import ekf
import ekf.quaternion as quat
from ekf import SENSORS
from ekf.estimator import batch_rows
from ekf.settings import EKFSettings, resolve_settings
from app.engine.snapshot import UserProblem
from app.engine.userfilter.code import (USER_ERRORS, BadOutput, FilterCode, Output, UserFilterError,
                                  instantiate, is_filter_file, load_code, output_problem,
                                  parse_output, problem_from_exception)
from app.engine.userfilter.watchdog import DEFAULT_LIMIT_S, UserCodeTimeout, guard

__all__ = ["UserFilterEstimator", "UserFilterError", "filter_settings", "is_filter_file",
           "make_estimator"]

RECENT_WEIGHT = 0.02          # of the latest call in the running time per call
MAX_NOTES = 20


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


def _vector(value: ArrayLike) -> np.ndarray:
    return np.array(value, dtype=float).reshape(3)


def _left_matrix(r: np.ndarray) -> np.ndarray:
    """L(r) with r ⊗ q = L(r) q."""
    w, x, y, z = r
    return np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])


class UserFilterEstimator:
    """``ekf.Estimator`` around a user's Filter (a file path or a loaded FilterCode).

    Loading raises :class:`UserFilterError` when the file cannot be used at all; everything
    later is caught: :attr:`problem` (None while running), :meth:`missing_steps`,
    :attr:`notes`, :attr:`time_per_call_s`. With :attr:`collect_innovations`, the returned
    innovations are kept in :attr:`innovations` as (t, sensor, nu, S, accepted) for the
    consistency view (bounded).
    """

    def __init__(self, source: str | Path | FilterCode, settings: EKFSettings | str | None = None,
                 sensors: tuple[str, ...] | list[str] = SENSORS) -> None:
        self.code = source if isinstance(source, FilterCode) else load_code(source)
        self.name = self.code.name
        self.settings: EKFSettings = resolve_settings(settings)
        self._enabled = {s: s in tuple(sensors) for s in SENSORS}
        self.problem: UserProblem | None = None
        self.notes: list[str] = []
        self.collect_innovations = False
        self.innovations: deque[tuple] = deque(maxlen=50_000)
        self.calls = 0
        self.seconds = 0.0
        self.time_per_call_s = math.nan
        self._heading = 0.0
        self.step_limit_s = DEFAULT_LIMIT_S
        self._guard = guard(self.step_limit_s, "step()")
        self._start()

    # ---- the user's object --------------------------------------------------------------------
    def _start(self) -> None:
        self._t = math.nan
        self._out: Output | None = None
        self._used = (False, False, False)
        self.filter: Any = None
        try:
            self.filter = instantiate(self.code, filter_settings(self.settings))
        except UserFilterError as error:
            self.problem = error.problem

    @property
    def paused(self) -> bool:
        return self.problem is not None or self.filter is None

    def missing_steps(self) -> list[str]:
        return self.code.missing_steps()

    def _note(self, text: str) -> None:
        if text not in self.notes and len(self.notes) < MAX_NOTES:
            self.notes.append(text)

    # ---- Estimator: public state ----------------------------------------------------------------
    @property
    def output(self) -> Output | None:
        """The latest accepted return value (None before the first)."""
        return self._out

    @property
    def quat(self) -> np.ndarray:
        if self._out is None:
            return quat.IDENTITY.copy()
        q = self._out.q
        if self._heading:
            q = quat.normalize(quat.multiply(quat.from_axis_angle([0, 0, 1], self._heading), q))
        return q.copy()

    @property
    def cov(self) -> np.ndarray | None:
        """P's quaternion block (4x4) when the filter returns P (turned with align_heading)."""
        if self._out is None or self._out.P is None:
            return None
        P = self._out.P[:4, :4].copy()
        if self._heading:
            L = _left_matrix(quat.from_axis_angle([0, 0, 1], self._heading))
            P = L @ P @ L.T
        return P

    @property
    def gyro_bias(self) -> np.ndarray:
        return np.asarray(self.settings.gyr_bias, float)

    @property
    def flags(self) -> ekf.Flags:
        out = self._out
        g, a, m = self._used
        if out is None:
            return ekf.Flags(used_gyr=g, used_acc=a, used_mag=m)
        return ekf.Flags(acc_rejected=bool(out.acc_disturbed), mag_rejected=bool(out.mag_disturbed),
                         at_rest=bool(out.standstill), used_gyr=g, used_acc=a, used_mag=m)

    @property
    def diagnostics(self) -> ekf.Diagnostics:
        s = self.settings
        d = ekf.Diagnostics(g=s.g, acc_gate=s.acc_gate, mag_gate=s.mag_gate)
        if self._out is not None:
            for sensor, (nu, S, _) in self._out.innovations.items():
                if sensor in ("acc", "mag"):
                    setattr(d, f"{sensor}_nis", _nis(nu, S))
        return d

    @property
    def enabled(self) -> dict[str, bool]:
        return dict(self._enabled)

    @property
    def initialised(self) -> bool:
        return self._out is not None

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
        self._start_keeping_problem()

    def reset(self) -> None:
        """A new Filter object: the user's filter starts afresh from the next samples."""
        self._start_keeping_problem()

    def _start_keeping_problem(self) -> None:
        problem = self.problem
        self._start()
        self.problem = self.problem or problem

    def align_heading(self, q_ref: ArrayLike) -> None:
        """Turn the output about world up so its heading matches q_ref's (the user's state
        is the user's: the turn is applied to what it returns)."""
        if self._out is None:
            return
        self._heading += quat.heading_of(quat.multiply(np.asarray(q_ref, float),
                                                       quat.conjugate(self.quat)))

    # ---- Estimator: samples -----------------------------------------------------------------
    def step(self, t: float, gyr: ArrayLike | None = None, acc: ArrayLike | None = None,
             mag: ArrayLike | None = None) -> None:
        """Call the user's step with the samples at t (switched-off sensors as None)."""
        t = float(t)
        self._t = t
        if self.paused:
            return
        on = self._enabled
        args = (_vector(gyr) if gyr is not None and on["gyr"] else None,
                _vector(acc) if acc is not None and on["acc"] else None,
                _vector(mag) if mag is not None and on["mag"] else None)
        start = time.perf_counter()
        if self._guard.limit_s != self.step_limit_s:
            self._guard = guard(self.step_limit_s, "step()")
        try:
            with self._guard:
                result = self.filter.step(t, *args)
        except UserCodeTimeout as error:
            self._guard.disarm()
            self._timed(start)
            self.problem = problem_from_exception(error, self.code.path, t)
            return
        except NotImplementedError as error:
            self._timed(start)
            where = problem_from_exception(error, self.code.path, t)
            self.code.note_missing(where.function or "Filter.step", error)
            return
        except USER_ERRORS as error:   # noqa: BLE001 (the user's code: anything)
            self._timed(start)
            self.problem = problem_from_exception(error, self.code.path, t)
            return
        self._timed(start)
        try:
            out = parse_output(result, unnormalised_ok="mu_normalizeQ" in self.code.missing)
        except BadOutput as error:
            self.problem = output_problem(error, self.code, t)
            return
        except USER_ERRORS as error:   # noqa: BLE001 (an object of the user's that misbehaves)
            self.problem = problem_from_exception(error, self.code.path, t, kind="output")
            return
        self._accept(out, t, args)

    def _timed(self, start: float) -> None:
        spent = time.perf_counter() - start
        self.calls += 1
        self.seconds += spent
        recent = self.time_per_call_s
        self.time_per_call_s = spent if math.isnan(recent) else (
            recent + RECENT_WEIGHT * (spent - recent))

    def _accept(self, out: Output, t: float, args: tuple) -> None:
        self._out = out
        self._used = tuple(a is not None for a in args)
        for note in out.notes:
            self._note(note)
        if self.collect_innovations and out.innovations:
            for sensor, (nu, S, accepted) in out.innovations.items():
                if accepted is None:
                    disturbed = out.acc_disturbed if sensor == "acc" else (
                        out.mag_disturbed if sensor == "mag" else None)
                    accepted = not disturbed
                self.innovations.append((t, sensor, nu, S, bool(accepted)))

    def run_batch(self, t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
                  mag: ArrayLike | None) -> ekf.BatchResult:
        """Rows as `step` would take them (a NaN row: no such sample)."""
        t, g, a, m = batch_rows(t_s, gyr, acc, mag)
        n = t.shape[0]
        out_q = np.empty((n, 4))
        flags = np.zeros((n, 3), bool)
        has = [~np.isnan(x).any(axis=1) for x in (g, a, m)]
        for k in range(n):
            self.step(t[k], g[k] if has[0][k] else None, a[k] if has[1][k] else None,
                      m[k] if has[2][k] else None)
            out_q[k] = self.quat
            f = self.flags
            flags[k] = (f.acc_rejected, f.mag_rejected, f.at_rest)
        bias = np.broadcast_to(self.gyro_bias, (n, 3)).copy()
        return ekf.BatchResult(t, out_q, flags[:, 0].copy(), flags[:, 1].copy(),
                               flags[:, 2].copy(), gyro_bias=bias)

    # ---- Estimator: snapshots -----------------------------------------------------------------
    def snapshot(self) -> dict[str, Any]:
        """A deep copy of the user's object and of what this wrapper keeps (ValueError if the
        user's object cannot be copied)."""
        try:
            state = copy.deepcopy({"filter": self.filter, "output": self._out, "t": self._t,
                                   "heading": self._heading, "enabled": self._enabled,
                                   "used": self._used, "problem": self.problem})
        except USER_ERRORS as error:   # noqa: BLE001 (whatever the user's object holds)
            raise ValueError(f"{self.name}: its Filter object cannot be copied ({error})") \
                from None
        return {"estimator": self.name, "settings": self.settings, "state": state}

    def restore(self, snapshot: Mapping[str, Any]) -> None:
        if not isinstance(snapshot, Mapping) or set(snapshot) != {"estimator", "settings",
                                                                   "state"}:
            raise ValueError("a snapshot has the keys ['estimator', 'settings', 'state']")
        if snapshot["estimator"] != self.name:
            raise ValueError(f"a snapshot of estimator {snapshot['estimator']!r} cannot "
                             f"restore into {self.name!r}")
        state = copy.deepcopy(dict(snapshot["state"]))
        self.settings = snapshot["settings"]
        self.filter, self._out, self._t = state["filter"], state["output"], state["t"]
        self._heading, self._enabled = state["heading"], state["enabled"]
        self._used, self.problem = state["used"], state["problem"]


def _nis(nu: np.ndarray, S: np.ndarray) -> float:
    try:
        return float(nu @ np.linalg.solve(S, nu))
    except np.linalg.LinAlgError:
        return math.nan


def make_estimator(name: str | ekf.Estimator, settings: EKFSettings | None = None,
                   sensors: tuple[str, ...] | list[str] = SENSORS) -> ekf.Estimator:
    """An estimator by name: a built-in (ekf.ESTIMATORS), a user's filter file (FILE.py; raises
    UserFilterError when it cannot be loaded), or an estimator object as it is."""
    if not isinstance(name, str):
        return name
    if name not in ekf.ESTIMATORS and is_filter_file(name):
        return UserFilterEstimator(name, settings, sensors)
    return ekf.make_estimator(name, settings, sensors)
