"""examples/course_ekf.py, a course EKF written as a student would against the template, agrees
with the built-in `course` preset (model 4a, task-8 and task-11 gates) on the shared phone logs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import ekf
from app.engine.config import open_log
from app.engine.offline.filtering import filter_log

from app.engine.userfilter.filter import UserFilterEstimator

COURSE_EKF = Path(__file__).resolve().parents[1] / "examples" / "course_ekf.py"
LOGS = ["sensorLog_20200324T153441-running.txt", "sensorLog_20221020T074342.txt",
        "sensorLog_20221024T182616_standstill.txt", "tsrt14_lab2_accdisturbance.txt",
        "tsrt14_lab2_calibration.txt", "tsrt14_lab2_magdisturbance.txt",
        "tsrt14_lab2_rotation.txt"]


@pytest.mark.shared
@pytest.mark.parametrize("name", LOGS)
def test_course_example_agrees_with_the_course_preset_within_a_tenth_of_a_degree(
        realphone_dir, name):
    path = realphone_dir / name
    if not path.is_file():
        pytest.skip(f"{path} not found")
    log = open_log(path)
    course = ekf.PRESETS["course"]
    student = UserFilterEstimator(COURSE_EKF, course)
    theirs = filter_log(log, student, course)
    ours = filter_log(log, "course")
    assert student.problem is None and student.missing_steps() == []
    assert np.array_equal(theirs.t_ms, ours.t_ms)
    difference = ekf.error_angles_deg(theirs.quat, ours.quat)[0]
    assert np.nanmax(difference) < 0.1
    # both use the gates the same way: the lights agree too
    assert np.mean(theirs.acc_rejected == ours.acc_rejected) > 0.999
    assert np.mean(theirs.mag_rejected == ours.mag_rejected) > 0.999
