"""The EKF's state, declared once: every field with its shape, kind, initial value and meaning.

:class:`EKFState` is what the readable filter (``ekf.reference``) keeps and works on, field by
field; the compiled filter (``ekf.fast``) packs the same fields into one float64 array whose
layout is generated from this declaration (``ekf.fast.layout``). A snapshot's ``"state"`` is
:func:`state_dict` of it, the same for both, so either restores into the other.

Conventions: "none" is explicit: a vector with a ``*_valid`` flag, a time that is NaN (not yet)
or -inf (never, so any period since it has passed). x and P have their largest size (7); with
model 4a (``n`` = 4) only their leading block is used and the rest stays zero.

The helpers (:func:`state_field`, :func:`state_dict`, :func:`load_state`) work for any such
dataclass, so other estimators declare their state the same way.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, Callable, Mapping

import numpy as np

from ekf.diagnostics import Diagnostics, Flags
from ekf.settings import EKFSettings

Init = Callable[[EKFSettings, Mapping[str, bool]], Any]


def state_field(doc: str, init: Init, *, unit: str = "-", shape: tuple[int, ...] = (),
                kind: type = float) -> Any:
    """A state field: `init(settings, enabled)` gives its value after reset; `kind` is float,
    bool or int for a number (shape ()), float for an array, or an outputs dataclass."""
    return field(metadata={"doc": doc, "unit": unit, "shape": shape, "kind": kind,
                           "init": init})


# ---- initial values ---------------------------------------------------------------------------
def _value(v: float | bool) -> Init:
    return lambda settings, enabled: v


def _zeros3(settings: EKFSettings, enabled: Mapping[str, bool]) -> np.ndarray:
    return np.zeros(3)


def _enabled(sensor: str) -> Init:
    return lambda settings, enabled: bool(enabled[sensor])


def state_size(settings: EKFSettings) -> int:
    """n: 7 with the gyro bias in the state (model 4c), else 4 (model 4a)."""
    return 7 if settings.estimate_gyro_bias else 4


def _initial_x(settings: EKFSettings, enabled: Mapping[str, bool]) -> np.ndarray:
    x = np.zeros(7)
    x[0] = 1.0
    if state_size(settings) == 7:
        x[4:] = settings.gyr_bias
    return x


def _initial_P(settings: EKFSettings, enabled: Mapping[str, bool]) -> np.ndarray:
    n = state_size(settings)
    P = np.zeros((7, 7))
    P[:n, :n] = np.eye(n)
    return P


def _initial_m0(settings: EKFSettings, enabled: Mapping[str, bool]) -> np.ndarray:
    return np.zeros(3) if settings.m0 is None else np.asarray(settings.m0, float).reshape(3).copy()


def _initial_strength(settings: EKFSettings, enabled: Mapping[str, bool]) -> float:
    return math.nan if settings.m0 is None else float(np.linalg.norm(_initial_m0(settings, enabled)))


def reference_dip_deg(m0: np.ndarray) -> float:
    """Angle between up and the field m0 (ENU) [deg]."""
    return math.degrees(math.acos(m0[2] / (np.linalg.norm(m0) + 1e-300)))


def _initial_diagnostics(settings: EKFSettings, enabled: Mapping[str, bool]) -> Diagnostics:
    dip = math.nan if settings.m0 is None else reference_dip_deg(_initial_m0(settings, enabled))
    return Diagnostics(g=settings.g, acc_gate=settings.acc_gate, mag_gate=settings.mag_gate,
                       mag_reference_dip_deg=dip)


_NAN = _value(math.nan)
_NEVER = _value(-math.inf)
_FALSE = _value(False)


@dataclass(eq=False)
class EKFState:
    """Everything the EKF needs to continue from here (model 4a: x = q; 4c: x = (q, b_w))."""

    # --- clock and switches --------------------------------------------------------------------
    t: float = state_field("time of the latest sample; NaN: none yet", _NAN, unit="s")
    gyr_enabled: bool = state_field("the gyroscope is switched in", _enabled("gyr"), kind=bool)
    acc_enabled: bool = state_field("the accelerometer is switched in", _enabled("acc"), kind=bool)
    mag_enabled: bool = state_field("the magnetometer is switched in", _enabled("mag"), kind=bool)
    initialised: bool = state_field("the orientation has been started from the first readings",
                                    _FALSE, kind=bool)
    heading_from_mag: bool = state_field("the heading has been taken from the magnetometer",
                                         _FALSE, kind=bool)

    # --- the estimate ----------------------------------------------------------------------------
    n: int = state_field("size of x in use: 4 (model 4a, x = q) or 7 (model 4c, x = (q, b_w))",
                         lambda settings, enabled: state_size(settings), kind=int)
    x: np.ndarray = state_field("q (w first, sensor -> ENU, w >= 0), then the gyro bias b_w "
                                "[rad/s] (zero when n = 4)", _initial_x, shape=(7,))
    P: np.ndarray = state_field("covariance of x; the leading n x n block is used, the rest is "
                                "zero", _initial_P, shape=(7, 7))

    # --- the latest samples --------------------------------------------------------------------
    omega: np.ndarray = state_field("latest gyroscope sample, bias not removed", _zeros3,
                                    unit="rad/s", shape=(3,))
    omega_valid: bool = state_field("omega holds a sample", _FALSE, kind=bool)
    omega_t: float = state_field("time of omega", _NEVER, unit="s")
    last_acc: np.ndarray = state_field("latest accelerometer sample", _zeros3, unit="m/s²",
                                       shape=(3,))
    last_acc_valid: bool = state_field("last_acc holds a sample", _FALSE, kind=bool)
    last_acc_t: float = state_field("time of last_acc", _NEVER, unit="s")
    last_mag: np.ndarray = state_field("latest magnetometer sample", _zeros3, unit="µT",
                                       shape=(3,))
    last_mag_valid: bool = state_field("last_mag holds a sample", _FALSE, kind=bool)
    last_mag_t: float = state_field("time of last_mag", _NEVER, unit="s")

    # --- the magnetic field reference (tasks 9 and 11) -----------------------------------------
    m0: np.ndarray = state_field("Earth field in ENU (0, horizontal, vertical) (setting m0, or "
                                 "from the first reading)", _initial_m0, unit="µT", shape=(3,))
    m0_valid: bool = state_field("m0 is known", lambda settings, enabled: settings.m0 is not None,
                                 kind=bool)
    mag_strength: float = state_field("L_k, the AR(1) field strength; NaN: unknown",
                                      _initial_strength, unit="µT")
    mag_passing_since: float = state_field("readings have passed the gates since then (settling);"
                                           " NaN: the latest was rejected", _NEVER, unit="s")
    mag_rejected_since: float = state_field("rejected readings agree with each other since then "
                                            "(re-learning); NaN: not rejecting", _NAN, unit="s")
    mag_candidate_norm: float = state_field("running strength of those rejected readings", _NAN,
                                            unit="µT")
    mag_candidate_dip: float = state_field("their running dip", _NAN, unit="deg")
    mag_offset: np.ndarray = state_field("the online hard-iron estimate b_m, subtracted from "
                                         "every reading (mag_hard_iron_tau_s)", _zeros3,
                                         unit="µT", shape=(3,))
    mag_offset_fit: np.ndarray = state_field("the fit's least-squares offset; b_m is it where it "
                                             "explains readings the field would reject, else 0",
                                             _zeros3, unit="µT", shape=(3,))
    mag_offset_info: np.ndarray = state_field("its normal matrix Σ w Dᵀ D (forgetting)",
                                              lambda settings, enabled: np.zeros((3, 3)),
                                              shape=(3, 3))
    mag_offset_rhs: np.ndarray = state_field("its right-hand side Σ w Dᵀ e", _zeros3, unit="µT",
                                             shape=(3,))
    mag_offset_t: float = state_field("time of the latest pair in the fit", _NAN, unit="s")
    mag_offset_prior: np.ndarray = state_field("the offset the fit is drawn to: 0, or the phone's "
                                               "own hard iron once acquired", _zeros3, unit="µT",
                                               shape=(3,))
    mag_acquiring: bool = state_field("the readings were beyond any Earth field: the offset is "
                                      "being acquired (fit unweighted, no prior) until every "
                                      "direction of it is known", _value(False), kind=bool)
    mag_waiting: bool = state_field("the magnetometer waits for the acquisition to know the "
                                    "offset where it turns the heading", _value(False), kind=bool)
    mag_restart_info: np.ndarray = state_field("the second fit's normal matrix Σ Dᵀ D over the "
                                               "recent pairs since one the fit did not explain",
                                               lambda settings, enabled: np.zeros((3, 3)),
                                               shape=(3, 3))
    mag_restart_rhs: np.ndarray = state_field("its right-hand side Σ Dᵀ e", _zeros3, unit="µT",
                                              shape=(3,))
    mag_restart_sq: float = state_field("its Σ |e|²", _value(0.0), unit="µT²")
    mag_restart_n: float = state_field("its (forgotten) count of pairs", _value(0.0))
    mag_restart_t: float = state_field("time of its latest pair (or of the one that opened it); "
                                       "NaN: none open", _NAN, unit="s")
    mag_pair_raw: np.ndarray = state_field("the first reading of the open pair (raw)", _zeros3,
                                           unit="µT", shape=(3,))
    mag_pair_q: np.ndarray = state_field("the turn since that reading, integrated from the "
                                         "gyroscope (F of every time update)",
                                         lambda settings, enabled: np.array([1.0, 0, 0, 0]),
                                         shape=(4,))
    mag_pair_t: float = state_field("time of that reading; NaN: no open pair", _NAN, unit="s")
    mag_candidate_world: np.ndarray = state_field(
        "running world-frame vector of the rejected readings (mag_relearn_world)", _zeros3,
        unit="µT", shape=(3,))
    mag_candidate_time: float = state_field("time those readings have agreed while the phone "
                                            "turned (mag_relearn_world)", _value(0.0), unit="s")
    mag_candidate_t: float = state_field("time of the latest candidate reading", _NAN, unit="s")
    mag_updated_t: float = state_field("time of the latest magnetometer update", _NEVER, unit="s")
    mag_dev_sq: float = state_field("low-pass of (‖y_m‖ − L_k)² (mag_noise_adapt)", _value(0.0),
                                    unit="µT²")
    mag_dev_t: float = state_field("time of the latest reading in mag_dev_sq", _NAN, unit="s")
    mag_disturbed_time: float = state_field("disturbance time counted against "
                                            "mag_max_reject_no_gyro_s (rejected or settling "
                                            "readings)",
                                            _value(0.0), unit="s")
    mag_disturbed_t: float = state_field("time of the latest reading when it was rejected; NaN: "
                                         "it passed", _NAN, unit="s")
    mag_passed_t: float = state_field("time of the latest reading that passed", _NAN, unit="s")
    mag_confirmed_time: float = state_field("how long readings have passed the gates of the "
                                            "learned field in all (mag_first_relearn_s)",
                                            _value(0.0), unit="s")
    mag_reference_until: float = state_field("the expected field is learned from the readings "
                                             "until then (mag_reference_s); -inf: done",
                                             _NEVER, unit="s")
    mag_reference_sum: np.ndarray = state_field("sum of those readings in the world frame",
                                                _zeros3, unit="µT", shape=(3,))
    mag_reference_norm_sum: float = state_field("sum of their strengths", _value(0.0), unit="µT")
    mag_reference_count: float = state_field("how many readings are in the sums", _value(0.0))

    # --- the accelerometer low-pass carried by the gyroscope ------------------------------------
    acc_carried: np.ndarray = state_field("low-passed specific force in the current body frame",
                                          _zeros3, unit="m/s²", shape=(3,))
    acc_carried_valid: bool = state_field("acc_carried holds an average", _FALSE, kind=bool)
    acc_carried_t: float = state_field("time of the latest reading blended into acc_carried",
                                       _NAN, unit="s")
    acc_updated_t: float = state_field("time of the latest accelerometer update", _NEVER, unit="s")
    acc_dev_sq: float = state_field("low-pass of (‖y_a‖ − g)² (acc_noise_adapt)", _value(0.0),
                                    unit="(m/s²)²")
    acc_dev_t: float = state_field("time of the latest reading in acc_dev_sq", _NAN, unit="s")
    acc_axis_max: float = state_field("largest |axis| of the accelerometer readings so far (the "
                                      "range detected from the data, acc_range = 0)",
                                      _value(0.0), unit="m/s²")

    # --- rest detection ------------------------------------------------------------------------
    acc_lowpass: np.ndarray = state_field("low-pass of the accelerometer for rest detection",
                                          _zeros3, unit="m/s²", shape=(3,))
    acc_lowpass_valid: bool = state_field("acc_lowpass holds an average", _FALSE, kind=bool)
    last_motion_t: float = state_field("time of the latest sample that was not still", _NEVER,
                                       unit="s")
    rest_updated_t: float = state_field("time of the latest zero-rate update", _NEVER, unit="s")

    # --- what the filter did with its latest samples -------------------------------------------
    flags: Flags = state_field("the lights and which sensors were used",
                               lambda settings, enabled: Flags(), kind=Flags)
    diagnostics: Diagnostics = state_field("the numbers behind the flags", _initial_diagnostics,
                                           kind=Diagnostics)

    @classmethod
    def initial(cls, settings: EKFSettings, enabled: Mapping[str, bool]) -> "EKFState":
        """The state after reset, built from the declaration."""
        return initial_state(cls, settings, enabled)


# ---- generic helpers over a declared state ----------------------------------------------------
def initial_state(cls: type, settings: EKFSettings, enabled: Mapping[str, bool]) -> Any:
    """An instance of the declared state dataclass `cls` with every field's initial value."""
    return cls(**{f.name: f.metadata["init"](settings, enabled) for f in fields(cls)})


def state_dict(state: Any) -> dict[str, Any]:
    """A copy of a declared state as {field name: value}: arrays copied, numbers as their
    declared kind (float, bool, int), outputs copied."""
    out: dict[str, Any] = {}
    for f in fields(state):
        kind, value = f.metadata["kind"], getattr(state, f.name)
        if is_dataclass(kind):
            out[f.name] = copy.copy(value)
        elif f.metadata["shape"]:
            out[f.name] = np.array(value, dtype=float)
        else:
            out[f.name] = kind(value)
    return out


def check_state(cls: type, state: Mapping[str, Any]) -> None:
    """ValueError naming what is wrong when `state` does not fit the declaration of `cls`."""
    if not isinstance(state, Mapping):
        raise ValueError(f"snapshot state must be a dict, got {type(state).__name__}")
    names = [f.name for f in fields(cls)]
    missing = [n for n in names if n not in state]
    unknown = sorted(set(state) - set(names))
    if missing or unknown:
        parts = []
        if missing:
            parts.append(f"missing {', '.join(missing)}")
        if unknown:
            parts.append(f"unknown {', '.join(unknown)}")
        raise ValueError(f"snapshot state does not fit {cls.__name__}: {'; '.join(parts)}")
    for f in fields(cls):
        kind, shape, value = f.metadata["kind"], f.metadata["shape"], state[f.name]
        if is_dataclass(kind):
            if not isinstance(value, kind):
                raise ValueError(f"snapshot state {f.name!r} must be {kind.__name__}, "
                                 f"got {type(value).__name__}")
            continue
        got = np.shape(value)
        if got != shape:
            raise ValueError(f"snapshot state {f.name!r} must have shape {shape}, got {got}")
        if not np.issubdtype(np.asarray(value).dtype, np.number) and \
                np.asarray(value).dtype != np.bool_:
            raise ValueError(f"snapshot state {f.name!r} must be numeric")


def upgrade_state(cls: type, state: Any) -> Any:
    """A state saved by an earlier version in today's form (a session's start_state, a
    checkpoint). EKFState's mag_disturbed_since (the time the disturbance began; NaN: none)
    became the counted mag_disturbed_time with the times of the latest readings; a state saved
    before mag_confirmed_time existed counts a field it had learned as confirmed (it filtered
    with that field before); one saved before the raw magnetometer's acquisition existed was
    not acquiring (offset drawn to 0); one saved before the fit kept its own least-squares
    offset has that offset as its fit; one saved when the fit restarted after five unexplained
    pairs in a row (``mag_offset_outliers``) has no second fit open. Anything else is returned
    as it is (and checked as usual)."""
    if cls is not EKFState or not isinstance(state, Mapping):
        return state
    out = dict(state)
    if "mag_disturbed_since" in out:
        since, now = float(out.pop("mag_disturbed_since")), float(state.get("t", math.nan))
        disturbed = math.isfinite(since) and math.isfinite(now)
        out.setdefault("mag_disturbed_time", max(0.0, now - since) if disturbed else 0.0)
        out.setdefault("mag_disturbed_t", now if disturbed else math.nan)
        out.setdefault("mag_passed_t", math.nan)
    if "mag_confirmed_time" not in out and "m0_valid" in out:
        out["mag_confirmed_time"] = math.inf if bool(out["m0_valid"]) else 0.0
    if "mag_offset" in out and "mag_offset_fit" not in out:
        out["mag_offset_fit"] = np.asarray(out["mag_offset"], float).copy()
    out.pop("mag_offset_outliers", None)
    if "mag_offset" in out:
        out.setdefault("mag_restart_info", np.zeros((3, 3)))
        out.setdefault("mag_restart_rhs", np.zeros(3))
        out.setdefault("mag_restart_sq", 0.0)
        out.setdefault("mag_restart_n", 0.0)
        out.setdefault("mag_restart_t", math.nan)
    if "mag_offset" in out and "mag_waiting" not in out:
        out.setdefault("mag_offset_prior", np.zeros(3))
        out.setdefault("mag_acquiring", False)
        out["mag_waiting"] = False
    return out


def load_state(cls: type, state: Mapping[str, Any]) -> Any:
    """An instance of `cls` from a checked state dict (values copied and converted)."""
    check_state(cls, state)
    values: dict[str, Any] = {}
    for f in fields(cls):
        kind, value = f.metadata["kind"], state[f.name]
        if is_dataclass(kind):
            values[f.name] = copy.copy(value)
        elif f.metadata["shape"]:
            values[f.name] = np.array(value, dtype=float)
        else:
            values[f.name] = kind(value)
    return cls(**values)
