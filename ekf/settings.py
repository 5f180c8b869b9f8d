"""Filter settings: one dataclass whose fields carry their unit and explanation, and named presets.

Every number a user may want to tune lives here, so a settings file (JSON) describes a run
completely. ``PRESETS["course"]`` is the plain course filter (model 4a, tasks 1-11);
``PRESETS["default"]`` adds the extensions that pay on real data (docs/filter.md).

Each field's unit and one-line explanation are in its ``dataclasses.field`` metadata ("unit",
"doc"; "shape" for vectors and matrices, "choices" for a word; "search" for the range a
tuning search tries, :func:`search_ranges`), readable at run time:
:func:`settings_rows` lists every setting with its default, course value, unit and explanation
(the table in docs/filter.md and a settings panel are made from it), and the compiled
filter's packed settings layout is generated from the same fields (``ekf.fast.layout``).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any, NamedTuple

# How a field is declared and checked lives in ekf.settings_fields; its public names are
# importable from here too.
from ekf.settings_fields import (SearchRange, SettingsError, _setting, allowed_text, check_value,
                                 shown_value)


def _diag(value: float) -> list[list[float]]:
    return [[value, 0.0, 0.0], [0.0, value, 0.0], [0.0, 0.0, value]]


@dataclass(frozen=True)
class EKFSettings:
    """Settings of the quaternion EKF; see each field's metadata (or :func:`settings_rows`) for
    its unit and meaning. Covariances are 3x3 nested lists.

    Measurement models (course eqs. 7-8): y_a = Q(q)^T g0 + e_a with g0 = (0, 0, g);
    y_m = Q(q)^T m0 + e_m with m0 in ENU.
    """

    # --- sensor models --------------------------------------------------------------------
    g: float = _setting(9.81, unit="m/s²", doc="expected ‖a‖ at rest; g⁰ = (0, 0, g)",
                        low=1.0, high=100.0)
    m0: tuple[float, float, float] | None = _setting(
        None, unit="µT (ENU)", shape=(3,),
        doc="Earth field (0, horizontal, vertical); none: from the first magnetometer reading, "
            "tilt-compensated with the first accelerometer reading (the course's flat reading)",
            optional=True)
    gyr_bias: tuple[float, float, float] = _setting(
        (0.0, 0.0, 0.0), unit="rad/s", shape=(3,),
        doc="subtracted from every gyroscope sample (from `calibrate`); with "
            "`estimate_gyro_bias` the initial bias estimate")
    mag_hard_iron: tuple[float, float, float] = _setting(
        (0.0, 0.0, 0.0), unit="µT", shape=(3,),
        doc="hard-iron offset b: every magnetometer reading becomes S (y_m − b) before any "
            "estimator sees it (from `calibrate-mag`; applied by the app's runner)")
    mag_soft_iron: list[list[float]] = _setting(
        unit="-", shape=(3, 3), factory=lambda: _diag(1.0),
        doc="soft-iron matrix S of that correction (identity: none)", matrix="invertible")

    # --- noise ----------------------------------------------------------------------------
    gyr_noise_cov: list[list[float]] = _setting(
        unit="(rad/s)²", shape=(3, 3), factory=lambda: _diag(1e-4),
        doc="R_w: covariance of the angular-rate noise v_k (eq. 5)", matrix="covariance",
        search=(1e-6, 1e-1))
    acc_noise_cov: list[list[float]] = _setting(
        unit="(m/s²)²", shape=(3, 3), factory=lambda: _diag(0.1),
        doc="R_a: accelerometer noise, larger than the sensor's own to absorb small specific "
            "forces", matrix="covariance", search=(0.1, 3.0, 0.1))
    mag_noise_cov: list[list[float]] = _setting(
        unit="µT²", shape=(3, 3), factory=lambda: _diag(2.0),
        doc="R_m: magnetometer noise (heading-only: σ_ψ² = tr(R_m)/3 / ‖m_horizontal‖²)",
        matrix="covariance", search=(0.1, 10.0, 0.1))
    gyr_scale_noise: float = _setting(
        0.0, unit="-",
        doc="relative uncertainty k of the gyroscope's scale: R_w grows by (k‖ω‖)² I, so fast "
            "turns are trusted less (0: the course's constant R_w)", high=1.0, search=(1e-4, 0.1))
    gyr_rate_before_sample: bool = _setting(
        False, unit="-",
        doc="true: a gyroscope sample is the rate over the interval that ends at its time stamp "
            "and drives the state up to it (no lag of one sample period); false (eq. 5): it "
            "drives the state from its time to the next sample")
    no_gyro_random_walk: float = _setting(
        1.0, unit="rad/√s",
        doc="orientation random walk when no gyroscope sample drives the time update: q stays, "
            "P grows (task 12, acc+mag only)", search=(1e-2, 10.0))
    initial_attitude_std: float = _setting(
        0.05, unit="rad", doc="standard deviation of the initial attitude from acc+mag",
        above=True, search=(1e-3, 1.0))

    # --- outlier gates (tasks 8 and 11) -----------------------------------------------------
    acc_gate: float = _setting(
        1.0, unit="m/s²",
        doc="reject an accelerometer reading when |‖y_a‖ − g| > gate (task 8); with the low-pass "
            "the reading is only flagged; 0: every reading out; inf: off", inf=True,
        search=(0.2, 10.0))
    mag_gate: float = _setting(
        5.0, unit="µT",
        doc="reject a magnetometer reading when |‖y_m‖ − L_k| > gate (task 11); 0: every "
            "reading out; inf: off", inf=True, search=(4.0, 16.0, 1.0))
    mag_alpha: float = _setting(
        0.01, unit="-",
        doc="AR(1) coefficient of the field strength L_k = (1 − α) L_{k−1} + α ‖y_m‖",
        high=1.0, search=(1e-3, 0.3))
    mag_strength_update: str = _setting(
        "always", unit="-", choices=("always", "accepted"),
        doc="'always': every reading moves L_k (the course); 'accepted': only readings that pass "
            "the gates, and a changed field is re-learned (`mag_relearn_s`)")
    mag_relearn_s: float = _setting(
        10.0, unit="s",
        doc="with 'accepted': rejected (or still settling) readings that agree with each other "
            "this long (strength and dip within the gates of their running mean) are the new "
            "normal: L_k and m0 are re-learned from the current reading; a magnet that moves "
            "with the phone never agrees for long", inf=True, search=(1.0, 120.0))
    mag_dip_gate_deg: float = _setting(
        math.inf, unit="deg",
        doc="also reject a magnetometer reading whose angle to up differs from the reference "
            "dip by more than this; inf: off", above=True, inf=True, search=(10.0, 40.0, 1.0))
    acc_range: float = _setting(
        math.inf, unit="m/s²",
        doc="an accelerometer reading with an axis at the sensor's range is clipped and never "
            "enters an update: |axis| >= this; 0: detect the range from the data (an axis "
            "within 1 % of the largest |axis| seen so far, once that exceeds 1.5 g); inf: off",
            inf=True)
    acc_lowpass_s: float = _setting(
        0.0, unit="s",
        doc="time constant of a low-pass of the accelerometer that the gyroscope carries along "
            "with the phone; the update sees the average specific force, in which accelerations "
            "cancel (0: off, the raw reading is used)", search=(0.25, 3.0, 0.25))
    acc_noise_adapt: float = _setting(
        0.0, unit="-",
        doc="with the low-pass: R_a grows with how hard the phone is shaken, R_a (1 + this · "
            "d²/g²), d² the low-passed (‖y_a‖ − g)² (clipped readings included): running and "
            "swinging cannot tilt the estimate (0: off)",
        # searched from 30: the low-pass (~0.75 s) of step-correlated accelerations (~0.1-0.2 s)
        # keeps ~τ_c/2τ of their variance, 0.2·k/g² ≈ 0.07-0.13 gives k ≈ 30-65 (twice that
        # counting the two axes the norm does not see); below it a fold tuned without running
        # lets running tilt the estimate (held out 9-13 deg)
        search=(30.0, 300.0, 1.0))
    acc_tilt_only_after_s: float = _setting(
        math.inf, unit="s",
        doc="once no magnetometer update has run for this long (none, switched off, or out for "
            "a disturbance), the accelerometer update corrects only what gravity observes: its "
            "gain on the heading and on the bias about up is projected out (Joseph form keeps P "
            "consistent). Through correlations in P, accelerations would otherwise turn the "
            "heading and teach the bias about up a rate it cannot see (inf: off)", inf=True)
    mag_dip_from_estimate: bool = _setting(
        False, unit="-",
        doc="true: the dip gate measures the field's angle to the estimated up (good while "
            "moving); false: to the accelerometer reading")
    mag_settle_s: float = _setting(
        0.0, unit="s",
        doc="after a rejection, readings must pass the gates this long before the magnetometer "
            "is used again (a magnet on the phone stays out)", inf=True, search=(0.05, 5.0))
    mag_hard_iron_tau_s: float = _setting(
        0.0, unit="s",
        doc="estimate the magnetometer's offset in the sensor frame (hard iron: a magnet on the "
            "phone) online and subtract it from every reading: pairs of readings the phone turned "
            "20° between must differ by that turn (y_j − b = Q_jᵀ Q_i (y_i − b)), a weighted "
            "least-squares fit remembering this long; 0: off", search=(20.0, 300.0, 10.0))
    mag_hard_iron_prior: float = _setting(
        1.0, unit="-",
        doc="weight of the prior b_m = 0 in that fit, in pairs of a full turn's worth: small "
            "offsets (a field that is not quite uniform) stay near zero, a magnet's hundreds of "
            "µT do not", above=True, search=(0.3, 10.0, 0.1))
    mag_delay_s: float = _setting(
        0.0, unit="s",
        doc="the magnetometer's readings are this much older than their time stamps (its own "
            "filtering and delivery): that fit turns each reading on to its stamp by the "
            "gyroscope, y ← b + R(−(ω − b_ω)·this)(y − b), so that a pair's turn is the turn "
            "between its readings (the heading update is not turned); 0: off")
    mag_noise_adapt: float = _setting(
        0.0, unit="-",
        doc="R_m grows where the field is uneven: R_m (1 + this · d²/L_k²), d² the low-pass "
            "(time constant mag_return_s) of (‖y_m‖ − L_k)² over every reading, rejected ones "
            "included (each at most `mag_noise_adapt_clip` gates off); only while the gyroscope "
            "drives the filter (0: off)", search=(100.0, 10000.0, 100.0))
    mag_noise_adapt_clip: float = _setting(
        math.inf, unit="gates",
        doc="in that low-pass a reading counts as at most this many `mag_gate`s off: a reading "
            "far beyond the gate is a magnet passing, rejected anyway, and its size says nothing "
            "about how the passing readings bend (a 100 µT spike would keep R_m large for tens "
            "of seconds after it); inf: off", above=True, inf=True)
    mag_reference_s: float = _setting(
        0.0, unit="s",
        doc="the expected field (strength L_k and the reference m0 with its dip) is the mean of "
            "the readings over this long from the first one, used meanwhile without the gates "
            "(0: the first reading decides)")
    mag_max_reject_no_gyro_s: float = _setting(
        math.inf, unit="s",
        doc="while no gyroscope drives the time update, a disturbance (rejected or settling "
            "readings) keeps the magnetometer out at most this long, then its readings are used "
            "with R_m x `mag_reject_noise_scale` until it ends: without a gyroscope the field is "
            "all the heading there is (with one, a disturbance keeps it out until readings pass "
            "the gates again or agree as a new field); inf: off", inf=True)
    mag_reject_noise_scale: float = _setting(
        10.0, unit="-",
        doc="R_m is multiplied by this for readings used past that bound", above=True)
    mag_relearn_world: bool = _setting(
        False, unit="-",
        doc="true: re-learning compares the rejected readings in the world frame (Q(q) y_m: a "
            "changed field in a building stays put, a magnet on the phone turns with it), counts "
            "time only while the phone turns faster than `mag_relearn_min_rate`; the new m0 "
            "takes their strength and dip, north stays (the heading follows no faster than "
            "`mag_return_s`); false: strength and dip agree, m0 from the latest reading")
    mag_first_relearn_s: float = _setting(
        0.0, unit="s",
        doc="with `mag_relearn_world`: until readings have passed the gates for this long in "
            "all, the expected field is young (it may have been learned in a disturbance, a "
            "recording started beside a laptop): rejected readings that agree this long (or "
            "`mag_relearn_s` if shorter), turning or not, are the new normal (VQF's "
            "magNewFirstTime); 0: off")
    mag_relearn_min_rate: float = _setting(
        0.0, unit="rad/s",
        doc="with `mag_relearn_world`: rejected readings count towards re-learning only while "
            "‖ω − b‖ is at least this (VQF: 20°/s)")
    mag_return_s: float = _setting(
        0.0, unit="s",
        doc="the heading follows the magnetometer no faster than this time constant: each "
            "heading update corrects at most dt/(dt + this) of the innovation (dt since the "
            "previous update), so the estimate comes back from a disturbance without a jump "
            "(0: off)", search=(2.0, 20.0, 1.0))
    mag_bias_innovation_limit: float = _setting(
        math.inf, unit="σ",
        doc="a heading update teaches the gyroscope bias from at most this many standard "
            "deviations of its innovation (its bias gain is scaled by limit·√S/|ψ| beyond): a "
            "heading far off says the field or the heading is wrong (a disturbance that passed "
            "the gates, a start beside a magnet), not the bias; inf: off", inf=True)
    update_period_s: float = _setting(
        0.0, unit="s",
        doc="run the low-passed accelerometer, magnetometer and zero-rate updates at most this "
            "often (they change slowly; 0: every sample, the course's filter)")
    mag_nis_gate: float = _setting(
        math.inf, unit="-",
        doc="also reject a magnetometer reading whose normalised innovation squared exceeds "
            "this (χ², 1 dof heading-only, 3 dof full); inf: off", above=True, inf=True)
    acc_nis_gate: float = _setting(
        math.inf, unit="-",
        doc="also reject an accelerometer reading whose normalised innovation squared exceeds "
            "this (χ², 3 dof); inf: off", above=True, inf=True)

    # --- model extensions -----------------------------------------------------------------
    exact_discretisation: bool = _setting(
        False, unit="-",
        doc="true: F = exp(T/2 S(ω)) (exact for constant ω); false: F = I + T/2 S(ω) (task 3)")
    mag_heading_only: bool = _setting(
        False, unit="-",
        doc="true: the magnetometer may only turn the estimate about world up (footnote 2), so "
            "a disturbed field cannot tilt it")
    estimate_gyro_bias: bool = _setting(
        False, unit="-",
        doc="true: model 4c, x = (q, b_ω) with the bias a random walk, plus a zero-rate update "
            "at rest")
    gyro_bias_random_walk: float = _setting(
        1e-4, unit="rad/s/√s", doc="bias random walk (model 4c)", search=(1e-7, 1e-3))
    initial_gyro_bias_std: float = _setting(
        0.01, unit="rad/s", doc="initial bias standard deviation (model 4c)")
    rest_rate_noise_std: float = _setting(
        0.01, unit="rad/s",
        doc="standard deviation of the zero-rate pseudo-measurement at rest (model 4c)",
        above=True, search=(1e-4, 0.1))

    # --- timing -----------------------------------------------------------------------------
    max_dt: float = _setting(
        0.5, unit="s", doc="a longer time step is a pause or a reconnect: it is not integrated",
        above=True, inf=True)
    gyr_hold_s: float = _setting(
        0.1, unit="s", doc="a gyroscope sample keeps driving the time update at most this long",
        inf=True)

    # --- rest detection -------------------------------------------------------------------
    rest_gyr_threshold: float = _setting(
        0.05, unit="rad/s", doc="‖ω − b‖ below this counts as still")
    rest_acc_threshold: float = _setting(
        0.3, unit="m/s²", doc="‖a − lowpass(a)‖ below this counts as still")
    rest_min_duration: float = _setting(
        0.5, unit="s", doc="still this long: at rest (standstill)", inf=True)

    # --- the offline smoother ------------------------------------------------------------
    smooth_hard_iron: bool = _setting(
        True, unit="-",
        doc="the offline smoother's forward pass keeps the online hard-iron fit "
            "(`mag_hard_iron_tau_s`); false: it runs without it (the backward pass smooths "
            "q and b only, so the fit's changes would be spread over the whole recording)")

    # ---------------------------------------------------------------------------------------
    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, check_value(f, getattr(self, f.name)))

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for k, v in d.items():
            if isinstance(v, float) and math.isinf(v):
                d[k] = "inf"
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "EKFSettings":
        """Settings from a dict (e.g. JSON): the preset named by its key "preset" (the default
        preset when it names none) with the dict's values. Unknown keys and values a setting
        does not allow raise :class:`SettingsError` naming them."""
        if not isinstance(d, dict):
            raise SettingsError("settings must be a JSON object of setting: value")
        values = dict(d)
        preset = values.pop("preset", "default")
        if not isinstance(preset, str) or preset not in PRESETS:
            raise SettingsError(f"setting preset = {shown_value(preset)}: must be "
                                + " or ".join(repr(p) for p in PRESETS))
        unknown = sorted(set(values) - {f.name for f in fields(cls)}, key=str)
        if unknown:
            raise SettingsError(f"unknown setting(s): {', '.join(map(str, unknown))}")
        return replace(PRESETS[preset], **values)

    def with_changes(self, **changes: Any) -> "EKFSettings":
        return replace(self, **changes)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> "EKFSettings":
        """Read a settings JSON file (a plain settings dict, or a `calibrate` output holding one
        under the key "settings"); a file larger than :data:`MAX_FILE_BYTES` is refused."""
        return cls.from_file_value(read_json(path))

    @classmethod
    def from_file_value(cls, data: Any) -> "EKFSettings":
        """Settings from a settings file's JSON value: a plain settings dict, or a file holding
        one under the key "settings" (`calibrate`, `tune`, a session.json)."""
        if isinstance(data, dict) and isinstance(data.get("settings"), dict):
            data = data["settings"]
        if not isinstance(data, dict):
            raise SettingsError("settings file must hold a JSON object")
        return cls.from_dict(data)


MAX_FILE_BYTES = 4 * 1024 * 1024


def read_json(path: str | Path, limit: int = MAX_FILE_BYTES) -> Any:
    """The JSON value in a file of at most ``limit`` bytes (settings, profiles, session.json:
    a larger one, or a device that never ends, is refused without reading it all)."""
    with open(path, "rb") as file:
        raw = file.read(limit + 1)
    if len(raw) > limit:
        raise ValueError(f"larger than {limit // (1024 * 1024)} MB; not a settings file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        raise ValueError(f"not UTF-8 text (byte {error.start})") from None
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError("JSON nested too deeply to be a settings or session file") from None


COURSE = EKFSettings()

# The course filter with the mechanisms that earn their place on recordings they were not
# chosen on (benchmarks/ablation.py; what each does and why: docs/filter.md, "The default preset"):
# - gyroscope: exact discretisation, the sample as the rate over the interval before it, bias
#   in the state with a zero-rate update at rest, R_w growing with a 2 % scale uncertainty;
# - accelerometer: low-passed over 0.75 s in a frame the gyroscope carries, clipped readings
#   left out (the range detected from the data), R_a growing with the shaking, tilt only once
#   the magnetometer has been silent for 2 s;
# - magnetometer: heading only, following the field with a 7 s time constant at the fastest,
#   R_m growing where the field is uneven (a reading counting at most 4 gates there);
#   strength and dip gates around the mean of the first second's agreeing readings, 0.5 s of
#   passing readings before use; with a gyroscope a rejected reading stays out until readings
#   pass or agree as a new field (in the world frame while turning, 20 s; 5 s while the
#   learned field is young); the bias learns from at most 1.345 sigma of a heading innovation;
#   the sensor-frame offset fitted online over 4 minutes (readings 30 ms late) and applied where
#   it explains what the field alone does not;
# - the slow updates at most every 50 ms; the smoother's forward pass without the online fit.
DEFAULT = EKFSettings(
    exact_discretisation=True,
    gyr_rate_before_sample=True,
    gyr_noise_cov=_diag(3e-4),
    gyr_scale_noise=0.02,
    estimate_gyro_bias=True,
    gyro_bias_random_walk=1e-5,
    rest_rate_noise_std=0.003,
    acc_lowpass_s=0.75,
    acc_noise_cov=_diag(0.2),
    acc_noise_adapt=50.0,
    acc_tilt_only_after_s=2.0,
    acc_gate=2.0,
    acc_range=0.0,
    mag_heading_only=True,
    mag_noise_cov=_diag(1.0),
    mag_noise_adapt=1000.0,
    mag_noise_adapt_clip=4.0,
    mag_return_s=7.0,
    mag_gate=5.0,
    mag_dip_gate_deg=20.0,
    mag_dip_from_estimate=True,
    mag_settle_s=0.5,
    mag_reference_s=1.0,
    mag_max_reject_no_gyro_s=0.0,
    mag_strength_update="accepted",
    mag_relearn_s=20.0,
    mag_relearn_world=True,
    mag_relearn_min_rate=round(math.radians(20.0), 4),
    mag_first_relearn_s=5.0,
    mag_bias_innovation_limit=1.345,
    mag_hard_iron_tau_s=240.0,
    mag_hard_iron_prior=0.4,
    mag_delay_s=0.03,
    update_period_s=0.05,
    smooth_hard_iron=False,
)

PRESETS: dict[str, EKFSettings] = {"default": DEFAULT, "course": COURSE}


def resolve_settings(settings: EKFSettings | str | None) -> EKFSettings:
    """An :class:`EKFSettings` as given, a preset by name, or the default preset for None."""
    if settings is None:
        return PRESETS["default"]
    if isinstance(settings, str):
        if settings not in PRESETS:
            raise ValueError(f"unknown preset {settings!r}; choose from {', '.join(PRESETS)}")
        return PRESETS[settings]
    return settings


# ---- the settings as rows (docs/filter.md table, settings panel) ----------------------------
class SettingRow(NamedTuple):
    """One setting: its name, the default and course presets' values, unit, explanation, what
    it allows and the range a tuning search tries ("" where none is declared)."""

    name: str
    default: Any
    course: Any
    unit: str
    doc: str
    allowed: str
    search: str = ""


def search_text(r: SearchRange | None) -> str:
    """A search range in words: ``0.1..3`` (searched on a log scale), "" for none."""
    return "" if r is None else f"{r.low:g}..{r.high:g}"


def settings_rows() -> list[SettingRow]:
    """Every field of :class:`EKFSettings` in declaration order (values as stored)."""
    return [SettingRow(f.name, getattr(PRESETS["default"], f.name),
                       getattr(PRESETS["course"], f.name), f.metadata["unit"], f.metadata["doc"],
                       allowed_text(f), search_text(f.metadata["search"]))
            for f in fields(EKFSettings)]


def search_ranges() -> dict[str, SearchRange]:
    """The declared search range of every setting that has one, in declaration order."""
    return {f.name: f.metadata["search"] for f in fields(EKFSettings)
            if f.metadata["search"] is not None}


def format_value(value: Any) -> str:
    """A short text for a setting's value: ``inf``, ``true``, ``none``, ``3e-04·I`` for an
    isotropic matrix, ``(0, 0, 0)`` for a vector, ``%g`` for a number."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return value
    if isinstance(value, (int, float)):
        return "inf" if math.isinf(value) else f"{value:g}"
    if isinstance(value, (list, tuple)) and value and isinstance(value[0], (list, tuple)):
        diag = value[0][0]
        if all(value[i][j] == (diag if i == j else 0.0) for i in range(3) for j in range(3)):
            return f"{diag:g}·I"
        return "[" + "; ".join(" ".join(f"{x:g}" for x in row) for row in value) + "]"
    return "(" + ", ".join(f"{x:g}" for x in value) + ")"
