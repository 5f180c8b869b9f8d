"""One interface for every estimator, one snapshot format for both EKFs.

As VQF's tests/test_implementation_comparison.py: each test runs over the implementations
(the readable reference and the compiled filter; for the interface, every estimator) instead
of one test per pair.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

import ekf
from ekf import Estimator, make_estimator
from ekf.estimator import BatchResult
from ekf.fast import FastEKF, warm_up
from ekf.diagnostics import (ACC_NIS_GATE, ACC_NORM_GATE, MAG_DIP_GATE, MAG_NIS_GATE, MAG_SETTLING,
                         MAG_STRENGTH_GATE, NOT_REJECTED, Diagnostics, Flags)
from ekf.reference import OrientationEKF
from ekf.settings import PRESETS
from ekf.simulate import simulate

IMPLEMENTATIONS = {"reference": OrientationEKF, "fast": FastEKF}
EVERY_ESTIMATOR = [(name, fast) for name in ekf.ESTIMATORS
                   for fast in ((True, False) if name in ("ekf", "course") else (True,))]
TOL = 1e-9
G0 = np.array([0.0, 0.0, 9.81])
M0 = np.array([0.0, 16.0, -45.0])


@pytest.fixture(scope="module", autouse=True)
def _compiled():
    warm_up()


@pytest.fixture(scope="module")
def rows():
    """30 s of a simulated phone (rests, turns, then acceleration bursts from 23 s and a magnetic
    disturbance from 26.6 s)."""
    s = simulate(duration_s=30.0, seed=7, gyro_bias=(0.01, -0.02, 0.015))
    return s.to_batch_arrays()


def _step_all(est, t, gyr, acc, mag, start=0, stop=None):
    quats = []
    for k in range(start, t.size if stop is None else stop):
        args = (None if np.isnan(x[k]).any() else x[k] for x in (gyr, acc, mag))
        assert est.step(t[k], *args) is None
        quats.append(est.quat)
    return np.array(quats)


def _label(item):
    name, fast = item
    return f"{name}-{'fast' if fast else 'reference'}"


# ---- the protocol -----------------------------------------------------------------------------
@pytest.mark.parametrize("item", EVERY_ESTIMATOR, ids=_label)
def test_every_estimator_meets_the_protocol(item, rows):
    name, fast = item
    est = make_estimator(name, fast=fast)
    assert isinstance(est, Estimator)
    assert est.time is None and not est.initialised
    t, gyr, acc, mag = rows
    _step_all(est, t, gyr, acc, mag, stop=50)
    assert est.initialised and est.time == t[49]
    assert est.quat.shape == (4,) and est.gyro_bias.shape == (3,)
    assert est.cov is None or est.cov.shape in ((4, 4), (7, 7))
    assert type(est.flags) is Flags and type(est.diagnostics) is Diagnostics
    assert est.enabled == {"gyr": True, "acc": True, "mag": True}
    est.set_enabled(mag=False)
    assert est.enabled == {"gyr": True, "acc": True, "mag": False}
    est.set_settings(PRESETS["course"])
    assert est.settings is PRESETS["course"]
    est.align_heading(ekf.quaternion.from_euler(1.0, 0.0, 0.0))
    est.reset()
    assert not est.initialised and est.time is None and est.enabled["mag"] is False
    assert isinstance(est.run_batch(t[:10], gyr[:10], acc[:10], mag[:10]), BatchResult)


@pytest.mark.parametrize("item", EVERY_ESTIMATOR, ids=_label)
def test_run_batch_is_the_step_loop(item, rows):
    name, fast = item
    t, gyr, acc, mag = rows
    n = t.size if fast or name not in ("ekf", "course") else 600   # the reference is slow
    t, gyr, acc, mag = t[:n], gyr[:n], acc[:n], mag[:n]
    stepped = make_estimator(name, fast=fast)
    quats, flags, bias = [], [], []
    for k in range(n):
        stepped.step(t[k], *(None if np.isnan(x[k]).any() else x[k] for x in (gyr, acc, mag)))
        quats.append(stepped.quat)
        f = stepped.flags
        flags.append((f.acc_rejected, f.mag_rejected, f.at_rest))
        bias.append(stepped.gyro_bias)
    batched = make_estimator(name, fast=fast)
    half = n // 2   # run_batch continues from the current state
    first = batched.run_batch(t[:half], gyr[:half], acc[:half], mag[:half])
    second = batched.run_batch(t[half:], gyr[half:], acc[half:], mag[half:])
    np.testing.assert_array_equal(np.vstack([first.quat, second.quat]), np.array(quats))
    flags = np.array(flags)
    for col, key in enumerate(("acc_rejected", "mag_rejected", "at_rest")):
        np.testing.assert_array_equal(np.concatenate([getattr(first, key), getattr(second, key)]),
                                      flags[:, col])
    np.testing.assert_array_equal(np.vstack([first.gyro_bias, second.gyro_bias]), np.array(bias))
    np.testing.assert_array_equal(batched.quat, stepped.quat)
    if n == rows[0].size:
        assert flags[:, 0].any(), "the session's acceleration bursts should light acc_rejected"


def test_filter_batch_is_run_batch_and_batch_result_has_one_home():
    assert ekf.estimators.BatchResult is BatchResult is ekf.BatchResult
    t = np.arange(0.0, 1.0, 0.01)
    gyr = np.tile([0.0, 0.0, 0.1], (t.size, 1))
    acc = np.tile(G0, (t.size, 1))
    r = ekf.filter_batch(t, gyr, acc, None)   # None: no magnetometer at all
    direct = FastEKF().run_batch(t, gyr, acc, np.full((t.size, 3), np.nan))
    np.testing.assert_array_equal(r.quat, direct.quat)
    with pytest.raises(ValueError, match="shape"):
        ekf.filter_batch(t, gyr[:-1], acc, None)


# ---- snapshots ----------------------------------------------------------------------------------
@pytest.mark.parametrize("item", EVERY_ESTIMATOR, ids=_label)
def test_snapshot_restores_exactly(item, rows):
    name, fast = item
    t, gyr, acc, mag = rows
    n = 500
    est = make_estimator(name, fast=fast)
    _step_all(est, t, gyr, acc, mag, stop=n // 2)
    snap = est.snapshot()
    assert set(snap) == {"estimator", "settings", "state"} and snap["estimator"] == est.name
    first = _step_all(est, t, gyr, acc, mag, n // 2, n)
    end = (est.quat, est.flags, repr(est.diagnostics))
    est.set_settings(PRESETS["course"].with_changes(acc_gate=0.1))
    est.set_enabled(mag=False)
    est.restore(snap)
    assert est.settings is snap["settings"] and est.enabled["mag"]
    again = _step_all(est, t, gyr, acc, mag, n // 2, n)
    np.testing.assert_array_equal(again, first)
    assert (est.quat.tolist(), est.flags, repr(est.diagnostics)) == (end[0].tolist(), end[1],
                                                                      end[2])
    # the snapshot is a copy: continuing did not change it, and changing it does not reach in
    snap2 = est.snapshot()
    for value in snap2["state"].values():
        if isinstance(value, np.ndarray):
            value[...] = 123.0
    assert not np.any(est.quat == 123.0)
    est.restore(snap)
    np.testing.assert_array_equal(_step_all(est, t, gyr, acc, mag, n // 2, n), first)


@pytest.mark.parametrize("source,target", [("reference", "fast"), ("fast", "reference")])
@pytest.mark.parametrize("preset", ["default", "course"])
def test_a_snapshot_of_one_implementation_restores_into_the_other(source, target, preset, rows):
    t, gyr, acc, mag = rows
    settings = PRESETS[preset].with_changes(mag_relearn_s=1.0)
    a = IMPLEMENTATIONS[source](settings)
    _step_all(a, t, gyr, acc, mag, stop=400)
    snap = a.snapshot()
    b = IMPLEMENTATIONS[target]("course" if preset == "default" else "default")
    b.restore(copy.deepcopy(snap))
    assert b.settings == settings and b.enabled == a.enabled and b.time == a.time
    np.testing.assert_array_equal(b.quat, a.quat)
    np.testing.assert_array_equal(b.cov, a.cov)
    # both continue with the same estimates
    qa = _step_all(a, t, gyr, acc, mag, 400, 1000)
    qb = _step_all(b, t, gyr, acc, mag, 400, 1000)
    np.testing.assert_allclose(qb, qa, rtol=0, atol=TOL)
    assert a.flags == b.flags
    sa, sb = a.snapshot()["state"], b.snapshot()["state"]
    assert sa.keys() == sb.keys()
    for key in sa:
        if isinstance(sa[key], np.ndarray):
            np.testing.assert_allclose(sb[key], sa[key], rtol=0, atol=1e-7, err_msg=key)
        elif not isinstance(sa[key], (Flags, Diagnostics)):
            assert type(sb[key]) is type(sa[key]), key
            assert (sb[key] == sa[key] or (math.isnan(sa[key]) and math.isnan(sb[key]))
                    or abs(sb[key] - sa[key]) < 1e-7), key


@pytest.mark.parametrize("impl", sorted(IMPLEMENTATIONS))
def test_restore_says_what_is_wrong(impl):
    est = IMPLEMENTATIONS[impl]()
    est.step(0.0, gyr=[0.0, 0.0, 0.0], acc=G0, mag=M0)
    good = est.snapshot()

    def broken(change):
        snap = copy.deepcopy(good)
        change(snap)
        return snap

    cases = [
        (lambda s: s["state"].pop("mag_strength"), r"missing mag_strength"),
        (lambda s: s["state"].update(velocity=np.zeros(3)), r"unknown velocity"),
        (lambda s: s["state"].update(P=np.eye(4)), r"'P' must have shape \(7, 7\), got \(4, 4\)"),
        (lambda s: s["state"].update(t=np.zeros(2)), r"'t' must have shape \(\), got \(2,\)"),
        (lambda s: s["state"].update(flags={"at_rest": True}), r"'flags' must be Flags"),
        (lambda s: s.update(settings={"g": 9.81}), r"settings must be EKFSettings"),
        (lambda s: s.update(estimator="gyro"), r"estimator 'gyro' cannot restore"),
        (lambda s: s.pop("settings"), r"keys"),
    ]
    for change, message in cases:
        with pytest.raises(ValueError, match=message):
            est.restore(broken(change))
    np.testing.assert_array_equal(est.quat, good["state"]["x"][:4])   # untouched by failures
    with pytest.raises(ValueError, match="dict"):
        est.restore((np.zeros(3), PRESETS["default"]))   # the old tuple snapshot


def test_comparison_estimators_restore_only_their_own_state():
    snap = make_estimator("gyro").snapshot()
    with pytest.raises(ValueError, match="cannot restore"):
        make_estimator("ekf").restore(snap)
    with pytest.raises(ValueError, match="cannot restore"):
        make_estimator("accmag").restore(snap)


# ---- which gate fired -----------------------------------------------------------------------------
def _level(est, seconds=1.0, t0=0.0, hz=100):
    for k in range(int(seconds * hz)):
        est.step(t0 + k / hz, gyr=[0.0, 0.0, 0.0], acc=G0, mag=M0)
    return t0 + seconds


@pytest.mark.parametrize("impl", sorted(IMPLEMENTATIONS))
def test_acc_gate_codes(impl):
    cls = IMPLEMENTATIONS[impl]
    est = cls("course")
    t = _level(est)
    assert est.diagnostics.acc_rejected_by == NOT_REJECTED and not est.flags.acc_rejected
    est.step(t, acc=G0 + [5.0, 0.0, 0.0])
    assert est.flags.acc_rejected and est.diagnostics.acc_rejected_by == ACC_NORM_GATE
    est.step(t + 0.01, acc=G0)
    assert not est.flags.acc_rejected and est.diagnostics.acc_rejected_by == NOT_REJECTED
    est = cls(PRESETS["course"].with_changes(acc_nis_gate=1.0))
    t = _level(est)
    tilted = ekf.quaternion.to_matrix(ekf.quaternion.from_euler(0.0, 0.3, 0.0)).T @ G0
    est.step(t, acc=tilted)   # the right norm, the wrong direction
    assert est.flags.acc_rejected and est.diagnostics.acc_rejected_by == ACC_NIS_GATE


@pytest.mark.parametrize("impl", sorted(IMPLEMENTATIONS))
def test_mag_gate_codes(impl):
    cls = IMPLEMENTATIONS[impl]
    settings = PRESETS["default"].with_changes(update_period_s=0.0, mag_settle_s=0.5,
                                               mag_dip_gate_deg=5.0)
    est = cls(settings)
    t = _level(est)
    assert est.diagnostics.mag_rejected_by == NOT_REJECTED and est.flags.used_mag
    est.step(t, gyr=[0.0, 0.0, 0.0], acc=G0, mag=1.3 * M0)
    assert est.flags.mag_rejected and est.diagnostics.mag_rejected_by == MAG_STRENGTH_GATE
    est.step(t + 0.01, gyr=[0.0, 0.0, 0.0], acc=G0, mag=M0)
    assert est.flags.mag_rejected and est.diagnostics.mag_rejected_by == MAG_SETTLING
    t = _level(est, t0=t + 0.02)
    assert not est.flags.mag_rejected and est.diagnostics.mag_rejected_by == NOT_REJECTED
    steep = np.array([0.0, 8.0, -np.sqrt(16.0 ** 2 + 45.0 ** 2 - 64.0)])   # same strength
    est.step(t, gyr=[0.0, 0.0, 0.0], acc=G0, mag=steep)
    assert est.flags.mag_rejected and est.diagnostics.mag_rejected_by == MAG_DIP_GATE
    ref_dip = math.degrees(math.acos(M0[2] / np.linalg.norm(M0)))
    assert est.diagnostics.mag_reference_dip_deg == pytest.approx(ref_dip, abs=1e-9)
    est = cls(settings.with_changes(mag_settle_s=0.0, mag_nis_gate=1e-6))
    t = _level(est, seconds=0.05)
    turned = ekf.quaternion.to_matrix(ekf.quaternion.from_euler(0.2, 0.0, 0.0)).T @ M0
    est.step(t, gyr=[0.0, 0.0, 0.0], acc=G0, mag=turned)
    assert est.flags.mag_rejected and est.diagnostics.mag_rejected_by == MAG_NIS_GATE


def test_a_gate_code_goes_with_its_flag(rows):
    """A code is non-zero exactly when its flag is set, row by row."""
    t, gyr, acc, mag = rows
    est = FastEKF(PRESETS["default"].with_changes(mag_relearn_s=1.0))
    for k in range(t.size):
        est.step(t[k], *(None if np.isnan(x[k]).any() else x[k] for x in (gyr, acc, mag)))
        f, d = est.flags, est.diagnostics
        assert (d.acc_rejected_by != 0) == f.acc_rejected
        assert (d.mag_rejected_by != 0) == f.mag_rejected


# ---- a filter written in Python -------------------------------------------------------------------
def test_a_python_filter_gets_the_plumbing_from_the_base_class(rows):
    """A user's estimator declares its state and writes step(); the base class gives it the
    switches, flags, diagnostics, snapshots and run_batch."""
    from dataclasses import dataclass

    from ekf.estimator import EstimatorBase
    from ekf.state import state_field

    def value(v):
        return lambda settings, enabled: v

    def switch(sensor):
        return lambda settings, enabled: enabled[sensor]

    @dataclass
    class TiltState:
        t: float = state_field("time of the latest sample", value(math.nan), unit="s")
        gyr_enabled: bool = state_field("gyroscope in", switch("gyr"), kind=bool)
        acc_enabled: bool = state_field("accelerometer in", switch("acc"), kind=bool)
        mag_enabled: bool = state_field("magnetometer in", switch("mag"), kind=bool)
        initialised: bool = state_field("started", value(False), kind=bool)
        q: np.ndarray = state_field("orientation", lambda s, e: np.array([1.0, 0, 0, 0]),
                                    shape=(4,))
        flags: Flags = state_field("lights", lambda s, e: Flags(), kind=Flags)
        diagnostics: Diagnostics = state_field("numbers", lambda s, e: Diagnostics(),
                                               kind=Diagnostics)

    class TiltOnly(EstimatorBase):
        name = "tilt"
        state_class = TiltState

        @property
        def quat(self):
            return self._state.q.copy()

        @property
        def gyro_bias(self):
            return np.zeros(3)

        def align_heading(self, q_ref):
            pass

        def step(self, t, gyr=None, acc=None, mag=None):
            self._state.t = float(t)
            if acc is not None and self._state.acc_enabled:
                self._state.q[:] = ekf.reference.tilt_quaternion(acc)
                self._state.initialised = True

    est = TiltOnly()
    assert isinstance(est, Estimator)
    t, gyr, acc, mag = rows
    result = est.run_batch(t[:200], gyr[:200], acc[:200], mag[:200])
    np.testing.assert_array_equal(result.quat[-1], est.quat)
    snap = est.snapshot()
    est.run_batch(t[200:300], gyr[200:300], acc[200:300], mag[200:300])
    est.restore(snap)
    np.testing.assert_array_equal(est.quat, result.quat[-1])
    assert est.time == t[199] and est.initialised
