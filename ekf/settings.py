"""Filter settings: one dataclass, documented defaults and units, and named presets.

Every number a user may want to tune lives here, so a settings file (JSON) describes a run
completely. ``PRESETS["course"]`` is the plain course filter (model 4a, tasks 1-11);
``PRESETS["default"]`` adds the extensions that pay on real data (see README, "Settings").
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any


def _diag(value: float) -> list[list[float]]:
    return [[value, 0.0, 0.0], [0.0, value, 0.0], [0.0, 0.0, value]]


@dataclass(frozen=True)
class EKFSettings:
    """Settings of the quaternion EKF. Units in brackets; covariances are 3x3 nested lists.

    Measurement models (course eqs. 7-8): y_a = Q(q)^T g0 + e_a with g0 = (0, 0, g);
    y_m = Q(q)^T m0 + e_m with m0 in ENU.
    """

    # --- sensor models --------------------------------------------------------------------
    g: float = 9.81
    """Expected specific-force magnitude at rest [m/s^2]; g0 = (0, 0, g)."""
    m0: tuple[float, float, float] | None = None
    """Earth field in ENU [uT], (0, horizontal, vertical). None: taken from the first magnetometer
    reading, tilt-compensated with the first accelerometer reading (the course's 'flat reading')."""
    gyr_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Gyroscope bias subtracted from every sample [rad/s] (from `calibrate`); with
    `estimate_gyro_bias` this is the initial bias estimate."""

    # --- noise ----------------------------------------------------------------------------
    gyr_noise_cov: list[list[float]] = field(default_factory=lambda: _diag(1e-4))
    """R_w: covariance of the angular-rate noise v_k [(rad/s)^2] (eq. 5)."""
    acc_noise_cov: list[list[float]] = field(default_factory=lambda: _diag(0.1))
    """R_a: accelerometer measurement noise [(m/s^2)^2]. Larger than the sensor's own noise to
    absorb small specific forces."""
    mag_noise_cov: list[list[float]] = field(default_factory=lambda: _diag(2.0))
    """R_m: magnetometer measurement noise [uT^2]."""
    gyr_scale_noise: float = 0.0
    """Relative uncertainty of the gyroscope's scale [-]: R_w grows by (k ||w||)^2 I, so the
    filter trusts the integration less in fast turns (0: the course's constant R_w)."""
    gyr_rate_before_sample: bool = False
    """False (course, eq. 5): a gyroscope sample drives the state from its time to the next
    sample. True: it is the rate over the interval that ends at its time stamp (IMUs average
    internally), so it drives the state up to its own time; the estimate does not lag by one
    sample period in fast turns."""
    no_gyro_random_walk: float = 1.0
    """Orientation random walk used when no gyroscope sample drives the time update
    [rad/sqrt(s)]: the state stays and P grows (task 12, acc+mag only)."""
    initial_attitude_std: float = 0.05
    """Standard deviation of the initial attitude from acc+mag [rad]."""

    # --- outlier gates (tasks 8 and 11) -----------------------------------------------------
    acc_gate: float = 1.0
    """Skip the accelerometer update when | ||y_a|| - g | > acc_gate [m/s^2] (task 8). inf: off."""
    mag_gate: float = 5.0
    """Skip the magnetometer update when | ||y_m|| - L_k | > mag_gate [uT] (task 11). inf: off."""
    mag_alpha: float = 0.01
    """AR(1) coefficient of the field-strength estimate L_k = (1 - a) L_{k-1} + a ||y_m|| [-]."""
    mag_strength_update: str = "always"
    """'always': L_k follows every reading (the course's filter). 'accepted': only readings that
    pass the gates move L_k, and L_k is re-learned after `mag_relearn_s` of continuous rejection
    (recovers from a changed field instead of trusting a drifted estimate)."""
    mag_relearn_s: float = 10.0
    """With mag_strength_update='accepted': after this long [s] of continuous rejection the field
    is taken as the new normal (L_k and m0's dip re-learned from the current readings)."""
    mag_dip_gate_deg: float = math.inf
    """Also reject a magnetometer reading whose angle to the measured gravity differs from the
    reference dip by more than this [deg] (inf: off). Needs an accepted accelerometer reading."""
    acc_lowpass_s: float = 0.0
    """Time constant [s] of a low-pass of the accelerometer that the gyroscope carries along with
    the phone (0: off, the raw reading is used). The update then sees the average specific force
    of the last seconds, in which accelerations cancel and gravity stays."""
    mag_dip_from_estimate: bool = False
    """False: the dip gate measures the field's angle to the accelerometer reading (disturbed by
    accelerations). True: to the estimated up direction, which stays good while moving."""
    mag_settle_s: float = 0.0
    """After a rejected reading, readings must pass the gates for this long [s] before the
    magnetometer is used again: a field that only now and then looks right (a magnet on the
    phone) stays out."""
    update_period_s: float = 0.0
    """Run the low-passed accelerometer, magnetometer and zero-rate updates at most this often
    [s]. They change slowly, so fewer updates cost little accuracy and save time. 0: every
    sample (the course's filter)."""
    mag_nis_gate: float = math.inf
    """Also reject a magnetometer reading whose normalised innovation squared exceeds this
    (chi-square, 1 dof heading-only, 3 dof full) [-] (inf: off)."""
    acc_nis_gate: float = math.inf
    """Also reject an accelerometer reading whose normalised innovation squared exceeds this
    (chi-square, 3 dof) [-] (inf: off). Scales with the innovation rather than only ||a||."""

    # --- model extensions -----------------------------------------------------------------
    exact_discretisation: bool = False
    """False: F = I + T/2 S(w) (course, task 3). True: F = exp(T/2 S(w)) (exact for constant w)."""
    mag_heading_only: bool = False
    """True: the magnetometer update may only turn the estimate about world up (footnote 2),
    so a disturbed field cannot tilt it."""
    estimate_gyro_bias: bool = False
    """True: model 4c, x = (q, b_w), gyro bias as a random walk, plus a zero-rate update at rest."""
    gyro_bias_random_walk: float = 1e-4
    """Bias random walk [rad/s/sqrt(s)] (model 4c)."""
    initial_gyro_bias_std: float = 0.01
    """Initial bias standard deviation [rad/s] (model 4c)."""
    rest_rate_noise_std: float = 0.01
    """Standard deviation of the zero-rate pseudo-measurement at rest [rad/s] (model 4c)."""

    # --- timing -----------------------------------------------------------------------------
    max_dt: float = 0.5
    """A time step longer than this [s] is a pause or a restart: it is not integrated."""
    gyr_hold_s: float = 0.1
    """A gyroscope sample keeps driving the time update for at most this long [s]."""

    # --- rest detection -------------------------------------------------------------------
    rest_gyr_threshold: float = 0.05
    """||w - b|| below this [rad/s] counts as still."""
    rest_acc_threshold: float = 0.3
    """||a - lowpass(a)|| below this [m/s^2] counts as still."""
    rest_min_duration: float = 0.5
    """Still for this long [s] -> at_rest."""

    # ---------------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for k, v in d.items():
            if isinstance(v, float) and math.isinf(v):
                d[k] = "inf"
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "EKFSettings":
        """Build settings from a dict (e.g. JSON). Unknown keys raise ValueError naming them."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"unknown setting(s): {', '.join(unknown)}")
        clean: dict[str, Any] = {}
        for k, v in d.items():
            if v == "inf":
                v = math.inf
            if k in ("m0", "gyr_bias") and v is not None:
                v = tuple(float(x) for x in v)
                if len(v) != 3:
                    raise ValueError(f"setting {k} needs 3 values")
            if k.endswith("_cov"):
                v = [[float(x) for x in row] for row in v]
                if len(v) != 3 or any(len(row) != 3 for row in v):
                    raise ValueError(f"setting {k} must be a 3x3 matrix")
            clean[k] = v
        s = cls(**clean)
        if s.mag_strength_update not in ("always", "accepted"):
            raise ValueError("mag_strength_update must be 'always' or 'accepted'")
        return s

    def with_changes(self, **changes: Any) -> "EKFSettings":
        return replace(self, **changes)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> "EKFSettings":
        """Read a settings JSON file (a plain settings dict, or a `calibrate` output holding one
        under the key "settings")."""
        data = json.loads(Path(path).read_text())
        if isinstance(data, dict) and "settings" in data and isinstance(data["settings"], dict):
            data = data["settings"]
        if not isinstance(data, dict):
            raise ValueError("settings file must hold a JSON object")
        return cls.from_dict(data)


COURSE = EKFSettings()

# Chosen on the shared BROAD trials and phone logs (benchmarks/accuracy.py), one set for all,
# in the middle of a plateau (every single value halved or doubled keeps the BROAD mean within
# 10%; see README "Settings"):
# - gyroscope: exact discretisation, the sample as the rate over the interval before it, bias in
#   the state with a zero-rate update at rest, R_w growing with 1% scale uncertainty;
# - accelerometer: low-passed over 0.5 s in a frame carried by the gyroscope (no reading is
#   dropped; the norm gate only lights the "disturbed" light);
# - magnetometer: heading only, strength and dip gates as VQF uses them (5 uT, 10 deg, dip from
#   the estimate), 0.5 s of passing readings before use, a changed field re-learned after 20 s
#   of consistent readings;
# - the slow updates (low-passed accelerometer, magnetometer, zero rate) at most every 50 ms.
DEFAULT = EKFSettings(
    exact_discretisation=True,
    gyr_rate_before_sample=True,
    gyr_noise_cov=_diag(3e-4),
    gyr_scale_noise=0.01,
    estimate_gyro_bias=True,
    gyro_bias_random_walk=1e-5,
    rest_rate_noise_std=0.003,
    acc_lowpass_s=0.5,
    acc_noise_cov=_diag(0.3),
    acc_gate=2.0,
    mag_heading_only=True,
    mag_noise_cov=_diag(1.0),
    mag_gate=5.0,
    mag_dip_gate_deg=10.0,
    mag_dip_from_estimate=True,
    mag_settle_s=0.5,
    mag_strength_update="accepted",
    mag_relearn_s=20.0,
    update_period_s=0.05,
)

PRESETS: dict[str, EKFSettings] = {"default": DEFAULT, "course": COURSE}
