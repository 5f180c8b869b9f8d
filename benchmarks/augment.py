"""Recordings made harder on purpose: the shared recordings with synthetic faults added.

The Nexus 5 recordings in ``../shared/data/tyrex`` are one person's, in one room. Other people,
other buildings and other phones bring stronger magnetic disturbances, a field already
disturbed where the recording starts, a magnet in the phone's case and a gyroscope with more
bias. Each scenario below adds one of these to a real recording, so the motion and its optical
truth stay real and exact, and only the sensor readings change:

* ``building-20`` / ``building-50``: fields that change in the **world** frame as a walk passes
  steel, furniture and machines: on average one every 15 s, each a smooth bump (sin²) lasting
  1-8 s whose peak is 20-100 % of 20 or 50 µT in a random world direction; added to the
  magnetometer through the true orientation (``y + Q(q_true)ᵀ d(t)``).
* ``desk-start``: the recording starts next to a laptop or a desk: a world-frame disturbance of
  9-30 µT present at the first reading, fading out (cos²) over 3-10 s.
* ``magnet-20``: a magnet in the phone's case: a constant offset of 20 µT in the **sensor**
  frame (hard iron).
* ``gyro-bias``: a gyroscope whose calibration is off by 0.5°/s (constant, random direction).

``magnet-N`` and ``building-N`` take any strength N [µT] (``magnet-400``: a raw magnetometer's
hard iron beside a calibrated gyroscope, as an iPhone's raw magnetometer gives), and scenarios
joined by ``+`` are applied in order (``building-50+magnet-400``: a raw magnetometer carried
through a building).

Every scenario is seeded by the recording's name, the scenario and a copy index, so a figure is
reproduced exactly. Used by ``benchmarks/robustness.py`` (ours and the peers on the same
perturbed samples) and ``benchmarks/tune_defaults.py --augment`` (more varied tuning data; the
held-out figures stay on the real recordings).
"""

from __future__ import annotations

import copy
import zlib

import numpy as np

from ekf import quaternion as Q
from ekf.metrics import interpolate_quat

from datasets import Recording

SCENARIOS = ("building-20", "building-50", "desk-start", "magnet-20", "gyro-bias")


def _true_rotations(rec: Recording) -> np.ndarray:
    """Q(q_true) (N, 3, 3) at every row of the recording (the truth's nearest end outside it)."""
    t_ms = np.clip(rec.t_s * 1000.0, rec.ref_t_ms[0], rec.ref_t_ms[-1])
    return Q.to_matrix(interpolate_quat(rec.ref_t_ms, rec.ref_q, t_ms))


def _world_field(rec: Recording, d_world: np.ndarray) -> np.ndarray:
    """The magnetometer with a world-frame field d_world (N, 3) [µT] added through the truth."""
    return rec.mag + np.einsum("nji,nj->ni", _true_rotations(rec), d_world)


def building(rec: Recording, rng: np.random.Generator, peak_uT: float,
             every_s: float = 15.0) -> np.ndarray:
    """World-frame bumps: Poisson in time (mean one per `every_s`), 1-8 s, peak 20-100 % of
    `peak_uT` in a random direction. Returns the disturbance (N, 3)."""
    t = rec.t_s
    d = np.zeros((len(t), 3))
    for _ in range(rng.poisson((t[-1] - t[0]) / every_s)):
        t0 = t[0] + rng.uniform(0.0, t[-1] - t[0])
        length = rng.uniform(1.0, 8.0)
        peak = rng.uniform(0.2, 1.0) * peak_uT
        v = rng.normal(size=3)
        x = (t - t0) / length
        d += np.where((x > 0) & (x < 1), np.sin(np.pi * x) ** 2, 0.0)[:, None] * (
            peak * v / np.linalg.norm(v))
    return d


def desk_start(rec: Recording, rng: np.random.Generator, peak_uT: float = 30.0) -> np.ndarray:
    """A world-frame disturbance at the first reading, fading out (cos²) over 3-10 s."""
    t = rec.t_s
    x = (t - t[0]) / rng.uniform(3.0, 10.0)
    v = rng.normal(size=3)
    w = np.where(x < 1, np.cos(0.5 * np.pi * np.minimum(x, 1.0)) ** 2, 0.0)
    return w[:, None] * (rng.uniform(0.3, 1.0) * peak_uT * v / np.linalg.norm(v))


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def known(scenario: str) -> bool:
    """Whether `scenario` is one :func:`perturbed` makes: a name of SCENARIOS, ``magnet-N`` or
    ``building-N`` with N > 0, or such scenarios joined by ``+``."""
    for part in scenario.split("+"):
        head, _, strength = part.rpartition("-")
        if part in SCENARIOS:
            continue
        try:
            ok = head in ("magnet", "building") and float(strength) > 0.0
        except ValueError:
            ok = False
        if not ok:
            return False
    return True


def perturbed(rec: Recording, scenario: str, copy_index: int = 0) -> Recording:
    """A copy of `rec` with one scenario's fault added (see the module's docstring); its name
    says which (``NAME+building-50#0``). Scenarios joined by ``+`` are applied in order."""
    if "+" in scenario:
        for part in scenario.split("+"):
            rec = perturbed(rec, part, copy_index)
        return rec
    rng = np.random.default_rng([zlib.crc32(rec.name.encode()), zlib.crc32(scenario.encode()),
                                 copy_index])
    out = copy.copy(rec)
    out._sync = None
    out.name = f"{rec.name}+{scenario}#{copy_index}"
    if scenario.startswith("building-"):
        out.mag = _world_field(rec, building(rec, rng, float(scenario.split("-")[1])))
    elif scenario == "desk-start":
        out.mag = _world_field(rec, desk_start(rec, rng))
    elif scenario.startswith("magnet-"):
        out.mag = rec.mag + float(scenario.split("-")[1]) * _unit(rng)
    elif scenario == "gyro-bias":
        out.gyr = rec.gyr + np.radians(0.5) * _unit(rng)
    else:
        raise ValueError(f"unknown scenario {scenario!r}; choose from {', '.join(SCENARIOS)}")
    return out
