"""The one interface every estimator meets, the plumbing they share, and batch results.

* :class:`Estimator`: a ``typing.Protocol`` (runtime-checkable) that both EKFs, the comparison
  estimators and filters that users write in Python satisfy; callers never ask ``hasattr``.
* :class:`EstimatorBase`: settings and switches, time, flags and diagnostics, snapshots, and a
  ``run_batch`` that is a Python loop over ``step``, for estimators whose state is a declared
  dataclass (see ``ekf.state``). A compiled estimator overrides what it does faster.
* :class:`BatchResult`: what ``run_batch`` and ``ekf.filter_batch`` return.

Snapshot format, the same for every estimator::

    {"estimator": name, "settings": EKFSettings, "state": {field name: value}}

where the state's values are numpy arrays, numbers, and :class:`~ekf.diagnostics.Flags` /
:class:`~ekf.diagnostics.Diagnostics` copies. ``restore`` checks keys and shapes and raises
ValueError naming what is wrong.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Mapping, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from ekf.diagnostics import Diagnostics, Flags
from ekf.settings import PRESETS, EKFSettings, resolve_settings
from ekf.state import check_state, initial_state, load_state, state_dict, upgrade_state

SENSORS = ("gyr", "acc", "mag")


@dataclass
class BatchResult:
    """Per row: t_s (N,) [s]; quat (N, 4) w-first sensor -> ENU, w >= 0; the flags (N,) after
    the row; gyro_bias (N, 3) [rad/s], the estimate (or the fixed setting) after the row."""

    t_s: np.ndarray
    quat: np.ndarray
    acc_rejected: np.ndarray
    mag_rejected: np.ndarray
    at_rest: np.ndarray
    gyro_bias: np.ndarray | None = None


@runtime_checkable
class Estimator(Protocol):
    """What every orientation estimator offers (units: s, rad/s, m/s^2, uT; quaternions w-first,
    sensor -> ENU, w >= 0)."""

    name: str
    settings: EKFSettings

    @property
    def quat(self) -> np.ndarray: ...          # (4,)

    @property
    def cov(self) -> np.ndarray | None: ...    # covariance of the state, or None

    @property
    def gyro_bias(self) -> np.ndarray: ...     # (3,) [rad/s]

    @property
    def flags(self) -> Flags: ...              # a copy

    @property
    def diagnostics(self) -> Diagnostics: ...  # a copy

    @property
    def enabled(self) -> dict[str, bool]: ...  # gyr/acc/mag -> switched in

    @property
    def initialised(self) -> bool: ...

    @property
    def time(self) -> float | None: ...        # of the latest sample [s]; None before the first

    def set_enabled(self, gyr: bool | None = None, acc: bool | None = None,
                    mag: bool | None = None) -> None: ...

    def set_settings(self, settings: EKFSettings) -> None: ...

    def reset(self) -> None: ...

    def align_heading(self, q_ref: ArrayLike) -> None: ...

    def step(self, t: float, gyr: ArrayLike | None = None, acc: ArrayLike | None = None,
             mag: ArrayLike | None = None) -> None: ...

    def run_batch(self, t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
                  mag: ArrayLike | None) -> BatchResult: ...

    def snapshot(self) -> dict[str, Any]: ...

    def restore(self, snapshot: Mapping[str, Any]) -> None: ...


def batch_rows(t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
               mag: ArrayLike | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """t (N,) and gyr, acc, mag (N, 3) as contiguous float arrays; None: a sensor without any
    sample (all NaN). ValueError for a wrong shape."""
    t = np.ascontiguousarray(t_s, dtype=float).reshape(-1)
    n = t.shape[0]
    out = []
    for a in (gyr, acc, mag):
        if a is None:
            out.append(np.full((n, 3), np.nan))
            continue
        a = np.ascontiguousarray(a, dtype=float)
        if a.shape != (n, 3):
            raise ValueError(f"sensor array must have shape ({n}, 3), got {a.shape}")
        out.append(a)
    return t, out[0], out[1], out[2]


def ekf_name(settings: EKFSettings) -> str:
    """The EKF's estimator name: "course" with the course preset itself, else "ekf"."""
    return "course" if settings is PRESETS["course"] else "ekf"


class EstimatorBase:
    """Shared plumbing of the estimators that keep their state in a declared dataclass.

    A subclass sets :attr:`state_class` (fields declared with ``ekf.state.state_field``, among
    them ``t``, ``initialised``, ``gyr_enabled``, ``acc_enabled``, ``mag_enabled``, ``flags`` and
    ``diagnostics``), and implements ``quat``, ``gyro_bias``, ``align_heading`` and ``step``.
    """

    name = "estimator"
    state_class: type
    compatible: tuple[str, ...] = ()
    """Other estimator names whose snapshots this one restores (same state declaration)."""

    def __init__(self, settings: EKFSettings | str | None = None,
                 sensors: tuple[str, ...] | list[str] = SENSORS) -> None:
        self.settings: EKFSettings = resolve_settings(settings)
        self._set_state(self._initial_state({s: (s in sensors) for s in SENSORS}))

    # ---- public state -----------------------------------------------------------------------
    @property
    def cov(self) -> np.ndarray | None:
        return None

    @property
    def flags(self) -> Flags:
        return replace(self._state.flags)

    @property
    def diagnostics(self) -> Diagnostics:
        return replace(self._state.diagnostics)

    @property
    def enabled(self) -> dict[str, bool]:
        st = self._state
        return {"gyr": st.gyr_enabled, "acc": st.acc_enabled, "mag": st.mag_enabled}

    @property
    def initialised(self) -> bool:
        return self._state.initialised

    @property
    def time(self) -> float | None:
        return None if math.isnan(self._state.t) else self._state.t

    # ---- control ------------------------------------------------------------------------------
    def set_enabled(self, gyr: bool | None = None, acc: bool | None = None,
                    mag: bool | None = None) -> None:
        """Switch sensors in or out; takes effect at the next sample."""
        st = self._state
        if gyr is not None:
            st.gyr_enabled = bool(gyr)
        if acc is not None:
            st.acc_enabled = bool(acc)
        if mag is not None:
            st.mag_enabled = bool(mag)

    def set_settings(self, settings: EKFSettings) -> None:
        """Use new settings from the next sample on."""
        self.settings = settings

    def reset(self) -> None:
        """Forget everything but settings and switches; re-initialise from the next samples."""
        self._set_state(self._initial_state(self.enabled))

    # ---- snapshots ----------------------------------------------------------------------------
    def snapshot(self) -> dict[str, Any]:
        """Everything needed to continue later from exactly here (a copy)."""
        return {"estimator": self.name, "settings": self.settings, "state": self._get_state()}

    def restore(self, snapshot: Mapping[str, Any]) -> None:
        """Continue from a snapshot (of this estimator, or of one with the same state; one
        saved by an earlier version is brought up to date first, ``ekf.state.upgrade_state``)."""
        if isinstance(snapshot, Mapping) and "state" in snapshot:
            snapshot = {**snapshot, "state": upgrade_state(self.state_class, snapshot["state"])}
        self._check_snapshot(snapshot)
        self._set_state(snapshot["state"])
        self.settings = snapshot["settings"]
        self.name = snapshot["estimator"]

    def _check_snapshot(self, snapshot: Mapping[str, Any]) -> None:
        if not isinstance(snapshot, Mapping):
            raise ValueError(f"a snapshot is a dict, got {type(snapshot).__name__}")
        keys = {"estimator", "settings", "state"}
        if set(snapshot) != keys:
            raise ValueError(f"a snapshot has the keys {sorted(keys)}, got {sorted(snapshot)}")
        name = snapshot["estimator"]
        if name != self.name and name not in self.compatible:
            raise ValueError(f"a snapshot of estimator {name!r} cannot restore into {self.name!r}")
        if not isinstance(snapshot["settings"], EKFSettings):
            raise ValueError("snapshot settings must be EKFSettings, got "
                             f"{type(snapshot['settings']).__name__}")
        check_state(self.state_class, snapshot["state"])

    def _initial_state(self, enabled: Mapping[str, bool]) -> dict[str, Any]:
        """The state after reset, from the declaration of :attr:`state_class`."""
        return state_dict(initial_state(self.state_class, self.settings, enabled))

    def _get_state(self) -> dict[str, Any]:
        return state_dict(self._state)

    def _set_state(self, state: Mapping[str, Any]) -> None:
        self._state = load_state(self.state_class, state)

    # ---- samples ------------------------------------------------------------------------------
    def step(self, t: float, gyr: ArrayLike | None = None, acc: ArrayLike | None = None,
             mag: ArrayLike | None = None) -> None:
        raise NotImplementedError

    def run_batch(self, t_s: ArrayLike, gyr: ArrayLike | None, acc: ArrayLike | None,
                  mag: ArrayLike | None) -> BatchResult:
        """Feed all rows as `step` would (a NaN row: no such sample) and return per-row results;
        continues from the current state."""
        t, g, a, m = batch_rows(t_s, gyr, acc, mag)
        n = t.shape[0]
        out_q = np.empty((n, 4))
        out_bias = np.empty((n, 3))
        acc_rejected = np.zeros(n, bool)
        mag_rejected = np.zeros(n, bool)
        at_rest = np.zeros(n, bool)
        has_g, has_a, has_m = (~np.isnan(x).any(axis=1) for x in (g, a, m))
        for k in range(n):
            self.step(t[k], g[k] if has_g[k] else None, a[k] if has_a[k] else None,
                      m[k] if has_m[k] else None)
            out_q[k] = self.quat
            out_bias[k] = self.gyro_bias
            flags = self.flags
            acc_rejected[k] = flags.acc_rejected
            mag_rejected[k] = flags.mag_rejected
            at_rest[k] = flags.at_rest
        return BatchResult(t, out_q, acc_rejected, mag_rejected, at_rest, gyro_bias=out_bias)
