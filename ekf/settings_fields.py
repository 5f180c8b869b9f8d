"""How a setting is declared and what it allows.

The declaration of an :class:`ekf.settings.EKFSettings` field with its metadata, the search
range a tuning search tries, and the check of a value.

:func:`_setting` declares a field with its unit, explanation and bounds (the metadata
:func:`ekf.settings.settings_rows` and the compiled filter's layout read); :func:`check_value`
turns a value into its stored form or raises :class:`SettingsError`, whose message
:func:`allowed_text` words. ``ekf.settings`` exports every public name of this module.
"""

from __future__ import annotations

import json
import math
from dataclasses import MISSING, field
from typing import Any, Callable, NamedTuple


def _setting(default: Any = MISSING, *, unit: str, doc: str, shape: tuple[int, ...] = (),
             choices: tuple[str, ...] | None = None,
             factory: Callable[[], Any] | None = None, low: float = 0.0, above: bool = False,
             high: float | None = None, inf: bool = False, matrix: str | None = None,
             optional: bool = False, search: tuple[float, ...] | None = None) -> Any:
    """A settings field with its unit ("-" when it has none), one-line explanation and what it
    allows: a number from ``low`` (excluded when ``above``) up to ``high``, infinity only with
    ``inf``; a vector of ``shape`` (``optional``: or none); a matrix that is ``"covariance"``
    (symmetric positive definite) or ``"invertible"``; a word from ``choices``. ``search``:
    the range a tuning search tries, ``(low, high)`` or ``(low, high, round_to)``
    (:class:`SearchRange`), inside what the setting allows."""
    metadata = {"unit": unit, "doc": doc, "shape": shape, "choices": choices, "low": low,
                "above": above, "high": high, "inf": inf, "matrix": matrix,
                "optional": optional, "search": None if search is None else SearchRange(*search)}
    if factory is not None:
        return field(default_factory=factory, metadata=metadata)
    return field(default=default, metadata=metadata)


class SearchRange(NamedTuple):
    """Where a tuning search (``tune``, the window's auto-tune, benchmarks/tune_defaults.py)
    looks for a setting: from ``low`` to ``high`` on a log scale (both positive; a covariance
    matrix as r·I, r in the range); ``round_to``: the step the default-tuning benchmark rounds
    its fit to (None: not searched there)."""

    low: float
    high: float
    round_to: float | None = None


class SettingsError(ValueError):
    """A setting's value is not one it allows; the message names the key, the value and what
    is allowed, on one line."""


def _kind(f: Any) -> str:
    if f.metadata["choices"]:
        return "word"
    if f.metadata["shape"] == (3, 3):
        return "matrix"
    if f.metadata["shape"] == (3,):
        return "vector"
    return "flag" if isinstance(f.default, bool) else "number"


def allowed_text(f: Any) -> str:
    """What a settings field allows, in words (error messages, docs/filter.md, the panel)."""
    meta, kind = f.metadata, _kind(f)
    if kind == "word":
        return " or ".join(repr(c) for c in meta["choices"])
    if kind == "flag":
        return "true or false"
    if kind == "matrix":
        return ("a symmetric positive-definite 3x3 matrix" if meta["matrix"] == "covariance"
                else "an invertible 3x3 matrix")
    if kind == "vector":
        text = "3 finite numbers"
        if f.name == "m0":
            text += " with a horizontal part ≥ 0.001"
        return ("none or " + text) if meta["optional"] else text
    bound = (f"> {meta['low']:g}" if meta["above"] else f"≥ {meta['low']:g}")
    if meta["high"] is not None:
        bound = (f"{meta['low']:g}..{meta['high']:g}" if not meta["above"]
                 else f"in ({meta['low']:g}, {meta['high']:g}]")
    return f'a number {bound} or "inf"' if meta["inf"] else f"a finite number {bound}"


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) or (
        type(value).__module__ == "numpy" and hasattr(value, "dtype")
        and value.dtype.kind in "iuf" and getattr(value, "ndim", 0) == 0)


def shown_value(value: Any) -> str:
    """A value as JSON for a one-line message, at most 60 characters."""
    try:
        text = json.dumps(value, allow_nan=True, default=repr)
    except (TypeError, ValueError):
        text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _finite_floats(value: Any, count: int) -> list[float] | None:
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__"):
        return None
    try:
        items = list(value)
    except TypeError:
        return None
    if len(items) != count or not all(_is_number(x) for x in items):
        return None
    floats = [float(x) for x in items]
    return floats if all(math.isfinite(x) for x in floats) else None


def check_value(f: Any, value: Any) -> Any:
    """The value of settings field ``f`` in its stored form (floats, tuples, nested lists), or
    :class:`SettingsError` when the field does not allow it."""
    meta, kind = f.metadata, _kind(f)

    def bad() -> SettingsError:
        return SettingsError(f"setting {f.name} = {shown_value(value)}: must be {allowed_text(f)}")

    if kind == "word":
        if not isinstance(value, str) or value not in meta["choices"]:
            raise bad()
        return value
    if kind == "flag":
        if not isinstance(value, bool) and not (type(value).__module__ == "numpy"
                                                and type(value).__name__ == "bool_"):
            raise bad()
        return bool(value)
    if kind == "number":
        if isinstance(value, str) and value == "inf" and meta["inf"]:
            return math.inf
        if not _is_number(value):
            raise bad()
        number = float(value)
        if math.isnan(number) or (math.isinf(number) and not (meta["inf"] and number > 0)):
            raise bad()
        if number < meta["low"] or (meta["above"] and number == meta["low"]):
            raise bad()
        if meta["high"] is not None and number > meta["high"]:
            raise bad()
        return number
    if kind == "vector":
        if value is None and meta["optional"]:
            return None
        floats = _finite_floats(value, 3)
        if floats is None or (f.name == "m0" and math.hypot(floats[0], floats[1]) < 1e-3):
            raise bad()
        return tuple(floats)
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__") or len(value) != 3:
        raise bad()
    rows = [_finite_floats(row, 3) for row in value]
    if any(row is None for row in rows):
        raise bad()
    m = rows
    det = (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
           - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
           + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))
    scale = max(abs(x) for row in m for x in row)
    if meta["matrix"] == "covariance":
        symmetric = all(abs(m[i][j] - m[j][i]) <= 1e-9 * scale for i in range(3)
                        for j in range(3))
        minor2 = m[0][0] * m[1][1] - m[0][1] * m[1][0]
        # Sylvester: every leading principal minor positive
        if not symmetric or not (m[0][0] > 0 and minor2 > 0 and det > 0):
            raise bad()
    elif scale == 0.0 or abs(det) <= 1e-12 * scale ** 3:
        raise bad()
    return [list(row) for row in m]
