"""A scripted phone session with known truth: the simulator behind tests, demos and `simulate`.

The trajectory is a list of segments. Within a segment the angular velocity has a fixed direction
in the sensor frame and a smooth sin² magnitude profile, so the orientation has the exact closed
form q(t) = q_start ⊗ exp(½ θ(t) axis) (the quaternion exponential; q̇ = ½ q ⊗ (0, ω), eq. 2d).
Segments can also carry a linear-acceleration burst (a specific force in the world frame) and a
magnetic disturbance (an extra world-frame field with smooth ramps).

Sensor models (course eqs. 7 and 8, ENU world, p_W = Q(q) p_S):
    y_gyr = ω_S + bias + e_w                  [rad/s]
    y_acc = Q(q)^T (g0 + f_W) + e_a           [m/s^2], g0 = (0, 0, g)
    y_mag = Q(q)^T (m0 + d_W) + e_m           [uT]
    ORI   = q (the true orientation, w >= 0)

Each sensor is sampled at its own rate with its own phase; timestamps are integer milliseconds
and every value is evaluated exactly at its integer timestamp, so the truth at a sample time is
exact. Everything is vectorised (a 20-minute 500 Hz session takes about a second) and fully
determined by the seed.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ekf.quaternion import from_euler, multiply, normalize, to_matrix

SENSOR_TAGS = ("GYR", "ACC", "MAG", "ORI")
"""Tie order at equal timestamps: the order estimators must be fed (gyr, acc, mag), then ORI."""

DEFAULT_RATES_HZ: dict[str, float] = {"gyr": 100.0, "acc": 100.0, "mag": 50.0, "ori": 100.0}

DEFAULT_NOISE_STD: dict[str, tuple[float, float, float]] = {
    # Between the student reports' rest tables (seeds 000/001: acc 0.005-0.012 m/s^2,
    # gyr 4-5e-4 rad/s, mag 0.2-0.8 uT) and the course's own calibration log
    # (acc 0.016-0.027, gyr 0.8-1.6e-3, mag 0.65-0.69): a typical phone.
    "gyr": (7e-4, 8e-4, 1e-3),
    "acc": (0.015, 0.015, 0.025),
    "mag": (0.5, 0.6, 0.5),
}

GRAVITY = 9.81
"""g [m/s^2] of the simulated world; g0 = (0, 0, g) in ENU."""

EARTH_FIELD_UT = (0.0, 15.5, -48.0)
"""m0 [uT] in ENU, roughly Linköping: no east component, north and (downward) vertical."""

SCRIPTS = ("standard", "rest")

MAX_RATE_HZ = 1000.0
"""The highest rate a sensor may have: time stamps are whole milliseconds."""

MAX_SAMPLES = 20_000_000
"""The most samples (all sensors together) a session may have: about 16 h at the default
rates. The session is computed in memory (about 120 bytes a sample), so a request beyond it is
refused before anything is allocated."""


@dataclass(frozen=True)
class Segment:
    """One piece of the script, in script seconds.

    rotation: `angle_rad` about the sensor-frame unit `axis`, with rate (2 angle/T) sin²(π τ/T).
    force: specific force `force_amplitude` sin(2π n τ/T) along the world unit `force_direction`
    (n = `force_cycles` whole cycles, so the velocity returns to zero) [m/s^2].
    magnetic disturbance: `mag_field` (world, uT) ramped in and out over `mag_ramp_s`.
    `kind` is "rest", "motion", "acc_burst" or "mag_disturbance"; rest-like segments may be
    stretched or compressed to fit a duration, the others keep their length.
    """

    duration_s: float
    kind: str = "rest"
    axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    angle_rad: float = 0.0
    force_direction: tuple[float, float, float] = (1.0, 0.0, 0.0)
    force_amplitude: float = 0.0
    force_cycles: int = 0
    mag_field: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_ramp_s: float = 0.5


def _rest(duration_s: float) -> Segment:
    return Segment(duration_s)


def _turn(axis: tuple[float, float, float], degrees: float, duration_s: float) -> Segment:
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    return Segment(duration_s, "motion", tuple(float(x) for x in a), float(np.deg2rad(degrees)))


def _standard_script() -> list[Segment]:
    """About 83 s: every axis slow (≈0.8 rad/s peak) and fast (≈6.3 rad/s peak), two linear
    acceleration bursts and one magnetic disturbance, separated by rests."""
    x, y, z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
    body: list[Segment] = [
        _turn(x, 90, 4.0), _rest(2.0), _turn(x, -90, 4.0), _rest(2.0),
        _turn(y, 90, 4.0), _rest(2.0), _turn(y, -90, 4.0), _rest(2.0),
        _turn(z, 90, 4.0), _rest(2.0), _turn(z, -45, 4.0), _rest(2.0),
        _turn(x, 180, 1.0), _rest(1.5), _turn(x, -180, 1.0), _rest(1.5),
        _turn(y, 180, 1.0), _rest(1.5), _turn(y, -180, 1.0), _rest(1.5),
        _turn(z, 180, 1.0), _rest(1.5), _turn(z, -180, 1.0), _rest(2.0),
        # Sliding the phone east-west on the table (task 7): held orientation, ±6 m/s^2 at 2 Hz.
        Segment(2.5, "acc_burst", force_direction=(1.0, 0.0, 0.0), force_amplitude=6.0,
                force_cycles=5),
        _rest(2.0),
        # Shaking up/north while turning slowly about the screen normal: ±8 m/s^2 at 3 Hz.
        Segment(2.0, "acc_burst", axis=z, angle_rad=float(np.deg2rad(20.0)),
                force_direction=(0.0, 0.6, 0.8), force_amplitude=8.0, force_cycles=6),
        _rest(2.0),
        # A magnet near the phone (task 10): +36 uT, mostly east: ||m|| grows by ~19 uT and the
        # field turns by ~30°.
        Segment(6.0, "mag_disturbance", mag_field=(35.0, 0.0, -10.0), mag_ramp_s=0.5),
        _rest(2.0),
        _turn((1.0, 1.0, 1.0), 120, 3.0), _rest(2.0),
        _turn(z, 360, 1.5),
    ]
    return [_rest(4.0), *body, _rest(4.0)]


def _fit_script(script: list[Segment], duration_s: float) -> list[Segment]:
    """Fit a script (initial rest, body, final rest) to `duration_s`.

    Longer: repeat the body as often as it fits whole, then stretch every rest evenly.
    Shorter, in stages until it fits: (1) shrink all rests to no less than 3/4 (the initial rest
    stays >= 3 s); (2) keep the initial rest at 3 s and shrink the other rests to no less than 1/4;
    (3) speed up the motions and events, down to half their length (rates up to 2x, same angles,
    same burst cycles); (4) below that (about 34 s for the standard script) the session ends
    part-way through the script.
    """
    first, body, last = script[0], script[1:-1], script[-1]
    body_len = sum(s.duration_s for s in body)
    nominal = first.duration_s + body_len + last.duration_s
    if duration_s >= nominal and body_len > 0:
        repeats = int((duration_s - first.duration_s - last.duration_s) // body_len)
        segments = [first, *(body * max(repeats, 1)), last]
        rest_total = sum(s.duration_s for s in segments if s.kind == "rest")
        factor = (duration_s - sum(s.duration_s for s in segments if s.kind != "rest")) / rest_total
        return [replace(s, duration_s=s.duration_s * factor) if s.kind == "rest" else s
                for s in segments]

    initial = first.duration_s
    other_rest = sum(s.duration_s for s in script[1:] if s.kind == "rest")
    motion = sum(s.duration_s for s in script if s.kind != "rest")
    initial_scale = rest_scale = motion_scale = 1.0
    if initial * 0.75 + other_rest * 0.75 + motion <= duration_s:                    # stage 1
        initial_scale = rest_scale = (duration_s - motion) / (initial + other_rest)
    else:
        initial_scale = min(1.0, 3.0 / initial) if initial > 0 else 1.0
        fixed = initial * initial_scale
        if fixed + other_rest * 0.25 + motion <= duration_s:                        # stage 2
            rest_scale = min((duration_s - fixed - motion) / other_rest, 0.75)
        else:
            rest_scale = 0.25
            fixed += other_rest * rest_scale
            motion_scale = max((duration_s - fixed) / motion, 0.5) if motion > 0 else 1.0  # 3, 4
    out = []
    for i, s in enumerate(script):
        if s.kind == "rest":
            scale = initial_scale if i == 0 else rest_scale
            out.append(replace(s, duration_s=s.duration_s * scale))
        else:
            out.append(replace(s, duration_s=s.duration_s * motion_scale,
                               mag_ramp_s=s.mag_ramp_s * motion_scale))
    return out


def _intervals(starts: np.ndarray, ends: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    """Merge consecutive selected segments into (start, end) script-second intervals."""
    out: list[tuple[float, float]] = []
    for s, e, m in zip(starts, ends, mask):
        if not m:
            continue
        if out and abs(out[-1][1] - s) < 1e-9:
            out[-1] = (out[-1][0], e)
        else:
            out.append((float(s), float(e)))
    return out


class _Trajectory:
    """The script as arrays, evaluated vectorised at any times (script seconds)."""

    def __init__(self, segments: list[Segment], initial_quat: np.ndarray):
        self.segments = segments
        d = np.array([s.duration_s for s in segments], dtype=float)
        self.starts = np.concatenate([[0.0], np.cumsum(d)[:-1]])
        self.durations = d
        self.ends = self.starts + d
        self.axes = np.array([s.axis for s in segments], dtype=float)
        self.angles = np.array([s.angle_rad for s in segments], dtype=float)
        self.force_dirs = np.array([s.force_direction for s in segments], dtype=float)
        self.force_dirs /= np.linalg.norm(self.force_dirs, axis=1, keepdims=True)
        self.force_amps = np.array([s.force_amplitude for s in segments], dtype=float)
        self.force_cycles = np.array([s.force_cycles for s in segments], dtype=float)
        self.mag_fields = np.array([s.mag_field for s in segments], dtype=float)
        self.mag_ramps = np.array([s.mag_ramp_s for s in segments], dtype=float)
        # Orientation at each segment start: chain the whole-segment rotations exactly.
        half = 0.5 * self.angles
        whole = np.column_stack([np.cos(half), np.sin(half)[:, None] * self.axes])
        q_start = np.empty((len(segments), 4))
        q = normalize(initial_quat)
        for i in range(len(segments)):
            q_start[i] = q
            q = multiply(q, whole[i])
            q = q / np.linalg.norm(q)
        self.q_start = q_start

    def _locate(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Segment index and the (clipped) time into it, for each time."""
        index = np.searchsorted(self.starts, t_s, side="right") - 1
        index = np.clip(index, 0, len(self.starts) - 1)
        tau = np.clip(t_s - self.starts[index], 0.0, self.durations[index])
        return index, tau

    def quat(self, t_s: np.ndarray) -> np.ndarray:
        index, tau = self._locate(t_s)
        u = tau / self.durations[index]
        # θ(τ) = angle (u - sin(2πu)/(2π)): the integral of the sin² rate profile.
        theta = self.angles[index] * (u - np.sin(2 * np.pi * u) / (2 * np.pi))
        step = np.column_stack([np.cos(0.5 * theta),
                                np.sin(0.5 * theta)[:, None] * self.axes[index]])
        return normalize(multiply(self.q_start[index], step))

    def angular_velocity(self, t_s: np.ndarray) -> np.ndarray:
        index, tau = self._locate(t_s)
        u = tau / self.durations[index]
        rate = 2.0 * self.angles[index] / self.durations[index] * np.sin(np.pi * u) ** 2
        return rate[:, None] * self.axes[index]

    def specific_force(self, t_s: np.ndarray) -> np.ndarray:
        index, tau = self._locate(t_s)
        u = tau / self.durations[index]
        f = self.force_amps[index] * np.sin(2 * np.pi * self.force_cycles[index] * u)
        return f[:, None] * self.force_dirs[index]

    def mag_disturbance(self, t_s: np.ndarray) -> np.ndarray:
        index, tau = self._locate(t_s)
        ramp = np.maximum(self.mag_ramps[index], 1e-9)
        edge = np.clip(np.minimum(tau, self.durations[index] - tau) / ramp, 0.0, 1.0)
        smooth = edge * edge * (3.0 - 2.0 * edge)  # smoothstep: no jump in the field
        return smooth[:, None] * self.mag_fields[index]


def _noise_cholesky(spec: Any) -> np.ndarray:
    """A 3x3 lower factor from a std (scalar or 3 values) or a 3x3 covariance."""
    a = np.asarray(spec, dtype=float)
    if a.ndim == 0:
        return np.eye(3) * float(a)
    if a.shape == (3,):
        return np.diag(a)
    if a.shape == (3, 3):
        if not np.any(a):
            return np.zeros((3, 3))
        return np.linalg.cholesky(a)
    raise ValueError("noise must be a std (scalar or 3 values) or a 3x3 covariance, "
                     f"got shape {a.shape}")


@dataclass
class SensorSeries:
    """One sensor's samples: integer phone times [ms] (N,) and values (N, 3) or (N, 4) for ORI."""

    t_ms: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ms)


@dataclass
class SimulatedSession:
    """A simulated phone session with its ground truth.

    Times are phone milliseconds (t0_ms + script time); interval arrays have shape (K, 2) with
    rows [start_ms, end_ms] (int64), clipped to the session. Units: gyr rad/s, acc m/s^2, mag uT.
    """

    gyr: SensorSeries
    acc: SensorSeries
    mag: SensorSeries
    ori: SensorSeries
    """ORI = the true orientation at the ORI times, w-first, sensor -> ENU, w >= 0."""
    rest_intervals_ms: np.ndarray
    """The phone is still (no rotation, no specific force; a magnetic disturbance may be on)."""
    acc_disturbance_intervals_ms: np.ndarray
    """Linear-acceleration bursts: specific force present (||y_acc|| differs from g in them)."""
    mag_disturbance_intervals_ms: np.ndarray
    """An extra magnetic field is present (including its ramps)."""
    t0_ms: int
    duration_s: float
    metadata: dict[str, Any] = field(default_factory=dict)
    """g (m/s^2), m0 (uT, ENU), gyr_bias (rad/s), noise_cov per sensor (3x3), rates_hz, seed,
    script, initial_quat."""
    _trajectory: _Trajectory | None = field(default=None, repr=False)

    # ---- truth at any time ---------------------------------------------------------------
    def _script_s(self, t_ms: ArrayLike) -> np.ndarray:
        return (np.atleast_1d(np.asarray(t_ms, dtype=float)) - self.t0_ms) / 1000.0

    def quat_at(self, t_ms: ArrayLike) -> np.ndarray:
        """True orientation (N, 4), w-first, sensor -> ENU, w >= 0, at phone times t_ms (N,)."""
        return self._trajectory.quat(self._script_s(t_ms))

    def angular_velocity_at(self, t_ms: ArrayLike) -> np.ndarray:
        """True angular velocity in the sensor frame (N, 3) [rad/s], without bias or noise."""
        return self._trajectory.angular_velocity(self._script_s(t_ms))

    def specific_force_at(self, t_ms: ArrayLike) -> np.ndarray:
        """Specific force in the world frame beyond gravity, f_W (N, 3) [m/s^2]."""
        return self._trajectory.specific_force(self._script_s(t_ms))

    def mag_disturbance_at(self, t_ms: ArrayLike) -> np.ndarray:
        """Extra magnetic field in the world frame, d_W (N, 3) [uT]."""
        return self._trajectory.mag_disturbance(self._script_s(t_ms))

    def inside(self, intervals_ms: np.ndarray, t_ms: ArrayLike) -> np.ndarray:
        """Boolean mask (N,): which t_ms fall in any [start, end] row of `intervals_ms`."""
        t = np.atleast_1d(np.asarray(t_ms))
        mask = np.zeros(t.shape, dtype=bool)
        for start, end in np.asarray(intervals_ms).reshape(-1, 2):
            mask |= (t >= start) & (t <= end)
        return mask

    # ---- sensors, merged ------------------------------------------------------------------
    def series(self, tag: str) -> SensorSeries:
        """The samples of "GYR", "ACC", "MAG" or "ORI" (case-insensitive)."""
        return getattr(self, tag.lower())

    def merged_order(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All samples in time order, ties in the order GYR, ACC, MAG, ORI.

        Returns (t_ms (M,), sensor index into SENSOR_TAGS (M,), row index into that sensor (M,)).
        """
        parts = [self.series(tag) for tag in SENSOR_TAGS]
        t = np.concatenate([p.t_ms for p in parts])
        sensor = np.concatenate([np.full(len(p), i, dtype=np.int64) for i, p in enumerate(parts)])
        row = np.concatenate([np.arange(len(p), dtype=np.int64) for p in parts])
        order = np.lexsort((row, sensor, t))
        return t[order], sensor[order], row[order]

    def iter_rows(self) -> Iterator[tuple[int, str, tuple[float, ...]]]:
        """(t_ms, tag, values) in time order (ties GYR, ACC, MAG, ORI), one at a time."""
        t, sensor, row = self.merged_order()
        values = [self.series(tag).values.tolist() for tag in SENSOR_TAGS]
        for ti, si, ri in zip(t.tolist(), sensor.tolist(), row.tolist()):
            yield ti, SENSOR_TAGS[si], tuple(values[si][ri])

    def to_rows(self) -> list[tuple[int, str, tuple[float, ...]]]:
        """All samples as (t_ms, tag, values) tuples in time order, ties GYR, ACC, MAG, ORI, so
        app code can format phone lines. For very long sessions prefer :meth:`iter_rows`."""
        return list(self.iter_rows())

    def to_batch_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(t_s (N,), gyr, acc, mag (N, 3) with NaN rows) over the distinct GYR/ACC/MAG times, the
        layout of `ekf.filter_batch`. t_s is phone time in seconds."""
        t_all = np.unique(np.concatenate([self.gyr.t_ms, self.acc.t_ms, self.mag.t_ms]))
        out = []
        for s in (self.gyr, self.acc, self.mag):
            a = np.full((len(t_all), 3), np.nan)
            a[np.searchsorted(t_all, s.t_ms)] = s.values
            out.append(a)
        return (t_all / 1000.0, *out)


def _sample_times(rate_hz: float, phase_ms: float, duration_ms: float) -> np.ndarray:
    """Integer-ms times k/rate + phase within [0, duration_ms], strictly increasing."""
    if rate_hz <= 0:
        return np.zeros(0, dtype=np.int64)
    period = 1000.0 / rate_hz
    n = int(np.floor((duration_ms - phase_ms) / period)) + 1
    t = np.round(phase_ms + period * np.arange(max(n, 0))).astype(np.int64)
    t = t[t <= duration_ms]
    # Above 1 kHz rounding could repeat a millisecond: keep each ms once (times strictly increase).
    keep = np.concatenate([[True], np.diff(t) > 0]) if len(t) else np.zeros(0, dtype=bool)
    return t[keep]


def _with_defaults(defaults: Mapping[str, Any], given: Mapping[str, Any] | None,
                   what: str) -> dict[str, Any]:
    """`defaults` updated by `given`; ValueError naming keys that are not sensors."""
    out = dict(defaults)
    if given:
        unknown = set(given) - set(out)
        if unknown:
            raise ValueError(f"unknown sensor(s) in {what}: {', '.join(sorted(unknown))}")
        out.update(given)
    return out


def _check_arguments(duration_s: float, rates: Mapping[str, float], seed: Any, g: float) -> None:
    """ValueError, before anything is allocated, for a duration or g that is not a finite
    number > 0, a seed that is not a whole number >= 0, a rate that is not a number from 0 to
    MAX_RATE_HZ or a session of more than MAX_SAMPLES samples."""
    if not 0 < duration_s < math.inf:
        raise ValueError(f"duration {duration_s:g} s: must be a finite number > 0")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed {seed!r}: must be a whole number >= 0")
    if not 0 < g < math.inf:
        raise ValueError(f"g {g:g}: must be a finite number > 0")
    for sensor, rate in rates.items():
        if not 0 <= rate <= MAX_RATE_HZ:
            raise ValueError(f"{sensor} rate {rate:g} Hz: must be from 0 to {MAX_RATE_HZ:g} Hz "
                             "(time stamps are whole milliseconds)")
    per_second = sum(rates.values())
    if duration_s * per_second > MAX_SAMPLES:
        raise ValueError(f"{duration_s:g} s at {per_second:g} samples/s is "
                         f"{duration_s * per_second:.3g} samples, more than the "
                         f"{MAX_SAMPLES:,} a session may have (about "
                         f"{MAX_SAMPLES / per_second / 3600:.3g} h at these rates)")


def _finite_vector(value: ArrayLike, name: str) -> np.ndarray:
    vector = np.asarray(value, dtype=float).reshape(3)
    if not np.isfinite(vector).all():
        raise ValueError(f"{name} {tuple(float(v) for v in vector)}: must be finite numbers")
    return vector


def _intervals_ms(intervals: list[tuple[float, float]], duration_s: float,
                  t0_ms: int) -> np.ndarray:
    """Script intervals [s] as phone-time rows (start_ms, end_ms), cut at the session's end."""
    rows = []
    for start, end in intervals:
        start_ms, end_ms = round(start * 1000.0), round(min(end, duration_s) * 1000.0)
        if start_ms < end_ms:
            rows.append((t0_ms + start_ms, t0_ms + end_ms))
    return np.array(rows, dtype=np.int64).reshape(-1, 2)


def _readings(trajectory: "_Trajectory", t_s: dict[str, np.ndarray], rng: np.random.Generator,
              chol: dict[str, np.ndarray], bias: np.ndarray, g0: np.ndarray,
              m0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """GYR, ACC, MAG (with noise, drawn in that order) and ORI at their sample times [s]."""

    def noise_for(sensor: str, n: int) -> np.ndarray:
        return rng.standard_normal((n, 3)) @ chol[sensor].T

    gyr = trajectory.angular_velocity(t_s["gyr"]) + bias + noise_for("gyr", len(t_s["gyr"]))
    rot_acc = to_matrix(trajectory.quat(t_s["acc"]))
    acc_world = g0 + trajectory.specific_force(t_s["acc"])
    acc = np.einsum("nji,nj->ni", rot_acc, acc_world) + noise_for("acc", len(t_s["acc"]))
    rot_mag = to_matrix(trajectory.quat(t_s["mag"]))
    mag_world = m0 + trajectory.mag_disturbance(t_s["mag"])
    mag = np.einsum("nji,nj->ni", rot_mag, mag_world) + noise_for("mag", len(t_s["mag"]))
    return gyr, acc, mag, trajectory.quat(t_s["ori"])


def simulate(
    duration_s: float = 120.0,
    rates_hz: Mapping[str, float] | None = None,
    seed: int = 0,
    gyro_bias: ArrayLike = (0.0, 0.0, 0.0),
    noise: Mapping[str, Any] | None = None,
    t0_ms: int = 1_000_000,
    script: str = "standard",
    initial_quat: ArrayLike | None = None,
    g: float = GRAVITY,
    m0: ArrayLike = EARTH_FIELD_UT,
) -> SimulatedSession:
    """Simulate a phone session with known truth, deterministic by `seed`.

    duration_s: length [s] (> 0); the script is fitted to it (see `_fit_script`).
    rates_hz: per sensor {"gyr", "acc", "mag", "ori"} [Hz]; missing keys use DEFAULT_RATES_HZ,
        a rate of 0 leaves that sensor out (e.g. a phone without gyroscope).
    gyro_bias: constant gyroscope bias (3,) [rad/s], added to every GYR sample.
    noise: per sensor "gyr"/"acc"/"mag": a std (scalar or 3 values) or a 3x3 covariance; missing
        keys use DEFAULT_NOISE_STD; 0 gives noise-free samples.
    t0_ms: phone time of script time 0 [ms].
    script: "standard" (rests, slow and fast turns about every axis, acceleration bursts, a
        magnetic disturbance) or "rest" (the phone lies still the whole time).
    initial_quat: orientation at t0 (4,), w-first; default flat, screen up, x axis 30° north of
        east.
    g, m0: gravity magnitude [m/s^2] and Earth field (3,) in ENU [uT].
    """
    if script not in SCRIPTS:
        raise ValueError(f"unknown script {script!r}; choose one of {', '.join(SCRIPTS)}")
    rates = _with_defaults(DEFAULT_RATES_HZ, {k: float(v) for k, v in (rates_hz or {}).items()},
                           "rates_hz")
    _check_arguments(duration_s, rates, seed, g)
    noise_spec = _with_defaults(DEFAULT_NOISE_STD, noise, "noise")
    chol = {k: _noise_cholesky(v) for k, v in noise_spec.items()}
    bias = _finite_vector(gyro_bias, "gyro_bias")
    m0 = _finite_vector(m0, "m0")
    g0 = np.array([0.0, 0.0, float(g)])
    q_initial = normalize(from_euler(np.deg2rad(30.0), 0.0, 0.0) if initial_quat is None
                          else np.asarray(initial_quat, dtype=float))

    base = _standard_script() if script == "standard" else [_rest(duration_s)]
    segments = _fit_script(base, duration_s) if script == "standard" else base
    trajectory = _Trajectory(segments, q_initial)
    rng = np.random.default_rng(seed)
    # Asynchronous sensors: each starts at its own phase within its first period.
    phases = {k: (rng.uniform(0.0, 1000.0 / r) if r > 0 else 0.0) for k, r in rates.items()}
    times = {k: _sample_times(rates[k], phases[k], duration_s * 1000.0)
             for k in ("gyr", "acc", "mag", "ori")}

    gyr, acc, mag, ori = _readings(trajectory, {k: v / 1000.0 for k, v in times.items()}, rng,
                                   chol, bias, g0, m0)

    kinds = np.array([s.kind for s in segments])
    still = (trajectory.angles == 0.0) & (trajectory.force_amps == 0.0)
    rest, acc_disturbed, mag_disturbed = (
        _intervals_ms(_intervals(trajectory.starts, trajectory.ends, mask), duration_s, t0_ms)
        for mask in (still, trajectory.force_amps > 0, kinds == "mag_disturbance"))
    return SimulatedSession(
        gyr=SensorSeries(times["gyr"] + t0_ms, gyr),
        acc=SensorSeries(times["acc"] + t0_ms, acc),
        mag=SensorSeries(times["mag"] + t0_ms, mag),
        ori=SensorSeries(times["ori"] + t0_ms, ori),
        rest_intervals_ms=rest,
        acc_disturbance_intervals_ms=acc_disturbed,
        mag_disturbance_intervals_ms=mag_disturbed,
        t0_ms=int(t0_ms),
        duration_s=float(duration_s),
        metadata={
            "g": float(g),
            "m0": tuple(float(v) for v in m0),
            "gyr_bias": tuple(float(v) for v in bias),
            "noise_cov": {k: (c @ c.T).tolist() for k, c in chol.items()},
            "rates_hz": rates,
            "seed": int(seed),
            "script": script,
            "initial_quat": tuple(float(v) for v in q_initial),
        },
        _trajectory=trajectory,
    )
