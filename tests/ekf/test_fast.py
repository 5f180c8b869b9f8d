"""ekf.fast.FastEKF gives the reference EKF's estimates (to 1e-9) and flags, sample by sample.

The reference is slow (pure numpy), so every scenario is a few hundred rows chosen to pass
through every branch: asynchronous sensors, rows with no sample, acc bursts beyond the gate,
a field-strength change longer than mag_relearn_s, a gap > max_dt, rest (zero-rate updates),
sensor switches through all seven non-empty combinations, and both presets plus a gated variant.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import fields

import numpy as np
import pytest

from ekf import quaternion as quat
from ekf.estimators import BatchResult, filter_batch
from ekf.estimators import make_estimator
from ekf.fast import FastEKF, warm_up
from ekf.diagnostics import Diagnostics, Flags
from ekf.reference import OrientationEKF
from ekf.settings import PRESETS

TOL = 1e-9
FLAGS = tuple(f.name for f in fields(Flags))
CODES = ("acc_rejected_by", "mag_rejected_by")
NUMBERS = tuple(f.name for f in fields(Diagnostics) if f.name not in CODES)

# The presets may be retuned; the variants below pin the branches each test needs (model 4a/4c,
# full or heading-only magnetometer update, gates on or off). mag_relearn_s is shortened so a
# disturbance longer than it fits in a few seconds of data.
SETTINGS = {
    "default": PRESETS["default"].with_changes(mag_relearn_s=1.0),
    "course": PRESETS["course"],
    "bias_heading": PRESETS["default"].with_changes(
        estimate_gyro_bias=True, mag_heading_only=True, exact_discretisation=True, acc_gate=1.0,
        mag_strength_update="accepted", mag_relearn_s=1.0, mag_dip_gate_deg=math.inf,
        acc_nis_gate=math.inf),
    "gated": PRESETS["default"].with_changes(
        estimate_gyro_bias=True, mag_heading_only=False, exact_discretisation=False,
        mag_strength_update="accepted", mag_relearn_s=1.0, acc_nis_gate=7.8,
        mag_dip_gate_deg=4.0),
    # the low-pass with the course's discretisation and sample convention, every sample updated,
    # the NIS gate on the averaged accelerometer and the accelerometer-based dip
    "lowpass_course_timing": PRESETS["default"].with_changes(
        exact_discretisation=False, gyr_rate_before_sample=False, update_period_s=0.0,
        acc_nis_gate=7.8, mag_dip_from_estimate=False, mag_relearn_s=1.0, mag_settle_s=0.2),
    # the magnetometer as the previous default handled it: strength/dip re-learning, no
    # reference window, no no-gyroscope bound, no hard-iron fit, no heading cap, no adaptive noise
    "previous_magnetometer": PRESETS["default"].with_changes(
        mag_relearn_world=False, mag_reference_s=0.0,
        mag_max_reject_no_gyro_s=math.inf, mag_hard_iron_tau_s=0.0, mag_return_s=0.0,
        mag_noise_adapt=0.0, acc_noise_adapt=0.0, acc_range=math.inf, mag_relearn_s=1.0),
    # every new branch within seconds: a fixed accelerometer range that the bursts reach, a
    # short no-gyroscope bound, a quick hard-iron fit, re-learning without the turn-rate condition
    "quick_field": PRESETS["default"].with_changes(
        acc_range=12.0, mag_max_reject_no_gyro_s=0.2,
        mag_hard_iron_tau_s=2.0, mag_hard_iron_prior=0.1, mag_relearn_min_rate=0.0,
        mag_relearn_s=1.0, mag_return_s=0.3, mag_reference_s=0.5, mag_noise_adapt=300.0),
    # the full magnetometer update (not heading only) with a quick hard-iron fit and the
    # expected field confirmed after 0.5 s
    "full_update_quick_fit": PRESETS["default"].with_changes(
        acc_range=12.0, mag_heading_only=False, mag_first_relearn_s=0.5, mag_hard_iron_tau_s=2.0,
        mag_hard_iron_prior=0.1, mag_relearn_min_rate=0.0, mag_relearn_s=1.0, mag_return_s=0.3,
        mag_reference_s=0.5),
    # the unevenness low-pass strong, every deviation counted at most one gate off
    "uneven_field_clipped": PRESETS["default"].with_changes(
        mag_noise_adapt=3000.0, mag_noise_adapt_clip=1.0, mag_relearn_s=1.0),
    # a calibrated, anisotropic R_w (the compiled path has a closed form for R_w = r I only)
    "anisotropic_rw": PRESETS["default"].with_changes(
        gyr_noise_cov=[[1e-4, 2e-5, 0.0], [2e-5, 3e-4, -1e-5], [0.0, -1e-5, 2e-4]],
        gyr_scale_noise=0.02, mag_relearn_s=1.0),
}


@pytest.fixture(scope="module", autouse=True)
def _compiled():
    warm_up()


def synthetic(seed: int = 1, duration_s: float = 7.0):
    """Rows (t, gyr, acc, mag) with NaN where a sensor has no sample.

    gyr 50 Hz, acc 25 Hz (+3 ms), mag 20 Hz (+7 ms); still for the first 1.2 s (rest), then
    turning about a slowly changing axis; gyro bias 0.02 rad/s; acc bursts of 9 m/s^2 (beyond
    a 3 m/s^2 gate); the
    field 30 % stronger from 3.0 s to 5.5 s; no samples at all from 5.8 s to 6.5 s (> max_dt);
    one row with no sensor at all.
    """
    rng = np.random.default_rng(seed)
    times = {"gyr": np.arange(0.0, duration_s, 0.02),
             "acc": np.arange(0.003, duration_s, 0.04),
             "mag": np.arange(0.007, duration_s, 0.05)}
    all_t = np.unique(np.concatenate(list(times.values()) + [np.array([2.2345])]))
    all_t = all_t[all_t < duration_s]
    all_t = all_t[(all_t < 5.8) | (all_t > 6.5)]
    # truth: q(t) integrated on a fine grid
    fine = np.arange(0.0, duration_s + 0.01, 0.001)
    omega = np.zeros((fine.size, 3))
    moving = fine > 1.2
    omega[moving] = np.column_stack([0.6 * np.sin(0.7 * fine), 0.4 * np.cos(1.1 * fine),
                                     0.8 * np.ones_like(fine)])[moving]
    q = np.empty((fine.size, 4))
    q[0] = quat.from_euler(0.3, 0.1, -0.2)
    for k in range(1, fine.size):
        step = quat.from_rotation_vector(omega[k - 1] * 0.001)
        q[k] = quat.normalize(quat.multiply(q[k - 1], step))
    bias = np.array([0.02, -0.01, 0.015])
    g0 = np.array([0.0, 0.0, 9.81])
    m0 = np.array([0.0, 15.5, -48.0])
    n = all_t.size
    gyr = np.full((n, 3), np.nan)
    acc = np.full((n, 3), np.nan)
    mag = np.full((n, 3), np.nan)
    for k, t in enumerate(all_t):
        i = int(round(t * 1000))
        R = quat.to_matrix(q[i])
        if np.any(np.isclose(times["gyr"], t)):
            gyr[k] = omega[i] + bias + rng.normal(0, 1e-3, 3)
        if np.any(np.isclose(times["acc"], t)):
            force = np.array([9.0, 0.0, 0.0]) if (1.5 < t < 1.8 or 4.0 < t < 4.3) else 0.0
            acc[k] = R.T @ (g0 + force) + rng.normal(0, 0.02, 3)
        if np.any(np.isclose(times["mag"], t)):
            field = m0 * (1.3 if 3.0 < t < 5.5 else 1.0)
            mag[k] = R.T @ field + rng.normal(0, 0.5, 3)
    return all_t, gyr, acc, mag


def _sample(row: np.ndarray) -> np.ndarray | None:
    return None if np.isnan(row).any() else row


def _compare(ref, fast, where: str) -> None:
    np.testing.assert_allclose(fast.quat, ref.quat, rtol=0, atol=TOL, err_msg=where)
    np.testing.assert_allclose(fast.gyro_bias, ref.gyro_bias, rtol=0, atol=TOL, err_msg=where)
    assert fast.initialised == ref.initialised, where
    fast_flags, ref_flags = fast.flags, ref.flags
    for name in FLAGS:
        assert getattr(fast_flags, name) == getattr(ref_flags, name), f"{where}: {name}"
    fast_diag, ref_diag = fast.diagnostics, ref.diagnostics
    for name in CODES:
        assert getattr(fast_diag, name) == getattr(ref_diag, name), f"{where}: {name}"
    # which gate fired goes with the flag it explains
    assert (fast_diag.acc_rejected_by != 0) == fast_flags.acc_rejected, where
    assert (fast_diag.mag_rejected_by != 0) == fast_flags.mag_rejected, where
    for name in NUMBERS:
        a, b = getattr(fast_diag, name), getattr(ref_diag, name)
        assert (math.isnan(a) and math.isnan(b)) or abs(a - b) <= 1e-6 * max(1.0, abs(b)), \
            f"{where}: {name} {a} != {b}"


def _run_both(settings, t, gyr, acc, mag, switches=None):
    """Feed both filters row by row; `switches` maps a row index to set_enabled kwargs.
    Returns the fast filter's quaternions per row."""
    ref = OrientationEKF(settings)
    fast = FastEKF(settings)
    out = np.empty((t.size, 4))
    for k in range(t.size):
        if switches and k in switches:
            ref.set_enabled(**switches[k])
            fast.set_enabled(**switches[k])
            assert fast.enabled == ref.enabled
        args = (_sample(gyr[k]), _sample(acc[k]), _sample(mag[k]))
        assert fast.step(t[k], *args) is None
        ref.step(t[k], *args)
        _compare(ref, fast, f"row {k} t={t[k]:.3f}")
        out[k] = fast.quat
    np.testing.assert_allclose(fast.cov, ref.cov, rtol=0, atol=1e-12)
    assert fast.time == ref.time
    return ref, fast, out


@pytest.mark.parametrize("variant", sorted(SETTINGS))
def test_synthetic_matches_reference(variant):
    t, gyr, acc, mag = synthetic()
    ref, fast, out = _run_both(SETTINGS[variant], t, gyr, acc, mag)
    # the scenario really exercised the branches it is meant to
    batch = FastEKF(SETTINGS[variant]).run_batch(t, gyr, acc, mag)
    assert batch.acc_rejected.any() and batch.at_rest.any()
    if variant != "course":
        assert batch.mag_rejected.any()
        # the 30 % stronger field was re-learned after mag_relearn_s (|m0| = 50.4 uT before)
        during = FastEKF(SETTINGS[variant])
        inside = t < 5.4
        during.run_batch(t[inside], gyr[inside], acc[inside], mag[inside])
        assert during.diagnostics.mag_expected > 60.0
    # run_batch is the same filter as the step loop
    np.testing.assert_array_equal(batch.quat, out)
    np.testing.assert_array_equal(batch.quat[-1], fast.quat)
    assert batch.gyro_bias.shape == (t.size, 3)
    np.testing.assert_array_equal(batch.gyro_bias[-1], fast.gyro_bias)


def disturbed_start(duration_s: float = 9.0):
    """Rows of a phone turning about up at 0.5 rad/s whose field is wrong where it starts: 25 uT
    more fading out over 0.4 s (the learning window starts again), then 1.4x for 1.6 s (learned
    as the expected field), then the real field with a 0.15 s disturbance every 0.7 s (the
    young candidate counts down and up again) and turned by 50 deg about up from 6 s (passing
    every gate: heading innovations beyond the bias limit). gyr 100 Hz, acc 50 Hz, mag 50 Hz."""
    t = np.round(np.arange(0.0, duration_s, 0.01), 6)
    gyr = np.full((t.size, 3), np.nan)
    acc = np.full((t.size, 3), np.nan)
    mag = np.full((t.size, 3), np.nan)
    m0 = np.array([0.0, 16.0, -45.0])
    turned = quat.to_matrix(quat.from_axis_angle([0, 0, 1], math.radians(50))) @ m0
    rng = np.random.default_rng(4)
    for k, tk in enumerate(t):
        R = quat.to_matrix(quat.from_axis_angle([0.1, 0.2, 1.0], 0.5 * tk))
        gyr[k] = R.T @ (np.array([0.1, 0.2, 1.0]) / np.linalg.norm([0.1, 0.2, 1.0]) * 0.5) \
            + rng.normal(0, 1e-3, 3)
        if k % 2 == 0:
            acc[k] = R.T @ np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.02, 3)
            if tk < 0.4:
                field = m0 + np.array([0.0, 0.0, -25.0]) * (1.0 - tk / 0.4)
            elif tk < 2.0:
                field = 1.4 * m0
            elif (tk % 0.7) > 0.55:
                field = 1.5 * m0
            else:
                field = turned if tk > 6.0 else m0
            mag[k] = R.T @ field + rng.normal(0, 0.3, 3)
    return t, gyr, acc, mag


def test_a_disturbed_start_matches_reference():
    """The young field, the learning window's restart, the candidate counting down and the bias
    limit, compiled and readable, row by row; and those branches really ran."""
    t, gyr, acc, mag = disturbed_start()
    s = PRESETS["default"].with_changes(mag_first_relearn_s=2.0, mag_bias_innovation_limit=0.5,
                                        update_period_s=0.0,
                                        mag_hard_iron_tau_s=0.0)
    ref, fast, _ = _run_both(s, t, gyr, acc, mag)
    assert fast.diagnostics.mag_expected == pytest.approx(np.linalg.norm([0, 16, -45]), rel=0.05)
    unlimited = FastEKF(s.with_changes(mag_bias_innovation_limit=math.inf))
    unlimited.run_batch(t, gyr, acc, mag)
    assert np.abs(unlimited.gyro_bias - fast.gyro_bias).max() > 1e-3


def test_sensor_switches_through_all_combinations():
    t, gyr, acc, mag = synthetic(seed=2)
    combos = [c for r in (1, 2, 3) for c in itertools.combinations(("gyr", "acc", "mag"), r)]
    assert len(combos) == 7
    # switch every ~35 rows; end with all on
    switches = {}
    for i, combo in enumerate(combos + [("gyr", "acc", "mag")]):
        switches[20 + 35 * i] = {s: (s in combo) for s in ("gyr", "acc", "mag")}
    for variant in ("default", "course", "bias_heading"):
        _run_both(SETTINGS[variant], t, gyr, acc, mag, switches)


def test_starts_with_partial_sensor_sets():
    t, gyr, acc, mag = synthetic(seed=3, duration_s=2.0)
    for sensors in (("gyr",), ("acc",), ("mag",), ("gyr", "mag"), ("acc", "mag")):
        ref = OrientationEKF(SETTINGS["bias_heading"], sensors)
        fast = FastEKF(SETTINGS["bias_heading"], sensors)
        for k in range(t.size):
            args = (_sample(gyr[k]), _sample(acc[k]), _sample(mag[k]))
            ref.step(t[k], *args)
            fast.step(t[k], *args)
            _compare(ref, fast, f"{sensors} row {k}")


def test_settings_change_and_reset_and_align_heading():
    t, gyr, acc, mag = synthetic(seed=4, duration_s=3.0)
    ref = OrientationEKF(SETTINGS["bias_heading"])
    fast = FastEKF(SETTINGS["bias_heading"])
    half = t.size // 2
    for k in range(t.size):
        if k == half:
            for est in (ref, fast):
                est.set_settings(SETTINGS["course"])      # n: 7 -> 4
                est.align_heading(quat.from_euler(1.0, 0.0, 0.0))
        if k == half + 40:
            for est in (ref, fast):
                est.set_settings(SETTINGS["gated"])       # n: 4 -> 7
        if k == half + 80:
            for est in (ref, fast):
                est.reset()
        args = (_sample(gyr[k]), _sample(acc[k]), _sample(mag[k]))
        ref.step(t[k], *args)
        fast.step(t[k], *args)
        _compare(ref, fast, f"row {k}")
    assert fast.cov.shape == ref.cov.shape == (7, 7)


def test_snapshot_restore_continues_exactly():
    t, gyr, acc, mag = synthetic(seed=5, duration_s=4.0)
    fast = FastEKF(SETTINGS["bias_heading"])
    half = t.size // 2
    fast.run_batch(t[:half], gyr[:half], acc[:half], mag[:half])
    snap = fast.snapshot()
    first = fast.run_batch(t[half:], gyr[half:], acc[half:], mag[half:])
    end_cov = fast.cov
    fast.set_settings(SETTINGS["course"])
    fast.set_enabled(mag=False)
    fast.restore(snap)
    assert fast.settings is SETTINGS["bias_heading"] and fast.enabled["mag"]
    again = fast.run_batch(t[half:], gyr[half:], acc[half:], mag[half:])
    np.testing.assert_array_equal(again.quat, first.quat)
    np.testing.assert_array_equal(again.at_rest, first.at_rest)
    np.testing.assert_array_equal(fast.cov, end_cov)
    # the snapshot is a copy: continuing did not change it
    fast.restore(snap)
    assert fast.time == t[half - 1]


def test_interface_names_flags_and_factory():
    assert FastEKF(PRESETS["course"]).name == "course"
    assert FastEKF(PRESETS["default"]).name == "ekf"
    assert FastEKF("course").name == "course"
    assert OrientationEKF("course").name == "course"
    est = make_estimator("course")
    assert isinstance(est, FastEKF) and est.name == "course"
    assert isinstance(make_estimator("ekf"), FastEKF)
    assert type(make_estimator("course", fast=False)) is OrientationEKF
    fast = FastEKF()
    assert fast.time is None and not fast.initialised
    np.testing.assert_array_equal(fast.quat, [1.0, 0.0, 0.0, 0.0])
    assert fast.cov.shape == OrientationEKF().cov.shape
    assert fast.step(0.0, acc=[0.0, 0.0, 9.81], mag=[0.0, 20.0, -40.0]) is None
    assert fast.initialised
    ref = OrientationEKF()
    ref.step(0.0, acc=[0.0, 0.0, 9.81], mag=[0.0, 20.0, -40.0])
    flags, diag = fast.flags, fast.diagnostics
    assert type(flags) is Flags and type(diag) is Diagnostics
    assert flags == ref.flags and repr(diag) == repr(ref.diagnostics)   # repr: NaN fields
    fast.update_acc(0.01, [0.0, 0.0, 30.0])   # far beyond any acc gate
    assert fast.flags.acc_rejected and not flags.acc_rejected   # copies: safe to keep
    flags.at_rest = True                                        # and to change
    assert not fast.flags.at_rest


def test_filter_batch_uses_compiled_loop():
    t, gyr, acc, mag = synthetic(seed=6, duration_s=2.0)
    fast_result = filter_batch(t, gyr, acc, mag, settings=SETTINGS["bias_heading"])
    slow_result = filter_batch(t, gyr, acc, mag, settings=SETTINGS["bias_heading"], fast=False)
    assert isinstance(fast_result, BatchResult) and fast_result.gyro_bias is not None
    np.testing.assert_allclose(fast_result.quat, slow_result.quat, rtol=0, atol=TOL)
    np.testing.assert_array_equal(fast_result.acc_rejected, slow_result.acc_rejected)
    np.testing.assert_array_equal(fast_result.at_rest, slow_result.at_rest)


def load_log(path, limit_rows: int):
    """Rows of a phone log: TAB-separated `t_ms TAG v1 v2 v3 [v4]`; rows = distinct times, sorted,
    samples at equal times fed GYR, ACC, MAG."""
    rows: dict[int, dict[str, list[float]]] = {}
    with open(path) as f:
        for line in f:
            parts = line.split("\t")
            if len(parts) >= 5 and parts[1] in ("GYR", "ACC", "MAG"):
                rows.setdefault(int(parts[0]), {})[parts[1]] = [float(v) for v in parts[2:5]]
    times = sorted(rows)[:limit_rows]
    t = np.array(times) / 1000.0
    arrays = [np.array([rows[k].get(tag, [np.nan] * 3) for k in times])
              for tag in ("GYR", "ACC", "MAG")]
    return t, *arrays


@pytest.mark.shared
def test_real_log_matches_reference(realphone_dir):
    path = realphone_dir / "tsrt14_lab2_rotation.txt"
    if not path.exists():
        pytest.skip(f"{path} not found")
    t, gyr, acc, mag = load_log(path, 700)
    assert np.all(np.diff(t) > 0)
    for settings in (PRESETS["default"], PRESETS["course"], SETTINGS["bias_heading"]):
        ref, fast, out = _run_both(settings, t, gyr, acc, mag)
        batch = FastEKF(settings).run_batch(t, gyr, acc, mag)
        np.testing.assert_array_equal(batch.quat, out)


@pytest.mark.parametrize("preset", ["default", "course"])
def test_a_field_along_gravity_at_the_start_gives_no_nan(preset):
    """Found by the invariant property test: the first readings have acc parallel to mag."""
    ref, fast = OrientationEKF(preset), FastEKF(preset)
    for f in (ref, fast):
        f.update_mag(0.0, [1.0, 0.0, 0.0])
        f.update_acc(0.0, [1.0, 0.0, 0.0])
        assert f.initialised and np.all(np.isfinite(f.quat))
        f.update_mag(0.01, [0.0, 20.0, -40.0])       # a usable field then sets the heading
        f.update_acc(0.01, [0.0, 0.0, 9.81])
        assert np.all(np.isfinite(f.quat)) and np.all(np.isfinite(f.cov))
    np.testing.assert_allclose(fast.quat, ref.quat, atol=TOL)


def test_cache_guard_flushes_compilations_built_against_another_layout(monkeypatch):
    """numba keys its disk cache on each function's own file; ekf.fast.jit.check_cache flushes
    a kernel module's cached compilations when they were built against other layouts or kernel
    sources."""
    from numba import njit

    from ekf.fast import algebra
    from ekf.fast import jit as fast_jit

    key = fast_jit.CACHE_KEY

    @njit
    def current_key():
        return key

    @njit
    def stale_key():
        return key + 1

    @njit
    def kernel():
        return 1.0

    class Recorder:
        def __init__(self):
            self.flushed = 0

        def flush(self):
            self.flushed += 1

    own, other = Recorder(), Recorder()
    monkeypatch.setattr(kernel, "_cache", own)
    monkeypatch.setattr(algebra.quat_normalize, "_cache", other)
    module = {"__name__": __name__, "kernel": kernel, "imported": algebra.quat_normalize}
    fast_jit.check_cache(current_key, module, key)
    assert own.flushed == 0
    fast_jit.check_cache(stale_key, module, key)
    assert own.flushed == 1 and other.flushed == 0   # only the module's own functions


def _defined_in_order(tree, skip):
    """The names of the functions a module or class body defines, in source order."""
    import ast

    return [node.name for node in tree.body
            if isinstance(node, ast.FunctionDef) and not skip(node)]


def _reference_names():
    """ekf.reference's module functions, then OrientationEKF's methods that a sample runs
    through (its properties, __init__ and the control methods FastEKF runs in Python left
    out), in source order."""
    import ast
    import inspect

    import ekf.reference

    tree = ast.parse(inspect.getsource(ekf.reference))
    cls = next(node for node in tree.body
               if isinstance(node, ast.ClassDef) and node.name == "OrientationEKF")

    def plumbing(node):
        decorators = {ast.unparse(d) for d in node.decorator_list}
        return (node.name.startswith("__") or node.name in CONTROL
                or "property" in decorators or any(d.endswith(".setter") for d in decorators))

    return (_defined_in_order(tree, lambda node: False)
            + _defined_in_order(cls, plumbing))


CONTROL = ("set_enabled", "set_settings", "align_heading")
"""OrientationEKF's methods that are not per-sample: FastEKF runs them in Python."""


def test_the_compiled_kernels_are_the_reference_function_for_function():
    """ekf.fast.kernels defines the reference's functions under the same names in the same
    order (an `X_n` is X's n-specialised body and follows X); each is compiled; nothing else
    is defined there but the cache-guard key."""
    import ast
    import inspect

    from numba.core.dispatcher import Dispatcher

    from ekf.fast import kernels

    tree = ast.parse(inspect.getsource(kernels))
    compiled = _defined_in_order(tree, lambda node: node.name == "_compiled_cache_key")
    bodies = [name for name in compiled if name.endswith("_n")]
    for body in bodies:
        assert compiled[compiled.index(body) - 1] == body[:-2], body
    twins = [name for name in compiled if name not in bodies]
    reference = _reference_names()
    assert len(reference) > 50
    assert twins == reference
    for name in compiled:
        assert isinstance(getattr(kernels, name), Dispatcher), name


def test_the_compiled_filter_has_the_reference_control_methods():
    """The methods FastEKF runs in Python are the reference's, in the same order."""
    import ast
    import inspect

    from ekf.fast.filter import FastEKF

    def methods(cls):
        tree = ast.parse(inspect.getsource(cls))
        return [name for name in _defined_in_order(tree.body[0], lambda node: False)
                if name in CONTROL]

    assert methods(FastEKF) == methods(OrientationEKF) == list(CONTROL)


def test_no_module_of_ekf_imports_a_private_name_of_another():
    """Shared pieces are public in the module that owns them (the settings' declarations are
    being folded into one module apart from this check)."""
    import ast
    from pathlib import Path

    import ekf

    root = Path(ekf.__file__).parent
    offenders = []
    for path in sorted(root.rglob("*.py")):
        if path.name.startswith("settings"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                offenders += [f"{path.relative_to(root)}: {node.module}.{alias.name}"
                              for alias in node.names if alias.name.startswith("_")]
    assert offenders == []


def test_a_silent_magnetometer_matches_reference():
    """acc_tilt_only_after_s: the magnetometer switched off for long enough that the
    accelerometer's gain loses the heading and the bias about up, compiled and readable row by
    row; and the branch really ran (the estimate differs from the one without it)."""
    t, gyr, acc, mag = synthetic(seed=5)
    s = PRESETS["default"].with_changes(acc_tilt_only_after_s=0.5, update_period_s=0.0)
    switches = {int(np.searchsorted(t, 2.0)): {"mag": False}}
    _, fast, _ = _run_both(s, t, gyr, acc, mag, switches)
    other = FastEKF(s.with_changes(acc_tilt_only_after_s=math.inf))
    for k in range(t.size):
        if k in switches:
            other.set_enabled(**switches[k])
        other.step(t[k], _sample(gyr[k]), _sample(acc[k]), _sample(mag[k]))
    assert _angle_deg(other.quat, fast.quat) > 1e-3


def _angle_deg(p, q) -> float:
    return math.degrees(float(quat.angle_between(p, q)))


def test_an_uncalibrated_magnetometer_matches_reference():
    """A raw magnetometer (an offset of hundreds of uT from the start): the acquisition of the
    offset (the magnetometer waiting, the unweighted fit, the hand-over), compiled and readable
    row by row; and it really ran (the last readings are used, the offset found)."""
    t, gyr, acc, mag = synthetic(seed=6, duration_s=12.0)
    mag = mag + np.array([60.0, -55.0, 400.0])
    s = PRESETS["default"].with_changes(update_period_s=0.0)
    ref, fast, _ = _run_both(s, t, gyr, acc, mag)
    offset = fast.snapshot()["state"]["mag_offset"]
    assert np.linalg.norm(offset - [60.0, -55.0, 400.0]) < 20.0
    assert not fast.snapshot()["state"]["mag_waiting"]


def test_a_magnet_put_on_and_taken_off_the_phone_matches_reference():
    """The offset that explains what the field alone does not: applied once the magnet's
    readings pass corrected, dropped once they pass as they come; compiled and readable, row
    by row, and both branches really ran."""
    hz = 50.0
    t = np.arange(0.0, 40.0, 1.0 / hz)
    rates = np.column_stack([1.5 * np.sin(0.31 * t), -1.0 + np.cos(0.17 * t),
                             2.0 * np.cos(0.23 * t)])
    q = quat.IDENTITY.copy()
    m0, g0 = np.array([0.0, 16.0, -45.0]), np.array([0.0, 0.0, 9.81])
    offset = np.array([30.0, -10.0, 5.0])
    gyr, acc, mag = np.empty((t.size, 3)), np.empty((t.size, 3)), np.empty((t.size, 3))
    for k in range(t.size):
        R = quat.to_matrix(q)
        gyr[k], acc[k] = rates[k], R.T @ g0
        mag[k] = R.T @ m0 + (offset if 5.0 < t[k] < 30.0 else 0.0)
        q = quat.normalize(quat.multiply(q, quat.from_rotation_vector(rates[k] / hz)))
    s = PRESETS["default"].with_changes(mag_hard_iron_tau_s=20.0)
    applied = []
    ref = OrientationEKF(s)
    fast = FastEKF(s)
    for k in range(t.size):
        args = (_sample(gyr[k]), _sample(acc[k]), _sample(mag[k]))
        fast.step(t[k], *args)
        ref.step(t[k], *args)
        _compare(ref, fast, f"row {k} t={t[k]:.3f}")
        applied.append(bool(np.any(ref._state.mag_offset != 0.0)))
    applied = np.array(applied)
    assert applied[(t > 25.0) & (t < 30.0)].all()
    assert not applied[t > 35.0].any()


def test_the_hard_iron_fit_restarting_matches_reference():
    """A raw magnetometer (200 uT) with a field moving in the world for 10 s (the second fit
    opened and dropped) and then a magnet fixed to the phone (the fit started again from it):
    compiled and readable row by row, the fit's state included; all three really ran."""
    hz = 50.0
    t = np.arange(0.0, 80.0, 1.0 / hz)
    rates = np.column_stack([1.2 * np.sin(0.31 * t), -0.8 + np.cos(0.17 * t),
                             1.5 * np.cos(0.23 * t)])
    m0, g0 = np.array([0.0, 16.0, -45.0]), np.array([0.0, 0.0, 9.81])
    raw, magnet = np.array([120.0, -80.0, 140.0]), np.array([60.0, 40.0, -30.0])
    q = quat.IDENTITY.copy()
    ref, fast = OrientationEKF(PRESETS["default"]), FastEKF(PRESETS["default"])
    opened, dropped, restarted = False, False, False
    for k in range(t.size):
        R = quat.to_matrix(q)
        a = 0.7 * (t[k] - 20.0)
        world = m0 + (150.0 * np.array([math.cos(a), math.sin(a), 0.3]) / math.sqrt(1.09)
                      if 20.0 <= t[k] <= 30.0 else 0.0)
        mag = R.T @ world + raw + (magnet if t[k] > 50.0 else 0.0)
        args = (rates[k], R.T @ g0, mag)
        fit_before = ref._state.mag_offset_fit.copy()
        fast.step(t[k], *args)
        ref.step(t[k], *args)
        _compare(ref, fast, f"row {k} t={t[k]:.3f}")
        state = fast.snapshot()["state"]
        for name in ("mag_offset_fit", "mag_restart_info", "mag_restart_rhs"):
            np.testing.assert_allclose(state[name], getattr(ref._state, name), rtol=1e-9,
                                       atol=1e-9, err_msg=f"row {k}: {name}")
        open_now = not math.isnan(ref._state.mag_restart_t)
        opened |= 20.0 < t[k] < 31.0 and open_now
        dropped |= opened and 31.0 < t[k] < 50.0 and not open_now
        restarted |= t[k] > 50.0 and np.linalg.norm(ref._state.mag_offset_fit - fit_before) > 30
        q = quat.normalize(quat.multiply(q, quat.from_rotation_vector(rates[k] / hz)))
    assert opened and dropped and restarted
    error = np.linalg.norm(fast.snapshot()["state"]["mag_offset_fit"] - raw - magnet)
    assert error < 0.25 * np.linalg.norm(magnet)
