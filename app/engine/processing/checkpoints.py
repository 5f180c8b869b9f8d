"""A replay's checkpoints: the engine's whole state every second of data, kept compactly.

A checkpoint (:class:`Checkpoint`) is what the engine needs to go on from a line of the replayed
file exactly as if it had played every line before it: every estimator's own ``snapshot()``
(the main one and the comparisons, through :meth:`EstimatorRunner.snapshot
<app.engine.processing.runner.EstimatorRunner.snapshot>`: also the phone's latest orientation, the
same-instant comparers, the running errors and the open row), the time orderer's state (the
samples it holds, its clocks), the parser's line state, the session's time origin and where the
recorded timeline stands. A seek restores the latest checkpoint at or before its target and
replays at most one second of lines.

Memory: an hour has 3,600 checkpoints of 8 estimators. An estimator snapshot as a dict of numpy
arrays and Python numbers costs about 5 KB; :func:`pack_snapshot` keeps its numbers in one
float64 vector (about 1 KB for the EKF) with the layout shared by every snapshot of the same
shape, and :func:`unpack_snapshot` gives back an equal dict for ``restore()``. Values it cannot
pack (a filter written by a user with other types of state) are kept as they are.
"""

from __future__ import annotations

import bisect
import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

# layout kinds of a state value
_FLOAT, _BOOL, _INT, _ARRAY, _RECORD, _OTHER = range(6)
_LAYOUTS: dict[tuple, tuple] = {}     # shared layouts (keys, kinds, shapes) -> one object


@dataclass(frozen=True)
class PackedSnapshot:
    """An estimator snapshot {"estimator", "settings", "state"} with the state's numbers in one
    vector: layout = ((key, kind, shape or record class), ...), others: unpackable values."""

    estimator: str
    settings: Any
    layout: tuple
    vector: np.ndarray
    others: tuple = ()


def _kind(value: Any) -> tuple[int, Any]:
    if isinstance(value, (bool, np.bool_)):
        return _BOOL, None
    if isinstance(value, (int, np.integer)):
        return _INT, None
    if isinstance(value, (float, np.floating)):
        return _FLOAT, None
    if isinstance(value, np.ndarray) and value.dtype.kind in "fbiu":
        return _ARRAY, (value.shape, value.dtype.str)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        names = tuple(f.name for f in dataclasses.fields(value))
        if all(isinstance(getattr(value, n), (bool, int, float)) for n in names):
            return _RECORD, (type(value), names, tuple(type(getattr(value, n)) for n in names))
    return _OTHER, None


_SIGNATURES: dict[tuple, tuple] = {}   # (keys, value types) -> layout


def _layout_of(state: dict[str, Any]) -> tuple:
    signature = tuple(state), tuple(type(v) for v in state.values())
    layout = _SIGNATURES.get(signature)
    if layout is None or any(kind == _ARRAY and state[key].shape != detail[0]
                             for key, kind, detail in layout):
        layout = tuple((key, *_kind(value)) for key, value in state.items())
        layout = _LAYOUTS.setdefault(layout, layout)
        _SIGNATURES[signature] = layout
    return layout


def pack_snapshot(snapshot: dict[str, Any]) -> PackedSnapshot:
    """An estimator's snapshot() in compact form (see the module docstring)."""
    state = snapshot["state"]
    layout = _layout_of(state)
    numbers: list[Any] = []
    others = []
    for key, kind, detail in layout:
        value = state[key]
        if kind == _ARRAY:
            numbers.extend(value.ravel().tolist())
        elif kind == _RECORD:
            numbers.extend(getattr(value, name) for name in detail[1])
        elif kind == _OTHER:
            others.append(value)
        else:
            numbers.append(value)
    return PackedSnapshot(snapshot["estimator"], snapshot["settings"], layout,
                          np.array(numbers, dtype=np.float64), tuple(others))


def unpack_snapshot(packed: PackedSnapshot) -> dict[str, Any]:
    """The snapshot dict again (equal to the one packed), for an estimator's restore()."""
    vector = packed.vector
    state: dict[str, Any] = {}
    position = 0
    others = iter(packed.others)
    for key, kind, detail in packed.layout:
        if kind == _ARRAY:
            shape, dtype = detail
            size = int(np.prod(shape, dtype=np.int64))
            state[key] = vector[position:position + size].astype(dtype).reshape(shape)
            position += size
        elif kind == _RECORD:
            cls, names, types = detail
            values = vector[position:position + len(names)].tolist()
            position += len(names)
            state[key] = cls(**{n: t(v) for n, t, v in zip(names, types, values)})
        elif kind == _OTHER:
            state[key] = next(others)
        else:
            value = float(vector[position])
            position += 1
            state[key] = bool(value) if kind == _BOOL else int(value) if kind == _INT \
                else value
    return {"estimator": packed.estimator, "settings": packed.settings, "state": state}


@dataclass(frozen=True)
class PackedGroup:
    """The comparison filters' snapshots of one checkpoint: one layout, their vectors as the
    rows of one matrix, their names, sensors and running errors (squared (k, 3), count (k,),
    latest (k, 3))."""

    names: tuple
    sensors: tuple
    estimators: tuple            # each snapshot's estimator name
    settings: Any
    layout: tuple
    matrix: np.ndarray
    squared: np.ndarray
    count: np.ndarray
    latest: np.ndarray


def pack_runner(snapshot: dict[str, Any]) -> dict[str, Any]:
    """An EstimatorRunner.snapshot() with its estimator snapshots packed (the comparisons in
    one PackedGroup when they share a layout, as the 7 sensor combinations do)."""
    out = dict(snapshot)
    out["main"] = pack_snapshot(snapshot["main"])
    packed = [pack_snapshot(estimator) for _, _, estimator, _ in snapshot["comparisons"]]
    if packed and all(p.layout is packed[0].layout and not p.others for p in packed) \
            and all(p.settings is packed[0].settings for p in packed):
        errors = [e for _, _, _, e in snapshot["comparisons"]]
        out["comparisons"] = PackedGroup(
            tuple(c[0] for c in snapshot["comparisons"]),
            tuple(tuple(c[1]) for c in snapshot["comparisons"]),
            tuple(p.estimator for p in packed), packed[0].settings, packed[0].layout,
            np.stack([p.vector for p in packed]),
            np.array([np.asarray(e[0], float) for e in errors]),
            np.array([int(e[1]) for e in errors]),
            np.array([np.asarray(e[2], float) for e in errors]))
    else:
        out["comparisons"] = [(name, sensors, p, errors) for (name, sensors, _, errors), p
                              in zip(snapshot["comparisons"], packed)]
    return out


def unpack_runner(packed: dict[str, Any]) -> dict[str, Any]:
    out = dict(packed)
    out["main"] = unpack_snapshot(packed["main"])
    group = packed["comparisons"]
    if isinstance(group, PackedGroup):
        out["comparisons"] = [
            (name, sensors, unpack_snapshot(PackedSnapshot(estimator, group.settings,
                                                           group.layout, vector)),
             (squared, int(count), latest))
            for name, sensors, estimator, vector, squared, count, latest in zip(
                group.names, group.sensors, group.estimators, group.matrix, group.squared,
                group.count, group.latest)]
    else:
        out["comparisons"] = [(name, sensors, unpack_snapshot(estimator), errors)
                              for name, sensors, estimator, errors in group]
    return out


def comparison_vectors(packed_runner: dict[str, Any]) -> list[np.ndarray]:
    """The comparison filters' state vectors of a packed runner snapshot (tests)."""
    group = packed_runner["comparisons"]
    if isinstance(group, PackedGroup):
        return list(group.matrix)
    return [estimator.vector for _, _, estimator, _ in group]


@dataclass
class Checkpoint:
    """The engine's state after lines 0..line-1 of a replay (see the module docstring).

    runner: a packed EstimatorRunner snapshot; orderer: TimeOrderer.snapshot(); parser: the
    parser's line state; t0_ms: the session's time origin (None before the first sample);
    fed: samples fed to the estimators in this pass; timeline_next: the index of the next
    recorded timeline event to apply; t_ms: the latest sample time (None before any)."""

    line: int
    runner: dict[str, Any]
    orderer: dict[str, Any]
    parser: tuple
    t0_ms: int | None
    fed: int
    timeline_next: int
    t_ms: int | None = None


class CheckpointStore:
    """Checkpoints in line order; thread-safe for one writer appending and readers looking up
    (appends only, and a list append is atomic)."""

    def __init__(self) -> None:
        self._lines: list[int] = []
        self._checkpoints: list[Checkpoint] = []

    def __len__(self) -> int:
        return len(self._checkpoints)

    def add(self, checkpoint: Checkpoint) -> None:
        if self._lines and checkpoint.line <= self._lines[-1]:
            raise ValueError("checkpoints are added in line order")
        self._checkpoints.append(checkpoint)
        self._lines.append(checkpoint.line)

    def before(self, line: int) -> Checkpoint | None:
        """The latest checkpoint at or before `line` (None: none yet)."""
        count = len(self._checkpoints)
        index = bisect.bisect_right(self._lines, line, 0, count) - 1
        return self._checkpoints[index] if index >= 0 else None

    @property
    def last_line(self) -> int:
        return self._lines[-1] if self._lines else -1

    def nbytes(self) -> int:
        """About how much memory the checkpoints hold (their vectors and held samples)."""
        total = 0
        for checkpoint in self._checkpoints:
            runner = checkpoint.runner
            total += runner["main"].vector.nbytes + 200
            total += sum(v.nbytes + 100 for v in comparison_vectors(runner))
            total += sum(a.nbytes for a in checkpoint.orderer.values()
                         if isinstance(a, np.ndarray))
        return total
