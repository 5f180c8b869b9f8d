"""Innovations for the consistency view: our EKF's from a twin (which must not change our
estimates and, for the course preset, is exactly the filter's own update), and the packing."""

from __future__ import annotations

import numpy as np
import pytest

import ekf
from app.engine.processing.innovations import OWN, InnovationBuffer, course_innovation
from app.engine.processing.runner import EstimatorRunner
from app.stream.fastparse import samples_to_arrays
from app.stream.protocol import parse_line
from user_filters import log_lines


def _arrays(seconds: float = 4.0):
    lines = log_lines(seconds, turn_rate=1.0)
    # a knock on the accelerometer now and then: the task-8 gate rejects it
    lines = [line.replace(b"\t9.81\n", b"\t12.5\n") if i % 97 == 0 else line
             for i, line in enumerate(lines)]
    return samples_to_arrays([parse_line(line.decode()) for line in lines])


@pytest.mark.parametrize("preset", ["course", "default"])
def test_the_probe_leaves_our_estimates_alone(preset):
    arrays = _arrays()
    settings = ekf.PRESETS[preset]
    plain = EstimatorRunner("ekf", settings)
    probed = EstimatorRunner("ekf", settings)
    probed.set_consistency_enabled(True)
    for runner in (plain, probed):
        for start in range(0, len(arrays.t_ms), 257):       # chunk by chunk, as live
            end = start + 257
            runner.feed_arrays(arrays.t_ms[start:end], arrays.tag[start:end],
                               arrays.values[start:end])
        runner.finish()
    assert np.array_equal(plain.take_rows().quat, probed.take_rows().quat)
    records = probed.take_innovations()
    n_acc = int(np.sum(records["innovation_sensor"] == 0))
    assert n_acc > 350 and np.all(records["innovation_source"] == OWN)
    assert (~records["innovation_accepted"][records["innovation_sensor"] == 0]).sum() >= 3


def test_for_the_course_preset_the_probe_is_the_filter_s_own_update():
    """NIS of each recorded accelerometer innovation = the EKF's diagnostic NIS after it."""
    arrays = _arrays(3.0)
    runner = EstimatorRunner("course")
    runner.set_consistency_enabled(True)
    runner.feed_arrays(arrays.t_ms, arrays.tag, arrays.values)
    records = runner.take_innovations()
    reference = ekf.OrientationEKF("course")
    expected = []
    for t, tag, values in zip(arrays.t_ms / 1000.0, arrays.tag, arrays.values):
        name = ("update_gyr", "update_acc", "update_mag", None)[tag]
        if name is None:
            continue
        initialised = reference.initialised
        getattr(reference, name)(t, values[:3])
        if tag == 1 and initialised and reference.flags.used_acc:
            expected.append(reference.diagnostics.acc_nis)
    acc = (records["innovation_sensor"] == 0) & records["innovation_accepted"]
    nu = records["innovation"][acc]
    S = records["innovation_cov"][acc]
    nis = np.einsum("ni,ni->n", nu, np.linalg.solve(S, nu[..., None])[..., 0])
    assert len(nis) == len(expected) > 100
    assert np.allclose(nis, expected, rtol=1e-9, atol=1e-12)


def test_course_innovation_and_the_padding():
    q = ekf.quaternion.from_axis_angle([1, 0, 0], 0.3)
    P = 1e-3 * np.eye(4)
    g0 = np.array([0.0, 0.0, 9.81])
    y = ekf.quaternion.to_matrix(q).T @ g0
    nu, S = course_innovation(q, P, y + [0.1, 0.0, 0.0], 0.1 * np.eye(3), g0)
    assert nu == pytest.approx([0.1, 0.0, 0.0]) and S.shape == (3, 3)
    assert np.all(np.linalg.eigvalsh(S) >= 0.1 - 1e-12)
    buffer = InnovationBuffer()
    buffer.add(1.0, 1, "mag", np.array([0.5]), np.array([[2.0]]), False)
    out = buffer.take()
    assert out["innovation"].shape == (1, 3) and np.isnan(out["innovation"][0, 1:]).all()
    assert out["innovation_cov"][0, 0, 0] == 2.0 and np.isnan(out["innovation_cov"][0, 1, 1])
    assert out["innovation_sensor"].tolist() == [1] and out["innovation_source"].tolist() == [1]
    assert len(buffer) == 0 and len(buffer.take()["t_innovation"]) == 0
