"""Allan deviation of the gyroscope at rest, with the angle random walk and the bias instability
read off as MATLAB's ``allanvar`` examples do.

* Angle random walk N [rad/√s] (= rad/s/√Hz): white rate noise gives σ(τ) = N / √τ, a line of
  slope -1/2 on the log-log plot; N is that line's value at τ = 1 s. The line is placed through
  the point where the measured slope is closest to -1/2.
* Bias instability B [rad/s]: the flat bottom of the curve, B = min σ / 0.664
  (0.664 = √(2 ln 2 / π)). On a short recording the minimum is often the longest τ computed:
  then B is only an upper bound (``bias_instability_is_bound``).

The deviations themselves come from ``allantools`` (overlapping Allan deviation), a library kept
for exactly this. The samples are taken as evenly spaced at the median rate.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ekf._optional import require
from ekf.calibration import AXES

BIAS_INSTABILITY_FACTOR = 0.664
"""√(2 ln 2 / π): σ at the flat bottom of the Allan curve = 0.664 × the bias instability."""


@dataclass
class AllanAxis:
    """One gyro axis: taus [s] (K,), adev [rad/s] (K,) with its 1-σ error adev_err (K,);
    arw [rad/√s] and the τ where the -1/2 line touches the curve; bias_instability [rad/s] and
    the τ of the minimum; bias_instability_is_bound: the minimum is at the longest τ."""

    axis: str
    taus: np.ndarray = field(repr=False)
    adev: np.ndarray = field(repr=False)
    adev_err: np.ndarray = field(repr=False)
    arw: float
    arw_tau_s: float
    bias_instability: float
    bias_instability_tau_s: float
    bias_instability_is_bound: bool

    def arw_line(self, taus: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The -1/2 line N/√τ over `taus` (default: the curve's), for drawing."""
        t = self.taus if taus is None else np.asarray(taus, dtype=float)
        return t, self.arw / np.sqrt(t)

    def to_dict(self) -> dict[str, Any]:
        return {"axis": self.axis, "arw_rad_per_sqrt_s": self.arw, "arw_tau_s": self.arw_tau_s,
                "bias_instability_rad_per_s": self.bias_instability,
                "bias_instability_tau_s": self.bias_instability_tau_s,
                "bias_instability_is_bound": self.bias_instability_is_bound,
                "taus_s": self.taus.tolist(), "adev_rad_per_s": self.adev.tolist()}


@dataclass
class AllanResult:
    """rate_hz: the sampling rate used; samples; duration_s; axes: one :class:`AllanAxis` per
    gyro axis x, y, z."""

    rate_hz: float
    samples: int
    duration_s: float
    axes: list[AllanAxis]

    def format_table(self) -> str:
        lines = [f"Allan deviation of the gyroscope: {self.samples} samples at "
                 f"{self.rate_hz:.1f} Hz ({self.duration_s:.1f} s)",
                 f"{'axis':<6}{'ARW rad/√s':>12}{'ARW °/√h':>11}{'bias instab. rad/s':>20}"
                 f"{'°/h':>9}{'at τ s':>9}"]
        for a in self.axes:
            bound = " (upper bound: record longer)" if a.bias_instability_is_bound else ""
            lines.append(f"{a.axis:<6}{a.arw:>12.3e}{np.degrees(a.arw) * 60:>11.3f}"
                         f"{a.bias_instability:>20.3e}"
                         f"{np.degrees(a.bias_instability) * 3600:>9.2f}"
                         f"{a.bias_instability_tau_s:>9.2f}{bound}")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        return {"rate_hz": self.rate_hz, "samples": self.samples, "duration_s": self.duration_s,
                "axes": [a.to_dict() for a in self.axes]}


def _read_off(taus: np.ndarray, adev: np.ndarray) -> tuple[float, float, float, float, bool]:
    """(arw, its tau, bias instability, its tau, is_bound) of one curve."""
    log_t, log_a = np.log10(taus), np.log10(adev)
    if len(taus) >= 2:
        slope = np.gradient(log_a, log_t)
        i = int(np.argmin(np.abs(slope + 0.5)))
    else:
        i = 0
    arw = float(10.0 ** (log_a[i] + 0.5 * log_t[i]))     # the -1/2 line at tau = 1 s
    j = int(np.argmin(adev))
    return (arw, float(taus[i]), float(adev[j] / BIAS_INSTABILITY_FACTOR), float(taus[j]),
            j == len(adev) - 1)


def allan_deviation(t_s: ArrayLike, gyr: ArrayLike, rate_hz: float | None = None,
                    taus: str | ArrayLike = "octave") -> AllanResult:
    """Overlapping Allan deviation of each gyro axis from rest data.

    t_s (N,) seconds (for the rate, when `rate_hz` is not given: 1 / the median step), gyr
    (N, 3) rad/s; NaN rows are dropped. taus: allantools' choice ("octave", "decade", "all") or
    the averaging times [s]. Raises ValueError with fewer than 10 samples."""
    allantools = require("allantools", "the Allan deviation")
    t = np.asarray(t_s, dtype=float).reshape(-1)
    g = np.asarray(gyr, dtype=float).reshape(-1, 3)
    keep = np.isfinite(t) & np.all(np.isfinite(g), axis=1)
    t, g = t[keep], g[keep]
    if len(t) < 10:
        raise ValueError(f"the Allan deviation needs at least 10 gyroscope samples, got {len(t)}")
    if rate_hz is None:
        step = float(np.median(np.diff(t)))
        if not step > 0:
            raise ValueError("gyroscope time stamps do not increase")
        rate_hz = 1.0 / step
    out = []
    for k, axis in enumerate(AXES):
        tau, adev, err, _ = allantools.oadev(g[:, k], rate=rate_hz, data_type="freq", taus=taus)
        ok = np.isfinite(adev) & (adev > 0)
        tau, adev, err = np.asarray(tau)[ok], np.asarray(adev)[ok], np.asarray(err)[ok]
        if len(tau) == 0:
            raise ValueError(f"gyroscope axis {axis} is constant: no Allan deviation")
        out.append(AllanAxis(axis, tau, adev, err, *_read_off(tau, adev)))
    return AllanResult(float(rate_hz), int(len(t)), float(t[-1] - t[0]), out)
