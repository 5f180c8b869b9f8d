"""Filter settings: one dataclass whose fields carry their group, unit, explanation, typical
value and what they allow; the groups; how a value is checked; and the named presets.

Every number a user may want to tune lives here, so a settings file (JSON) describes a run
completely. ``PRESETS["course"]`` is the plain course filter (model 4a, tasks 1-11);
``PRESETS["default"]`` adds the extensions that pay on real data (docs/filter.md).

The settings come in named groups (:data:`GROUPS`, in the order the tables show them), one per
part of the filter; a group whose mechanism can be off names its switch (:class:`When`): a
setting of its own (a flag, a word) or the value of one of its settings that turns it off (0,
inf). A setting that only acts while another one is on says so in its ``requires``.

Each field's metadata ("group", "unit", "doc", "typical", "requires"; "shape" for vectors and
matrices, "choices" for a word; what a number allows; "search" for the range a tuning search
tries, :func:`search_ranges`) is readable at run time: :func:`settings_rows` lists every
setting with its group, default, course value, typical value, unit and explanation (the tables
in docs/filter.md and the settings panel are made from it), :func:`inactive_reason` says why a
setting has no effect in given settings, and the compiled filter's packed settings layout is
generated from the same fields (``ekf.fast.layout``).
"""

from __future__ import annotations

import json
import math
from dataclasses import MISSING, asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Callable, NamedTuple


# ---- the groups -----------------------------------------------------------------------------
class When(NamedTuple):
    """A condition on one setting: ``name`` is on, that is, not at its ``off`` value (False for
    a flag, 0 or inf for a number, a word for a choice)."""

    name: str
    off: Any

    def holds(self, settings: "EKFSettings") -> bool:
        return getattr(settings, self.name) != self.off

    def text(self) -> str:
        """The condition in words: ```x` = true``, ```x` > 0``, ```x` < inf``, ```x` ≠ 'w'``."""
        if isinstance(self.off, bool):
            return f"`{self.name}` = {'false' if self.off else 'true'}"
        if isinstance(self.off, str):
            return f"`{self.name}` ≠ '{self.off}'"
        return f"`{self.name}` < inf" if math.isinf(self.off) else f"`{self.name}` > {self.off:g}"


class Group(NamedTuple):
    """A part of the filter and its settings: ``name`` (the key in each field's metadata),
    ``title``, one line of what it does, and its ``switch`` (None: always on)."""

    name: str
    title: str
    doc: str
    switch: When | None = None


GROUPS: tuple[Group, ...] = (
    Group("calibration", "Sensor calibration",
          "what `calibrate` (at rest) and `calibrate-mag` (turning) measure for one phone; zero "
          "offsets and the identity apply no correction"),
    Group("start", "Start",
          "how the estimate starts: the initial attitude from the first accelerometer and "
          "magnetometer readings and the field it expects"),
    Group("gyroscope", "Gyroscope and time update",
          "how a gyroscope sample turns the estimate and how much it is trusted (without a "
          "gyroscope, `--sensors acc,mag`, the random walk alone)"),
    Group("bias", "Gyroscope bias",
          "the gyroscope's bias in the state (model 4c), learned from the updates and a "
          "zero-rate update at rest", When("estimate_gyro_bias", False)),
    Group("rest", "Rest detection",
          "when the phone counts as still (the `at_rest` flag and the bias's zero-rate update)",
          When("rest_min_duration", math.inf)),
    Group("accelerometer", "Accelerometer update",
          "the accelerometer's correction of the tilt (task 8) and the readings it leaves out"),
    Group("acc_lowpass", "Accelerometer low-pass",
          "the update sees the accelerometer averaged in a frame the gyroscope carries, so "
          "accelerations cancel", When("acc_lowpass_s", 0.0)),
    Group("magnetometer", "Magnetometer update",
          "the magnetometer's correction of the heading (task 11) and how much it is trusted"),
    Group("mag_field", "Expected field and magnetometer gates",
          "the field strength and dip a reading must match to be used, and what happens to a "
          "reading that does not"),
    Group("mag_relearn", "Re-learning a changed field",
          "readings that are rejected but agree with each other long enough become the new "
          "expected field (a building's field, not a magnet on the phone)",
          When("mag_strength_update", "always")),
    Group("hard_iron", "Online hard-iron fit",
          "the magnetometer's offset in the sensor frame (a magnet on the phone) fitted online "
          "from pairs of readings the gyroscope says turned, and subtracted",
          When("mag_hard_iron_tau_s", 0.0)),
    Group("timing", "Timing",
          "how gaps, stale gyroscope samples and the rate of the slow updates are handled"),
)

GROUP_BY_NAME: dict[str, Group] = {g.name: g for g in GROUPS}


# ---- how a setting is declared and checked ----------------------------------------------------
def _setting(default: Any = MISSING, *, group: str, unit: str, doc: str, typical: str,
             requires: When | None = None, shape: tuple[int, ...] = (),
             choices: tuple[str, ...] | None = None,
             factory: Callable[[], Any] | None = None, low: float = 0.0, above: bool = False,
             high: float | None = None, inf: bool = False, matrix: str | None = None,
             optional: bool = False, search: tuple[float, ...] | None = None) -> Any:
    """A settings field of ``group`` (a name in :data:`GROUPS`) with its unit ("-" when it has
    none), one-line explanation, a typical value (a range or a sentence), the setting it
    ``requires`` beyond its group's switch, and what it allows: a number from ``low``
    (excluded when ``above``) up to ``high``, infinity only with ``inf``; a vector of ``shape``
    (``optional``: or none); a matrix that is ``"covariance"`` (symmetric positive definite)
    or ``"invertible"``; a word from ``choices``. ``search``: the range a tuning search tries,
    ``(low, high)`` or ``(low, high, round_to)`` (:class:`SearchRange`), inside what the
    setting allows."""
    if group not in GROUP_BY_NAME:
        raise ValueError(f"no settings group {group!r}")
    metadata = {"group": group, "unit": unit, "doc": doc, "typical": typical,
                "requires": requires, "shape": shape, "choices": choices, "low": low,
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


def _diag(value: float) -> list[list[float]]:
    return [[value, 0.0, 0.0], [0.0, value, 0.0], [0.0, 0.0, value]]


@dataclass(frozen=True)
class EKFSettings:
    """Settings of the quaternion EKF, in the groups of :data:`GROUPS`; see each field's
    metadata (or :func:`settings_rows`) for its unit and meaning. Covariances are 3x3 nested
    lists.

    Measurement models (course eqs. 7-8): y_a = Q(q)^T g0 + e_a with g0 = (0, 0, g);
    y_m = Q(q)^T m0 + e_m with m0 in ENU.
    """

    # each field names its group (GROUPS); grouped_rows() lists them group by group
    g: float = _setting(
        9.81, group="calibration", unit="m/s²", doc="expected ‖a‖ at rest; g⁰ = (0, 0, g)",
        typical="9.78-9.83 (the local gravity; `calibrate` measures the phone's own)",
        low=1.0, high=100.0)
    m0: tuple[float, float, float] | None = _setting(
        None, group="start", unit="µT (ENU)", shape=(3,),
        doc="Earth field (0, horizontal, vertical); none: from the first magnetometer reading, "
            "tilt-compensated with the first accelerometer reading (the course's flat reading)",
        typical="none; or from `calibrate`: a strength of 25-65 µT", optional=True)
    gyr_bias: tuple[float, float, float] = _setting(
        (0.0, 0.0, 0.0), group="calibration", unit="rad/s", shape=(3,),
        doc="subtracted from every gyroscope sample (from `calibrate`); also the initial bias "
            "estimate of `estimate_gyro_bias`",
        typical="a phone's is 0.001-0.02 per axis; (0, 0, 0) when the bias is estimated")
    mag_hard_iron: tuple[float, float, float] = _setting(
        (0.0, 0.0, 0.0), group="calibration", unit="µT", shape=(3,),
        doc="hard-iron offset b: every magnetometer reading becomes S (y_m − b) before any "
            "estimator sees it (from `calibrate-mag`; applied by the app's runner)",
        typical="(0, 0, 0) for a phone that calibrates its magnetometer itself; tens to "
                "hundreds of µT for a raw sensor")
    mag_soft_iron: list[list[float]] = _setting(
        group="calibration", unit="-", shape=(3, 3), factory=lambda: _diag(1.0),
        doc="soft-iron matrix S of the hard-iron correction (identity: none)",
        typical="the identity, or within a few per cent of it (from `calibrate-mag`)",
        matrix="invertible")
    gyr_noise_cov: list[list[float]] = _setting(
        group="gyroscope", unit="(rad/s)²", shape=(3, 3), factory=lambda: _diag(1e-4),
        doc="R_w: covariance of the angular-rate noise v_k (eq. 5)", matrix="covariance",
        typical="1e-4·I to 1e-3·I (above the sensor's own noise from `calibrate`, to absorb "
                "model error)", search=(1e-6, 1e-1))
    acc_noise_cov: list[list[float]] = _setting(
        group="accelerometer", unit="(m/s²)²", shape=(3, 3), factory=lambda: _diag(0.1),
        doc="R_a: accelerometer noise, larger than the sensor's own to absorb small specific "
            "forces", typical="0.1·I to 1·I", matrix="covariance", search=(0.1, 3.0, 0.1))
    mag_noise_cov: list[list[float]] = _setting(
        group="magnetometer", unit="µT²", shape=(3, 3), factory=lambda: _diag(2.0),
        doc="R_m: magnetometer noise (heading-only: σ_ψ² = tr(R_m)/3 / ‖m_horizontal‖²)",
        typical="0.5·I to 5·I", matrix="covariance", search=(0.1, 10.0, 0.1))
    gyr_scale_noise: float = _setting(
        0.0, group="gyroscope", unit="-",
        doc="relative uncertainty k of the gyroscope's scale: R_w grows by (k‖ω‖)² I, so fast "
            "turns are trusted less (0: the course's constant R_w)",
        typical="0.01-0.03 (a phone gyroscope's scale error of a few per cent)", high=1.0,
        search=(1e-4, 0.1))
    gyr_rate_before_sample: bool = _setting(
        False, group="gyroscope", unit="-",
        doc="true: a gyroscope sample is the rate over the interval that ends at its time stamp "
            "and drives the state up to it (no lag of one sample period); false (eq. 5): it "
            "drives the state from its time to the next sample",
        typical="true (no lag of a sample period)")
    no_gyro_random_walk: float = _setting(
        1.0, group="gyroscope", unit="rad/√s",
        doc="orientation random walk when no gyroscope sample drives the time update: q stays, "
            "P grows (task 12, acc+mag only)", typical="0.1-3", search=(1e-2, 10.0))
    initial_attitude_std: float = _setting(
        0.05, group="start", unit="rad", doc="standard deviation of the initial attitude from "
        "acc+mag", typical="0.01-0.1", above=True, search=(1e-3, 1.0))
    acc_gate: float = _setting(
        1.0, group="accelerometer", unit="m/s²",
        doc="reject an accelerometer reading when |‖y_a‖ − g| > gate (task 8); under the "
            "low-pass (`acc_lowpass_s`) the reading is only flagged; 0: every reading out; "
            "inf: off", typical="1-3 (a tenth to a third of g)", inf=True, search=(0.2, 10.0))
    mag_gate: float = _setting(
        5.0, group="mag_field", unit="µT",
        doc="reject a magnetometer reading when |‖y_m‖ − L_k| > gate (task 11); 0: every "
            "reading out; inf: off", typical="4-10 (a tenth of the Earth's field)", inf=True,
        search=(4.0, 16.0, 1.0))
    mag_alpha: float = _setting(
        0.01, group="mag_field", unit="-",
        doc="AR(1) coefficient of the field strength L_k = (1 − α) L_{k−1} + α ‖y_m‖",
        typical="0.005-0.05 (L_k remembers 1/α readings)", high=1.0, search=(1e-3, 0.3))
    mag_strength_update: str = _setting(
        "always", group="mag_relearn", unit="-", choices=("always", "accepted"),
        doc="'always': every reading moves L_k (the course); 'accepted': only readings that pass "
            "the gates, and a changed field is re-learned (`mag_relearn_s`)",
        typical="'accepted' (a disturbance then cannot teach L_k its strength)")
    mag_relearn_s: float = _setting(
        10.0, group="mag_relearn", unit="s",
        doc="rejected (or still settling) readings that agree with each other this long "
            "(strength and dip within the gates of their running mean) are the new normal: L_k "
            "and m0 are re-learned from the current reading; a magnet that moves with the phone "
            "never agrees for long", typical="10-30", inf=True, search=(1.0, 120.0))
    mag_dip_gate_deg: float = _setting(
        math.inf, group="mag_field", unit="deg",
        doc="also reject a magnetometer reading whose angle to up differs from the reference "
            "dip by more than this; inf: off", typical="10-30", above=True, inf=True,
        search=(10.0, 40.0, 1.0))
    acc_range: float = _setting(
        math.inf, group="accelerometer", unit="m/s²",
        doc="an accelerometer reading with an axis at the sensor's range is clipped and never "
            "enters an update: |axis| >= this; 0: detect the range from the data (an axis "
            "within 1 % of the largest |axis| seen so far, once that exceeds 1.5 g); inf: off",
        typical="0 (detected from the data); or the sensor's range, e.g. 78.5 (±8 g)", inf=True)
    acc_lowpass_s: float = _setting(
        0.0, group="acc_lowpass", unit="s",
        doc="time constant of a low-pass of the accelerometer that the gyroscope carries along "
            "with the phone; the update sees the average specific force, in which accelerations "
            "cancel (0: off, the raw reading is used)", typical="0.5-1",
        search=(0.25, 3.0, 0.25))
    acc_noise_adapt: float = _setting(
        0.0, group="acc_lowpass", unit="-",
        doc="R_a grows with how hard the phone is shaken, R_a (1 + this · d²/g²), d² the "
            "low-passed (‖y_a‖ − g)² (clipped readings included): running and swinging cannot "
            "tilt the estimate (0: off)", typical="30-100",
        # searched from 30: the low-pass (~0.75 s) of step-correlated accelerations (~0.1-0.2 s)
        # keeps ~τ_c/2τ of their variance, 0.2·k/g² ≈ 0.07-0.13 gives k ≈ 30-65 (twice that
        # counting the two axes the norm does not see); below it a fold tuned without running
        # lets running tilt the estimate (held out 9-13 deg)
        search=(30.0, 300.0, 1.0))
    acc_tilt_only_after_s: float = _setting(
        math.inf, group="accelerometer", unit="s",
        doc="once no magnetometer update has run for this long (none, switched off, or out for "
            "a disturbance), the accelerometer update corrects only what gravity observes: its "
            "gain on the heading and on the bias about up is projected out (Joseph form keeps P "
            "consistent). Through correlations in P, accelerations would otherwise turn the "
            "heading and teach the bias about up a rate it cannot see (inf: off)",
        typical="1-5", inf=True)
    mag_dip_from_estimate: bool = _setting(
        False, group="mag_field", unit="-",
        doc="true: the dip gate measures the field's angle to the estimated up (good while "
            "moving); false: to the accelerometer reading",
        typical="true (the reading's up moves with every acceleration)",
        requires=When("mag_dip_gate_deg", math.inf))
    mag_settle_s: float = _setting(
        0.0, group="mag_field", unit="s",
        doc="after a rejection, readings must pass the gates this long before the magnetometer "
            "is used again (a magnet on the phone stays out)", typical="0.2-1", inf=True,
        search=(0.05, 5.0))
    mag_hard_iron_tau_s: float = _setting(
        0.0, group="hard_iron", unit="s",
        doc="estimate the magnetometer's offset in the sensor frame (hard iron: a magnet on the "
            "phone) online and subtract it from every reading: pairs of readings the phone turned "
            "20° between must differ by that turn (y_j − b = Q_jᵀ Q_i (y_i − b)), a weighted "
            "least-squares fit remembering this long; 0: off", typical="60-300",
        search=(20.0, 300.0, 10.0))
    mag_hard_iron_prior: float = _setting(
        1.0, group="hard_iron", unit="-",
        doc="weight of the prior b_m = 0 in the online fit, in pairs of a full turn's worth: "
            "small offsets (a field that is not quite uniform) stay near zero, a magnet's "
            "hundreds of µT do not", typical="0.3-2", above=True, search=(0.3, 10.0, 0.1))
    mag_delay_s: float = _setting(
        0.0, group="hard_iron", unit="s",
        doc="the magnetometer's readings are this much older than their time stamps (its own "
            "filtering and delivery): the online fit turns each reading on to its stamp by the "
            "gyroscope, y ← b + R(−(ω − b_ω)·this)(y − b), so that a pair's turn is the turn "
            "between its readings (the heading update is not turned); 0: off",
        typical="0.01-0.05 on phones")
    mag_noise_adapt: float = _setting(
        0.0, group="magnetometer", unit="-",
        doc="R_m grows where the field is uneven: R_m (1 + this · d²/L_k²), d² the low-pass "
            "(time constant mag_return_s) of (‖y_m‖ − L_k)² over every reading, rejected ones "
            "included (each at most `mag_noise_adapt_clip` gates off); only while the gyroscope "
            "drives the filter (0: off)", typical="300-3000", search=(100.0, 10000.0, 100.0))
    mag_noise_adapt_clip: float = _setting(
        math.inf, group="magnetometer", unit="gates",
        doc="in the low-pass of `mag_noise_adapt` a reading counts as at most this many "
            "`mag_gate`s off: a reading far beyond the gate is a magnet passing, rejected "
            "anyway, and its size says nothing about how the passing readings bend (a 100 µT "
            "spike would keep R_m large for tens of seconds after it); inf: off",
        typical="2-6", requires=When("mag_noise_adapt", 0.0), above=True, inf=True)
    mag_reference_s: float = _setting(
        0.0, group="start", unit="s",
        doc="the expected field (strength L_k and the reference m0 with its dip) is the mean of "
            "the readings over this long from the first one, used meanwhile without the gates "
            "(0: the first reading decides)", typical="0.5-2; 0 for the course's first reading")
    mag_max_reject_no_gyro_s: float = _setting(
        math.inf, group="mag_field", unit="s",
        doc="while no gyroscope drives the time update, a disturbance (rejected or settling "
            "readings) keeps the magnetometer out at most this long, then its readings are used "
            "with R_m x `mag_reject_noise_scale` until it ends: without a gyroscope the field is "
            "all the heading there is (with one, a disturbance keeps it out until readings pass "
            "the gates again or agree as a new field); inf: off",
        typical="0-2 (without a gyroscope nothing else holds the heading)", inf=True)
    mag_reject_noise_scale: float = _setting(
        10.0, group="mag_field", unit="-",
        doc="R_m is multiplied by this for readings used past `mag_max_reject_no_gyro_s`",
        typical="5-100", requires=When("mag_max_reject_no_gyro_s", math.inf), above=True)
    mag_relearn_world: bool = _setting(
        False, group="mag_relearn", unit="-",
        doc="true: re-learning compares the rejected readings in the world frame (Q(q) y_m: a "
            "changed field in a building stays put, a magnet on the phone turns with it), counts "
            "time only while the phone turns faster than `mag_relearn_min_rate`; the new m0 "
            "takes their strength and dip, north stays (the heading follows no faster than "
            "`mag_return_s`); false: strength and dip agree, m0 from the latest reading",
        typical="true (a magnet on the phone agrees with itself in the sensor frame)")
    mag_first_relearn_s: float = _setting(
        0.0, group="mag_relearn", unit="s",
        doc="until readings have passed the gates for this long in all, the expected field is "
            "young (it may have been learned in a disturbance, a recording started beside a "
            "laptop): rejected readings that agree this long (or `mag_relearn_s` if shorter), "
            "turning or not, are the new normal (VQF's magNewFirstTime); 0: off",
        typical="3-10", requires=When("mag_relearn_world", False))
    mag_relearn_min_rate: float = _setting(
        0.0, group="mag_relearn", unit="rad/s",
        doc="rejected readings count towards re-learning only while ‖ω − b‖ is at least this "
            "(VQF: 20°/s)", typical="0.2-0.5 (10-30°/s)",
        requires=When("mag_relearn_world", False))
    mag_return_s: float = _setting(
        0.0, group="magnetometer", unit="s",
        doc="the heading follows the magnetometer no faster than this time constant: each "
            "heading update corrects at most dt/(dt + this) of the innovation (dt since the "
            "previous update), so the estimate comes back from a disturbance without a jump "
            "(0: off)", typical="3-10", search=(2.0, 20.0, 1.0))
    mag_bias_innovation_limit: float = _setting(
        math.inf, group="magnetometer", unit="σ",
        doc="a heading update teaches the gyroscope bias from at most this many standard "
            "deviations of its innovation (its bias gain is scaled by limit·√S/|ψ| beyond): a "
            "heading far off says the field or the heading is wrong (a disturbance that passed "
            "the gates, a start beside a magnet), not the bias; inf: off",
        typical="1.345 (Huber's) to 3", inf=True)
    update_period_s: float = _setting(
        0.0, group="timing", unit="s",
        doc="run the low-passed accelerometer, magnetometer and zero-rate updates at most this "
            "often (they change slowly; 0: every sample, the course's filter)",
        typical="0.02-0.1")
    mag_nis_gate: float = _setting(
        math.inf, group="magnetometer", unit="-",
        doc="also reject a magnetometer reading whose normalised innovation squared exceeds "
            "this (χ², 1 dof heading-only, 3 dof full); inf: off",
        typical="inf; 7-11 heading-only, 11-16 full (χ², 1 % to 0.1 %)", above=True, inf=True)
    acc_nis_gate: float = _setting(
        math.inf, group="accelerometer", unit="-",
        doc="also reject an accelerometer reading whose normalised innovation squared exceeds "
            "this (χ², 3 dof); inf: off", typical="inf; 11-16 (χ², 3 dof, 1 % to 0.1 %)",
        above=True, inf=True)
    exact_discretisation: bool = _setting(
        False, group="gyroscope", unit="-",
        doc="true: F = exp(T/2 S(ω)) (exact for constant ω); false: F = I + T/2 S(ω) (task 3)",
        typical="true (exact for a constant rate; false: the course's first-order step)")
    mag_heading_only: bool = _setting(
        False, group="magnetometer", unit="-",
        doc="true: the magnetometer may only turn the estimate about world up (footnote 2), so "
            "a disturbed field cannot tilt it", typical="true")
    estimate_gyro_bias: bool = _setting(
        False, group="bias", unit="-",
        doc="true: model 4c, x = (q, b_ω) with the bias a random walk, plus a zero-rate update "
            "at rest", typical="true for a phone (its bias drifts with temperature)")
    gyro_bias_random_walk: float = _setting(
        1e-4, group="bias", unit="rad/s/√s", doc="bias random walk (model 4c)",
        typical="1e-6-1e-4", search=(1e-7, 1e-3))
    initial_gyro_bias_std: float = _setting(
        0.01, group="bias", unit="rad/s", doc="initial bias standard deviation (model 4c)",
        typical="0.005-0.02 (a phone's bias is within it)")
    rest_rate_noise_std: float = _setting(
        0.01, group="bias", unit="rad/s",
        doc="standard deviation of the zero-rate pseudo-measurement at rest (model 4c)",
        typical="0.001-0.01", above=True, search=(1e-4, 0.1))
    max_dt: float = _setting(
        0.5, group="timing", unit="s",
        doc="a longer time step is a pause or a reconnect: it is not integrated",
        typical="0.2-1 (several sample periods)", above=True, inf=True)
    gyr_hold_s: float = _setting(
        0.1, group="timing", unit="s",
        doc="a gyroscope sample keeps driving the time update at most this long",
        typical="0.05-0.2 (a few gyroscope periods)", inf=True)
    rest_gyr_threshold: float = _setting(
        0.05, group="rest", unit="rad/s", doc="‖ω − b‖ below this counts as still",
        typical="0.02-0.1 (a few times the gyroscope's noise)")
    rest_acc_threshold: float = _setting(
        0.3, group="rest", unit="m/s²", doc="‖a − lowpass(a)‖ below this counts as still",
        typical="0.1-0.5")
    rest_min_duration: float = _setting(
        0.5, group="rest", unit="s", doc="still this long: at rest (standstill)",
        typical="0.3-2", inf=True)
    smooth_hard_iron: bool = _setting(
        True, group="hard_iron", unit="-",
        doc="the offline smoother's forward pass keeps the online hard-iron fit; false: it runs "
            "without it (the backward pass smooths q and b only, so the fit's changes would be "
            "spread over the whole recording)",
        typical="false (as in the default preset)")

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


# ---- the settings as rows (docs/filter.md tables, settings panel) ----------------------------
class SettingRow(NamedTuple):
    """One setting: its name, the default and course presets' values, unit, explanation, what
    it allows, the range a tuning search tries ("" where none is declared), its group's name,
    a typical value, and the condition beyond its group's switch it needs ("" for none)."""

    name: str
    default: Any
    course: Any
    unit: str
    doc: str
    allowed: str
    search: str = ""
    group: str = ""
    typical: str = ""
    requires: str = ""


def search_text(r: SearchRange | None) -> str:
    """A search range in words: ``0.1..3`` (searched on a log scale), "" for none."""
    return "" if r is None else f"{r.low:g}..{r.high:g}"


def settings_rows() -> list[SettingRow]:
    """Every field of :class:`EKFSettings` in declaration order (values as stored);
    :func:`grouped_rows` gives them group by group."""
    return [SettingRow(f.name, getattr(PRESETS["default"], f.name),
                       getattr(PRESETS["course"], f.name), f.metadata["unit"], f.metadata["doc"],
                       allowed_text(f), search_text(f.metadata["search"]), f.metadata["group"],
                       f.metadata["typical"],
                       "" if f.metadata["requires"] is None else f.metadata["requires"].text())
            for f in fields(EKFSettings)]


def grouped_rows() -> list[tuple[Group, list[SettingRow]]]:
    """The groups of :data:`GROUPS` in order, each with its settings' rows."""
    rows = settings_rows()
    return [(group, [r for r in rows if r.group == group.name]) for group in GROUPS]


def switch_text(group: Group) -> str:
    """How a group is switched off, in words: which setting, and whether it is a setting of its
    own or a value of one of the group's settings ("always on" without a switch)."""
    switch = group.switch
    if switch is None:
        return "none, always on"
    off = f"'{switch.off}'" if isinstance(switch.off, str) else format_value(switch.off)
    if isinstance(switch.off, (bool, str)):
        return f"`{switch.name}`, a switch of its own; {off} turns the group off"
    return (f"`{switch.name}` = {off} turns the group off, a value of that setting rather than "
            "a switch of its own")


def inactive_reason(settings: EKFSettings, name: str) -> str:
    """Why setting ``name`` has no effect in ``settings`` (its group's switch is off, or the
    setting it requires is), "" when it acts."""
    f = _FIELDS[name]
    switch = GROUP_BY_NAME[f.metadata["group"]].switch
    if switch is not None and switch.name != name and not switch.holds(settings):
        return f"needs {switch.text()}"
    requires = f.metadata["requires"]
    if requires is not None and not requires.holds(settings):
        return f"needs {requires.text()}"
    return ""


_FIELDS = {f.name: f for f in fields(EKFSettings)}


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
