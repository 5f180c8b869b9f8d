"""Behaviour of the extensions beyond the course filter (ekf.settings, DEFAULT preset).

Each test isolates one extension on data with known truth and checks what it is for; the
compiled filter's equality with the reference on the same settings is in test_fast.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import ekf
from ekf import quaternion as Q
from ekf.outputs import ACC_NORM_GATE
from ekf.reference import OrientationEKF
from ekf.settings import PRESETS

G0 = np.array([0.0, 0.0, 9.81])
M0 = np.array([0.0, 16.0, -45.0])


def _turning(rate: np.ndarray, duration_s: float, hz: float = 200.0, q0=None):
    """Truth and samples of a phone turning at a constant body rate (rad/s)."""
    t = np.arange(0.0, duration_s, 1.0 / hz)
    q = np.empty((t.size, 4))
    q[0] = Q.IDENTITY if q0 is None else q0
    step = Q.from_rotation_vector(rate / hz)
    for k in range(1, t.size):
        q[k] = Q.normalize(Q.multiply(q[k - 1], step))
    return t, q


def test_carried_lowpass_follows_a_turning_phone_without_lag():
    """Turning at 2 rad/s, the carried average of the accelerometer is gravity in the current
    body frame: no lag, unlike a plain low-pass of the readings."""
    settings = PRESETS["default"].with_changes(gyr_rate_before_sample=True, update_period_s=0.0)
    f = OrientationEKF(settings)
    rate = np.array([1.2, -0.8, 1.4])
    t, q = _turning(rate, 3.0)
    plain = None
    for k in range(t.size):
        R = Q.to_matrix(q[k])
        acc = R.T @ G0
        f.step(t[k], gyr=rate, acc=acc, mag=R.T @ M0)
        plain = acc.copy() if plain is None else plain + (acc - plain) * (0.005 / (0.5 + 0.005))
    carried = f.snapshot()["state"]["acc_carried"]
    truth = Q.to_matrix(q[-1]).T @ G0
    assert np.linalg.norm(carried - truth) < 1e-6 * 9.81
    assert np.linalg.norm(plain - truth) > 1.0        # a plain low-pass lags far behind
    assert math.degrees(Q.angle_between(f.quat, q[-1])) < 0.05


def test_lowpass_keeps_tilt_through_back_and_forth_translation():
    """Shaking horizontally (+-6 m/s^2 at 1 Hz) while level: the course filter (its norm gate
    cannot see horizontal forces, ||g + a|| stays near g) is pulled about 10 deg off level;
    the low-passed accelerometer, in which the shaking largely cancels, stays far closer."""
    hz = 200.0
    t = np.arange(0.0, 20.0, 1.0 / hz)
    force = np.column_stack([6.0 * np.sin(2 * np.pi * 1.0 * t), 3.0 * np.cos(2 * np.pi * 0.7 * t),
                             np.zeros_like(t)])
    gyr = np.zeros((t.size, 3))
    acc = G0 + force
    mag = np.tile(M0, (t.size, 1))
    settings = {
        "course, wide gate": PRESETS["course"].with_changes(acc_gate=10.0),
        "default": PRESETS["default"],
    }
    rms = {}
    for name, s in settings.items():
        r = ekf.filter_batch(t, gyr, acc, mag, settings=s)
        _, _, incl = ekf.error_angles_deg(r.quat[t > 2], np.tile(Q.IDENTITY, ((t > 2).sum(), 1)))
        rms[name] = float(np.sqrt(np.mean(incl ** 2)))
    assert rms["course, wide gate"] > 8.0
    assert rms["default"] < 0.4 * rms["course, wide gate"]


def test_norm_gate_only_flags_when_lowpass_is_on():
    f = OrientationEKF("default")
    for k in range(100):
        f.step(k * 0.01, gyr=[0, 0, 0], acc=G0, mag=M0)
    f.step(1.0, gyr=[0, 0, 0], acc=G0 + [8.0, 0, 0], mag=M0)
    assert f.flags.acc_rejected                         # the light: disturbed
    assert f.diagnostics.acc_rejected_by == ACC_NORM_GATE
    assert f.flags.used_acc                             # and still averaged
    assert f.diagnostics.acc_norm == pytest.approx(np.linalg.norm(G0 + [8.0, 0, 0]))


def test_gyro_sample_convention():
    """Turning at 1 rad/s about up for 0.5 s (50 samples at 100 Hz, the first at rest): a sample
    that ends its interval brings the state to its own time stamp (0.50 rad); the course's
    convention is one sample behind (0.49 rad)."""
    hz = 100.0
    for before, expected_rad in ((True, 0.50), (False, 0.49)):
        s = PRESETS["course"].with_changes(exact_discretisation=True, gyr_rate_before_sample=before,
                                           acc_gate=0.0, mag_gate=0.0)
        f = OrientationEKF(s)
        f.step(0.0, gyr=[0, 0, 0], acc=G0, mag=M0)   # level, facing north: yaw 0
        assert abs(Q.to_euler(f.quat)[0]) < 1e-12
        for k in range(1, 51):
            f.step(k / hz, gyr=[0, 0, 1.0])
        assert Q.to_euler(f.quat)[0] == pytest.approx(expected_rad, abs=1e-9), before


def test_gyro_scale_noise_grows_the_covariance_in_fast_turns():
    def attitude_var_after(rate):
        s = PRESETS["course"].with_changes(gyr_scale_noise=0.05, acc_gate=0.0, mag_gate=0.0)
        f = OrientationEKF(s)
        f.step(0.0, gyr=[0, 0, 0], acc=G0, mag=M0)
        p0 = np.trace(f.cov)
        for k in range(1, 101):
            f.step(k * 0.01, gyr=[0, 0, rate])
        return np.trace(f.cov) - p0
    slow, fast = attitude_var_after(0.0), attitude_var_after(10.0)
    assert fast > 10 * slow


def _magnet_on_phone(settings, seconds=30.0, hz=100.0):
    """Handled (turning about a tilted axis at 2.7 rad/s) with a magnet stuck to the phone from
    5 s on: the reading is the Earth field (turning in the body frame) plus a body-fixed 30 uT.
    Returns the filter's used_mag flags after 5 s and the final m0."""
    rate = np.array([1.5, -1.0, 2.0])
    t, q = _turning(rate, seconds, hz)
    f = OrientationEKF(settings)
    used = []
    for k in range(t.size):
        R = Q.to_matrix(q[k])
        mag = R.T @ M0 + (np.array([30.0, -10.0, 5.0]) if t[k] > 5 else 0.0)
        f.step(t[k], gyr=rate, acc=R.T @ G0, mag=mag)
        if t[k] > 5:
            used.append(f.flags.used_mag)
    return np.array(used), f.snapshot()["state"]["m0"]


def test_settling_keeps_a_magnet_on_the_phone_out_and_is_never_learned():
    s = PRESETS["default"].with_changes(mag_relearn_s=5.0, update_period_s=0.0)
    used, m0 = _magnet_on_phone(s)
    # now and then the disturbed reading looks right; settling keeps those out
    assert used.mean() < 0.02
    # the readings never agree with each other for relearn_s: the reference field stays
    np.testing.assert_allclose(m0, [0.0, 16.0, -45.0], atol=0.5)
    without_settling, _ = _magnet_on_phone(s.with_changes(mag_settle_s=0.0))
    assert without_settling.mean() > used.mean()


def test_a_changed_field_is_relearned_after_consistent_readings():
    s = PRESETS["default"].with_changes(mag_relearn_s=3.0, update_period_s=0.0)
    f = OrientationEKF(s)
    new_field = np.array([0.0, 30.0, -30.0])     # stronger and another dip: a new place
    for k in range(1000):
        t = k * 0.01
        f.step(t, gyr=[0, 0, 0], acc=G0, mag=M0 if t < 2 else new_field)
        if 2.5 < t < 4.9:
            assert f.flags.mag_rejected
    assert not f.flags.mag_rejected and f.flags.used_mag
    assert f.snapshot()["state"]["mag_strength"] == pytest.approx(np.linalg.norm(new_field),
                                                                  rel=1e-6)


def test_dip_from_the_estimate_ignores_accelerations():
    s = PRESETS["default"].with_changes(update_period_s=0.0)
    ref = math.degrees(math.acos(M0[2] / np.linalg.norm(M0)))
    f = OrientationEKF(s)
    acc_based = OrientationEKF(s.with_changes(mag_dip_from_estimate=False, acc_gate=100.0))
    for filt in (f, acc_based):
        for k in range(100):
            filt.step(k * 0.01, gyr=[0, 0, 0], acc=G0, mag=M0)
        filt.step(1.0, gyr=[0, 0, 0], acc=G0 + [6.0, 0, 0], mag=M0)
    assert f.diagnostics.mag_dip_deg == pytest.approx(ref, abs=0.05)
    assert f.diagnostics.mag_reference_dip_deg == pytest.approx(ref, abs=1e-9)
    assert abs(acc_based.diagnostics.mag_dip_deg - ref) > 10


def test_update_period_caps_the_slow_updates():
    s = PRESETS["default"].with_changes(update_period_s=0.05)
    f = OrientationEKF(s)
    mag_updates = 0
    for k in range(200):                        # 2 s at 100 Hz
        f.step(k * 0.01, gyr=[0, 0, 0], acc=G0, mag=M0)
        mag_updates += f.flags.used_mag
    assert 35 <= mag_updates <= 41


def test_exact_time_update_keeps_w_nonnegative_without_normalising():
    s = PRESETS["default"]
    f = OrientationEKF(s.with_changes(acc_gate=0.0))
    f.set_enabled(acc=True, mag=False)
    f.step(0.0, gyr=[0, 0, 0], acc=G0)
    f.set_enabled(acc=False)
    for k in range(1, 400):                     # 4 s at 3 rad/s: w changes sign
        f.step(k * 0.01, gyr=[0, 0, 3.0])
        assert f.quat[0] >= 0
        assert abs(np.linalg.norm(f.quat) - 1) < 1e-12
