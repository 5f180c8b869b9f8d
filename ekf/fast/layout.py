"""The compiled filter's packed arrays, laid out from the declarations (never numbered by hand).

* ``S``: offsets into the float64 state array. One slot range per :class:`ekf.state.EKFState`
  field in declaration order (x: 7, P: 7x7 row-major, numbers: 1, booleans as 0.0/1.0), the
  :class:`~ekf.diagnostics.Flags` and :class:`~ekf.diagnostics.Diagnostics` fields by their own names,
  then the kernels' scratch (:data:`WORK`, not state: never packed or unpacked).
* ``C``: offsets into the float64 settings array: every numeric :class:`ekf.settings.EKFSettings`
  field (vectors 3, matrices 3x3 row-major, booleans 0.0/1.0, m0 None as NaN), then the derived
  coefficients (:data:`COEFFICIENTS`).

Both are namedtuples of ints; numba freezes a module-global namedtuple as compile-time constants,
so ``s[S.mag_strength]`` in a kernel costs what a literal offset costs. ``S.size`` and ``C.size``
are the array lengths. :func:`pack_state` / :func:`unpack_state` and :func:`pack_settings` are
generic loops over the same declarations; a snapshot's state is :func:`unpack_state`'s dict.
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import fields, is_dataclass
from typing import Any, Callable, Mapping

import numpy as np

from ekf.settings import EKFSettings
from ekf.state import EKFState

# Scratch of the compiled functions (not state): name, length, use.
WORK: tuple[tuple[str, int, str], ...] = (
    ("work_pht", 21, "B = P H^T (7x3, or 7 for the heading update)"),
    ("work_gain", 28, "rows of A P in the time update (4x7), or the gain K (7x3 or 7)"),
    ("work_s", 9, "S = H P H^T + R (3x3)"),
    ("work_s_inv", 9, "S^-1 (3x3)"),
    ("work_pred_x", 7, "x after the latest time update (recorded for the smoother)"),
    ("work_pred_P", 49, "P after the latest time update (recorded for the smoother)"),
    ("work_pred_T", 1, "its time step T [s]: 0 without a gyroscope (random walk), -1 none"),
    ("work_pred_omega", 3, "the gyroscope sample that drove it [rad/s]"),
)

# Settings the kernels read as numbers that are not fields: name, value from the settings, doc.
COEFFICIENTS: tuple[tuple[str, Callable[[EKFSettings], float], str], ...] = (
    ("mag_strength_always", lambda s: float(s.mag_strength_update == "always"),
     "mag_strength_update == 'always'"),
    ("mag_strength_accepted", lambda s: float(s.mag_strength_update == "accepted"),
     "mag_strength_update == 'accepted'"),
    ("gyr_noise_isotropic", lambda s: float(np.array_equal(
        np.asarray(s.gyr_noise_cov, float), s.gyr_noise_cov[0][0] * np.eye(3))),
     "R_w = r I: G R_w G^T has the closed form r (T/2)^2 (|q|^2 I - q q^T)"),
    ("record_prediction", lambda s: 0.0,
     "1: every time update copies x, P and T into work_pred_* (set by ekf.smooth_batch)"),
)


def _size(shape: tuple[int, ...]) -> int:
    return int(np.prod(shape)) if shape else 1


def _state_slots() -> tuple[list[tuple[str, int, tuple[int, ...], type]],
                            dict[str, tuple[type, list[tuple[str, int, type]]]], int]:
    """(name, offset, shape, kind) per plain field; per record field (Flags, Diagnostics) its
    class and (name, offset, kind) per member; the end offset of the state."""
    plain, records, offset = [], {}, 0
    for f in fields(EKFState):
        kind = f.metadata["kind"]
        if is_dataclass(kind):
            members = []
            for g in fields(kind):
                members.append((g.name, offset, g.metadata["kind"]))
                offset += 1
            records[f.name] = (kind, members)
        else:
            plain.append((f.name, offset, f.metadata["shape"], kind))
            offset += _size(f.metadata["shape"])
    return plain, records, offset


_PLAIN, _RECORDS, _STATE_END = _state_slots()


def _state_layout():
    names = [name for name, *_ in _PLAIN]
    offsets = [offset for _, offset, *_ in _PLAIN]
    for _, members in _RECORDS.values():
        names += [name for name, *_ in members]
        offsets += [offset for _, offset, _ in members]
    end = _STATE_END
    for name, length, _ in WORK:
        names.append(name)
        offsets.append(end)
        end += length
    if len(set(names)) != len(names):
        raise AssertionError("state, flags, diagnostics and work names must be distinct")
    return namedtuple("StateLayout", names + ["size"])(*offsets, end)


def _settings_slots() -> list[tuple[str, int, int]]:
    slots, offset = [], 0
    for f in fields(EKFSettings):
        if f.metadata["choices"]:
            continue   # a word: the kernels read its derived coefficients
        n = _size(f.metadata["shape"])
        slots.append((f.name, offset, n))
        offset += n
    for name, _, _ in COEFFICIENTS:
        slots.append((name, offset, 1))
        offset += 1
    return slots


_SETTINGS_SLOTS = _settings_slots()

S = _state_layout()
"""Offsets into the packed state (see the module docstring)."""
C = namedtuple("SettingsLayout", [n for n, _, _ in _SETTINGS_SLOTS] + ["size"])(
    *[o for _, o, _ in _SETTINGS_SLOTS], _SETTINGS_SLOTS[-1][1] + _SETTINGS_SLOTS[-1][2])
"""Offsets into the packed settings (see the module docstring)."""

STATE_SLOTS = _PLAIN
RECORD_SLOTS = _RECORDS


def pack_settings(settings: EKFSettings) -> np.ndarray:
    """The settings as the float64 array the compiled functions read (layout ``C``)."""
    c = np.empty(C.size)
    coefficients = {name: value for name, value, _ in COEFFICIENTS}
    for name, offset, n in _SETTINGS_SLOTS:
        if name in coefficients:
            c[offset] = coefficients[name](settings)
            continue
        value = getattr(settings, name)
        c[offset:offset + n] = np.nan if value is None else np.asarray(value, float).reshape(n)
    return c


def pack_state(state: Mapping[str, Any], out: np.ndarray | None = None) -> np.ndarray:
    """A state dict (``ekf.state.state_dict`` form, checked) into the packed array (layout
    ``S``); the work area is zeroed."""
    s = np.zeros(S.size) if out is None else out
    s[_STATE_END:] = 0.0
    for name, offset, shape, _ in _PLAIN:
        s[offset:offset + _size(shape)] = np.asarray(state[name], float).reshape(-1)
    for record, (_, members) in _RECORDS.items():
        value = state[record]
        for name, offset, _ in members:
            s[offset] = float(getattr(value, name))
    return s


def unpack_record(s: np.ndarray, record: str) -> Any:
    """The Flags or Diagnostics held in the packed state, as a plain dataclass."""
    cls, members = _RECORDS[record]
    return cls(**{name: kind(s[offset]) for name, offset, kind in members})


def unpack_state(s: np.ndarray) -> dict[str, Any]:
    """The packed state as a state dict (arrays copied; numbers as float, bool or int)."""
    out: dict[str, Any] = {}
    for name, offset, shape, kind in _PLAIN:
        if shape:
            out[name] = s[offset:offset + _size(shape)].reshape(shape).copy()
        else:
            out[name] = kind(s[offset])
    for record in _RECORDS:
        out[record] = unpack_record(s, record)
    return out


def describe() -> str:
    """The layouts as text (names and offsets): what the compiled kernels were built against."""
    return repr(S) + repr(C)
