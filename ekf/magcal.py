"""Magnetometer hard- and soft-iron calibration: an ellipsoid fit to readings taken while the
phone is turned in every direction (as PJRC's MotionCal does it), with a coverage figure.

Model: a reading is m_raw = D m_true + b, with the Earth's field m_true of fixed strength, b the
hard-iron offset [µT] and D the soft-iron distortion. The readings then lie on an ellipsoid
(x - b)ᵀ A (x - b) = 1. The correction is

    m = S (m_raw - b),  S = R A^{1/2}  (symmetric),  R = det(A)^{-1/6}

so the corrected readings lie on a sphere of radius R (S keeps the volume: det S = 1, and R is
the geometric mean of the ellipsoid's semi-axes, the field strength in µT). A distortion that
only scales all axes alike cannot be told from a stronger field and is left alone.

The fit is linear least squares on the quadric's nine coefficients (needs readings on much of
the sphere); with little coverage only the offset is fitted (a sphere, four coefficients).
Coverage is the fraction of 100 nearly equal-area directions (a Fibonacci sphere) that some
reading, seen from the centre, points to.

The phone's own calibration is often applied before the app sees the readings: then the fit
finds nothing worth correcting, and says so (:attr:`MagCalibration.nothing_to_correct`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

COVERAGE_BINS = 100
ELLIPSOID_MIN_COVERAGE = 0.35
"""Below this coverage the nine-coefficient fit is ill-posed: only the offset is fitted."""
MIN_SAMPLES = 20
OUTLIER_PASSES = 8
"""At most this many refits leaving out readings far off the sphere (see _inliers)."""
EARTH_FIELD_RANGE_UT = (25.0, 65.0)
MIN_SPREAD_UT = 5.0
"""The readings must spread at least this far (standard deviation along their widest axis):
a phone turned in even one plane spreads them by about the field's strength, one lying still
only by its noise, around which a sphere of any size fits."""


def fibonacci_directions(n: int = COVERAGE_BINS) -> np.ndarray:
    """n unit vectors (n, 3) spread nearly evenly over the sphere (golden-angle spiral)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * k
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


_DIRECTIONS = fibonacci_directions()


def direction_counts(mag: ArrayLike, center: ArrayLike = (0.0, 0.0, 0.0),
                     soft_iron: ArrayLike | None = None,
                     directions: np.ndarray = _DIRECTIONS) -> np.ndarray:
    """How many readings point (from `center`, after `soft_iron` if given) to each of the
    `directions` (nearest direction): (len(directions),) ints."""
    m = np.asarray(mag, dtype=float).reshape(-1, 3)
    m = m[np.all(np.isfinite(m), axis=1)] - np.asarray(center, dtype=float)
    if soft_iron is not None:
        m = m @ np.asarray(soft_iron, dtype=float).T
    norms = np.linalg.norm(m, axis=1)
    m = m[norms > 0] / norms[norms > 0, None]
    if len(m) == 0:
        return np.zeros(len(directions), int)
    nearest = np.argmax(m @ directions.T, axis=1)
    return np.bincount(nearest, minlength=len(directions))


def coverage(mag: ArrayLike, center: ArrayLike = (0.0, 0.0, 0.0),
             soft_iron: ArrayLike | None = None, min_per_bin: int = 1) -> float:
    """Fraction (0..1) of the sphere's directions visited by at least `min_per_bin` readings,
    seen from `center` (the hard-iron offset; the origin for calibrated readings)."""
    counts = direction_counts(mag, center, soft_iron)
    return float(np.mean(counts >= min_per_bin))


def fit_sphere(mag: ArrayLike) -> tuple[np.ndarray, float]:
    """Least-squares sphere ‖x - c‖ = r through readings (N, 3): (c (3,), r)."""
    m = np.asarray(mag, dtype=float).reshape(-1, 3)
    design = np.column_stack([2.0 * m, np.ones(len(m))])
    target = np.sum(m * m, axis=1)
    solution, *_ = np.linalg.lstsq(design, target, rcond=None)
    c = solution[:3]
    return c, float(np.sqrt(max(solution[3] + c @ c, 0.0)))


def fit_ellipsoid(mag: ArrayLike) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares ellipsoid through readings (N, 3): (offset b (3,), soft-iron S (3, 3)
    symmetric with det 1, radius R) with ‖S (x - b)‖ ≈ R. Raises ValueError when the quadric
    found is not an ellipsoid (too little coverage, or collinear readings)."""
    m = np.asarray(mag, dtype=float).reshape(-1, 3)
    # Centre and scale first: the quadric's normal equations are then well conditioned.
    shift = m.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((m - shift) ** 2, axis=1)))) or 1.0
    x, y, z = ((m - shift) / scale).T
    design = np.column_stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z,
                              2 * x, 2 * y, 2 * z])
    coef, *_ = np.linalg.lstsq(design, np.ones(len(m)), rcond=None)
    a, b, c, d, e, f, g, h, i = coef
    quad = np.array([[a, d, e], [d, b, f], [e, f, c]])
    lin = np.array([g, h, i])
    try:
        center = -np.linalg.solve(quad, lin)
    except np.linalg.LinAlgError:
        raise ValueError("the readings do not determine an ellipsoid") from None
    k = 1.0 + center @ quad @ center
    shape = quad / k
    eigenvalues, vectors = np.linalg.eigh(shape)
    if not np.all(eigenvalues > 0) or not np.isfinite(eigenvalues).all():
        raise ValueError("the readings do not lie on an ellipsoid (turn the phone further)")
    sqrt_shape = vectors @ np.diag(np.sqrt(eigenvalues)) @ vectors.T
    radius_scaled = float(np.prod(eigenvalues) ** (-1.0 / 6.0))
    soft_iron = radius_scaled * sqrt_shape
    return center * scale + shift, soft_iron, radius_scaled * scale


def correct(mag: ArrayLike, offset: ArrayLike, soft_iron: ArrayLike) -> np.ndarray:
    """S (m - b) row by row: readings (N, 3) µT -> corrected (N, 3); NaN rows stay NaN."""
    m = np.asarray(mag, dtype=float)
    return (m - np.asarray(offset, dtype=float)) @ np.asarray(soft_iron, dtype=float).T


@dataclass
class MagCalibration:
    """The fit's result.

    offset (3,) µT and soft_iron (3, 3) (det 1): the correction S (m - b); field_strength R µT;
    model "ellipsoid" or "sphere" (offset only); samples; coverage (0..1) seen from the fitted
    centre; fit_error_pct: RMS of ‖S (m - b)‖ - R relative to R; norm_mean/std_before/after:
    ‖m‖ of the raw and the corrected readings [µT] (these figures over the readings fitted:
    those far off the sphere, a magnet passing by, are left out and counted in `outliers`); nothing_to_correct: the correction changes
    the spread of ‖m‖ by less than it is worth (the phone had calibrated already); message: one
    line for the user."""

    offset: np.ndarray
    soft_iron: np.ndarray
    field_strength: float
    model: str
    samples: int
    coverage: float
    fit_error_pct: float
    norm_mean_before: float
    norm_std_before: float
    norm_mean_after: float
    norm_std_after: float
    nothing_to_correct: bool
    message: str = ""
    outliers: int = 0
    counts: np.ndarray = field(default_factory=lambda: np.zeros(COVERAGE_BINS, int), repr=False)

    def correct(self, mag: ArrayLike) -> np.ndarray:
        return correct(mag, self.offset, self.soft_iron)

    def settings_changes(self) -> dict[str, Any]:
        """The EKFSettings fields this result sets (identity when there is nothing to
        correct)."""
        if self.nothing_to_correct:
            return {"mag_hard_iron": (0.0, 0.0, 0.0), "mag_soft_iron": np.eye(3).tolist()}
        return {"mag_hard_iron": tuple(float(v) for v in self.offset),
                "mag_soft_iron": self.soft_iron.tolist()}

    def format_report(self) -> str:
        lines = [f"magnetometer calibration ({self.model} fit, {self.samples} readings)",
                 "hard-iron offset b = (" + ", ".join(f"{v:.2f}" for v in self.offset) + ") uT",
                 "soft-iron matrix S (m = S (m_raw - b)):"]
        lines += ["  " + "".join(f"{v:>10.4f}" for v in row) for row in self.soft_iron]
        lines += [f"field strength R = {self.field_strength:.2f} uT",
                  f"coverage {100 * self.coverage:.0f} % of the sphere's directions",
                  f"fit error {self.fit_error_pct:.2f} % of R",
                  f"|m| before: {self.norm_mean_before:.2f} +- {self.norm_std_before:.2f} uT; "
                  f"after: {self.norm_mean_after:.2f} +- {self.norm_std_after:.2f} uT"]
        if self.message:
            lines.append(self.message)
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        return {"offset": self.offset.tolist(), "soft_iron": self.soft_iron.tolist(),
                "field_strength": self.field_strength, "model": self.model,
                "samples": self.samples, "coverage": self.coverage,
                "fit_error_pct": self.fit_error_pct,
                "norm_mean_before": self.norm_mean_before, "norm_std_before": self.norm_std_before,
                "norm_mean_after": self.norm_mean_after, "norm_std_after": self.norm_std_after,
                "nothing_to_correct": self.nothing_to_correct, "message": self.message,
                "outliers": self.outliers}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "MagCalibration":
        values = dict(d)
        values["offset"] = np.asarray(values["offset"], dtype=float).reshape(3)
        values["soft_iron"] = np.asarray(values["soft_iron"], dtype=float).reshape(3, 3)
        known = set(cls.__dataclass_fields__) - {"counts"}
        return cls(**{k: v for k, v in values.items() if k in known})


def _fit(m: np.ndarray, min_coverage: float) -> tuple[np.ndarray, np.ndarray, float, str]:
    center, radius = fit_sphere(m)
    if coverage(m, center) >= min_coverage:
        try:
            offset, soft_iron, radius_e = fit_ellipsoid(m)
            return offset, soft_iron, radius_e, "ellipsoid"
        except ValueError:
            pass
    return center, np.eye(3), radius, "sphere"


def _inliers(m: np.ndarray) -> np.ndarray:
    """Readings on the field's sphere: a sphere is fitted and the readings more than 3.5 robust
    standard deviations off it (a magnet or iron passing by) left out, until none is. The
    sphere is stiffer than the ellipsoid, which bends towards such readings."""
    used = np.ones(len(m), bool)
    for _ in range(OUTLIER_PASSES):
        center, radius = fit_sphere(m[used])
        residual = np.linalg.norm(m - center, axis=1) - radius
        middle = np.median(residual[used])
        spread = 1.4826 * np.median(np.abs(residual[used] - middle))
        keep = np.abs(residual - middle) <= max(3.5 * spread, 0.01 * radius)
        if keep.sum() < MIN_SAMPLES or np.array_equal(keep, used):
            break
        used = keep
    return used


def _nothing_to_correct(norms_before: np.ndarray, std_after: float, covered: float) -> bool:
    """The correction is not worth applying: the raw readings already have an Earth-like
    strength, cover a fair part of the sphere, and the correction narrows the spread of ‖m‖ by
    less than 0.5 µT or a third (the phone had calibrated already)."""
    low, high = EARTH_FIELD_RANGE_UT
    std_before = float(norms_before.std())
    plausible = low <= float(norms_before.mean()) <= high
    little_gain = (std_before - std_after) < max(0.5, std_before / 3.0)
    return bool(plausible and little_gain and covered >= 0.2)


def calibrate_magnetometer(mag: ArrayLike,
                           min_coverage: float = ELLIPSOID_MIN_COVERAGE) -> MagCalibration:
    """Fit hard- and soft-iron from readings (N, 3) µT taken while turning the phone in every
    direction (NaN rows dropped). Raises ValueError with fewer than MIN_SAMPLES readings."""
    m = np.asarray(mag, dtype=float).reshape(-1, 3)
    m = m[np.all(np.isfinite(m), axis=1)]
    if len(m) < MIN_SAMPLES:
        raise ValueError(f"the magnetometer fit needs at least {MIN_SAMPLES} readings, "
                         f"got {len(m)}")
    used = _inliers(m)
    spread = float(np.sqrt(max(np.linalg.eigvalsh(np.cov(m[used].T))[-1], 0.0)))
    if spread < MIN_SPREAD_UT:
        raise ValueError(f"the phone hardly turned: the readings spread by {spread:.1f} uT "
                         f"(at least {MIN_SPREAD_UT:g} uT needed; turned in every direction "
                         f"they spread by about the field's {EARTH_FIELD_RANGE_UT[0]:g}-"
                         f"{EARTH_FIELD_RANGE_UT[1]:g} uT)")
    offset, soft_iron, strength, model = _fit(m[used], min_coverage)
    outliers = int(len(m) - used.sum())
    inliers = m[used]           # the figures are those of the readings fitted
    norms_before = np.linalg.norm(inliers, axis=1)
    norms_after = np.linalg.norm(correct(inliers, offset, soft_iron), axis=1)
    counts = direction_counts(inliers, offset, soft_iron)
    fit_error = float(100.0 * np.sqrt(np.mean((norms_after - strength) ** 2)) / strength)
    covered = float(np.mean(counts > 0))
    nothing = _nothing_to_correct(norms_before, float(norms_after.std()), covered)
    low, high = EARTH_FIELD_RANGE_UT
    if nothing:
        message = ("nothing to correct: the readings already lie on a sphere about the origin "
                   "(the phone's own calibration is applied)")
    elif not low <= strength <= high:
        message = (f"the fitted field strength {strength:.1f} uT is not the Earth's "
                   f"({low:g}-{high:g} uT): turn the phone in more directions, away from iron")
    elif model == "sphere" and covered < min_coverage:
        message = (f"offset only: turn the phone in more directions for the soft-iron matrix "
                   f"(coverage {100 * covered:.0f} %, {100 * min_coverage:.0f} % needed)")
    elif model == "sphere":
        message = ("offset only: the readings do not determine a soft-iron matrix (turn the "
                   "phone further, away from iron)")
    else:
        message = ""
    if outliers:
        message = (message + "; " if message else "") + \
            f"{outliers} readings far off the sphere left out (iron or a magnet nearby?)"
    return MagCalibration(offset, soft_iron, strength, model, len(m), covered, fit_error,
                          float(norms_before.mean()), float(norms_before.std()),
                          float(norms_after.mean()), float(norms_after.std()), nothing, message,
                          outliers, counts)


def settings_correction(settings: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """(offset, soft_iron) of EKFSettings' mag_hard_iron / mag_soft_iron, or None when they are
    the identity (nothing to apply)."""
    offset = np.asarray(settings.mag_hard_iron, dtype=float).reshape(3)
    soft_iron = np.asarray(settings.mag_soft_iron, dtype=float).reshape(3, 3)
    if not offset.any() and np.array_equal(soft_iron, np.eye(3)):
        return None
    return offset, soft_iron
