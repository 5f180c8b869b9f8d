"""benchmarks/augment.py: the faults it adds to a recording are the physics it claims, and each
copy is reproduced exactly (the robustness figures and `tune_defaults.py --augment` rely on it).

A simulated session stands in for a shared recording: its truth is known at every sample."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from ekf import quaternion as Q
from ekf.simulate import simulate

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from augment import SCENARIOS, perturbed  # noqa: E402
from datasets import Recording  # noqa: E402


@pytest.fixture(scope="module")
def recording() -> Recording:
    s = simulate(duration_s=40.0, seed=2)
    t, g, a, m = s.to_batch_arrays()
    truth_t_ms = np.arange(np.ceil(t[0] * 1000), np.floor(t[-1] * 1000), 10.0)
    truth = s.quat_at(truth_t_ms.astype(np.int64))
    return Recording("sim", "tyrex", "tyrex-sim", False, t, g, a, m, truth_t_ms, truth,
                     np.ones(len(truth_t_ms), bool))


def _world_change(rec: Recording, copy: Recording) -> tuple[np.ndarray, np.ndarray]:
    """What was added to the magnetometer, turned into the world frame by the truth, and the
    rows it was added on (inside the truth)."""
    rows = ~np.isnan(rec.mag).any(axis=1)
    inside = rows & (rec.t_s * 1000 >= rec.ref_t_ms[0]) & (rec.t_s * 1000 <= rec.ref_t_ms[-1])
    q = np.array([rec.ref_q[np.argmin(np.abs(rec.ref_t_ms - t * 1000))] for t in rec.t_s[inside]])
    return np.einsum("nij,nj->ni", Q.to_matrix(q), copy.mag[inside] - rec.mag[inside]), inside


def test_each_copy_is_reproduced_and_copies_differ(recording):
    for scenario in SCENARIOS:
        a, b = perturbed(recording, scenario, 0), perturbed(recording, scenario, 0)
        other = perturbed(recording, scenario, 1)
        for name in ("gyr", "mag"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        changed = "gyr" if scenario == "gyro-bias" else "mag"
        assert not np.array_equal(getattr(a, changed), getattr(other, changed))
        assert a.name == f"sim+{scenario}#0"
        np.testing.assert_array_equal(a.ref_q, recording.ref_q)       # the truth stays
    with pytest.raises(ValueError, match="unknown scenario"):
        perturbed(recording, "earthquake")


def test_a_building_field_is_fixed_in_the_world_and_bounded(recording):
    copy = perturbed(recording, "building-50", 0)
    d, _ = _world_change(recording, copy)
    size = np.linalg.norm(d, axis=1)
    assert 10.0 < size.max() <= 50.0 * 1.5          # bumps may overlap
    assert (size < 1e-9).mean() > 0.2               # it comes and goes
    # in the world it changes smoothly however fast the phone turns (the truth's 10 ms grid
    # and the 1-8 s bumps: no step beyond what a bump's slope allows)
    assert np.abs(np.diff(d, axis=0)).max() < 3.0


def test_a_desk_start_fades_out(recording):
    copy = perturbed(recording, "desk-start", 0)
    d, inside = _world_change(recording, copy)
    t = recording.t_s[inside] - recording.t_s[0]
    assert np.linalg.norm(d[t < 0.5], axis=1).min() > 5.0
    assert np.abs(d[t > 10.0]).max() < 1e-9
    assert np.ptp(d[t < 2.0] / np.linalg.norm(d[t < 2.0], axis=1, keepdims=True), axis=0).max() \
        < 1e-6                                      # one direction, fading


def test_a_magnet_and_a_gyro_bias_are_constant_in_the_sensor_frame(recording):
    magnet = perturbed(recording, "magnet-20", 0)
    rows = ~np.isnan(recording.mag).any(axis=1)
    offset = magnet.mag[rows] - recording.mag[rows]
    np.testing.assert_allclose(offset, np.tile(offset[0], (len(offset), 1)), atol=1e-9)
    assert np.linalg.norm(offset[0]) == pytest.approx(20.0)
    bias = perturbed(recording, "gyro-bias", 0)
    g_rows = ~np.isnan(recording.gyr).any(axis=1)
    step = bias.gyr[g_rows] - recording.gyr[g_rows]
    np.testing.assert_allclose(step, np.tile(step[0], (len(step), 1)), atol=1e-12)
    assert np.degrees(np.linalg.norm(step[0])) == pytest.approx(0.5)


def test_a_raw_magnetometer_in_a_building_is_two_scenarios_in_order(recording):
    """``magnet-400``: any strength; ``building-50+magnet-400``: the building's field, then the
    400 uT offset, each as on its own (the composition's name says both)."""
    from augment import known

    raw = perturbed(recording, "magnet-400", 0)
    rows = ~np.isnan(recording.mag).any(axis=1)
    offset = raw.mag[rows] - recording.mag[rows]
    np.testing.assert_allclose(np.linalg.norm(offset, axis=1), 400.0)
    both = perturbed(recording, "building-50+magnet-400", 0)
    building = perturbed(recording, "building-50", 0)
    step = perturbed(building, "magnet-400", 0)
    np.testing.assert_array_equal(both.mag, step.mag)
    assert both.name == "sim+building-50#0+magnet-400#0"
    assert known("building-50+magnet-400") and known("magnet-400") and known("desk-start")
    assert not known("magnet-") and not known("magnet-0") and not known("earthquake+magnet-20")
