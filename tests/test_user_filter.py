"""Your own filter as an estimator: the contract, the template, and every way it can go wrong
(each gives a message naming the file and line, or what was wrong, and pauses only that filter).

UserFilterEstimator runs the filter in a process of its own; a few tests look at the user's
object itself through FilterInstance, the part of that process that holds it."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
import pytest

import ekf
from app.engine.offline.filtering import run_offline
from app.engine.userfilter.code import UserFilterError, load_code
from app.engine.userfilter.filter import UserFilterEstimator, estimator_for, filter_settings
from app.engine.userfilter.instance import FilterInstance
from app.engine.userfilter.protocol import settings_from_wire, settings_to_wire
from app.engine.userfilter.template import template_text, write_template
from app.stream.logfile import LogData
from app.stream.protocol import parse_line
from user_filters import FILTERS, log_lines, write_filter


def _samples(seconds: float = 3.0, turn_rate: float = 0.5) -> LogData:
    return LogData.from_samples(parse_line(line.decode())
                                for line in log_lines(seconds, turn_rate=turn_rate))


def _run(path, seconds: float = 3.0, settings=None, turn_rate: float = 0.5):
    estimator = UserFilterEstimator(path, settings)
    rows = run_offline(_samples(seconds, turn_rate), estimator, settings)
    return estimator, rows


# ---- the template ----------------------------------------------------------------------------

def test_the_template_runs_as_written_flat_with_every_step_noted_missing(tmp_path):
    path = write_template(tmp_path / "mine.py")
    estimator, rows = _run(path)
    assert isinstance(estimator, ekf.Estimator)
    assert estimator.problem is None
    assert np.all(rows.quat == [1.0, 0.0, 0.0, 0.0])           # a flat estimate throughout
    lines = path.read_text().splitlines()
    missing = estimator.missing_steps()
    assert [m.split(" ")[0] for m in missing] == ["tu_qw", "mu_g", "mu_m", "mu_normalizeQ"]
    for entry in missing:                     # each names the line of its raise
        line = int(entry.rsplit(":", 1)[1].rstrip(")"))
        assert "raise NotImplementedError" in lines[line - 1]
    assert estimator.cov.shape == (4, 4)


def test_writing_tu_qw_alone_turns_the_phone_with_the_gyroscope(tmp_path):
    text = template_text("mine.py").replace(
        '    raise NotImplementedError("task 4: tu_qw")',
        "    F = np.eye(4) + T / 2 * Somega(omega)\n"
        "    G = T / 2 * Sq(x)\n"
        "    return F @ x, F @ P @ F.T + G @ Rw @ G.T")
    path = tmp_path / "mine.py"
    path.write_text(text)
    estimator, rows = _run(path, seconds=3.0, turn_rate=2.0)
    assert estimator.problem is None          # |q| drifts: normalised for display, with a note
    assert any("mu_normalizeQ is not written yet" in note for note in estimator.notes)
    turned = ekf.quaternion.from_axis_angle([0, 0, 1], 2.0 * 1.98)   # 2 rad/s for 1.98 s
    assert math.degrees(ekf.quaternion.angle_between(rows.quat[-1], turned)) < 0.5
    assert [m.split(" ")[0] for m in estimator.missing_steps()] == ["mu_g", "mu_m",
                                                                    "mu_normalizeQ"]


def test_the_constructor_gets_the_active_settings(tmp_path):
    path = write_filter(tmp_path, "keeps", """
        class Filter:
            def __init__(self, settings):
                self.settings = settings
                print("g0", settings["g0"].tolist(), "Ra", settings["Ra"].tolist(),
                      "m0", settings["m0"], "gates", settings["acc_gate"], settings["mag_gate"])
            def step(self, t, gyr, acc, mag):
                return [1.0, 0.0, 0.0, 0.0]
    """)
    printed = []
    with UserFilterEstimator(path, ekf.PRESETS["course"], on_output=printed.append):
        pass                        # (closing it: what it printed has been read)
    course = ekf.PRESETS["course"]
    assert printed == [f"g0 [0.0, 0.0, 9.81] Ra {course.acc_noise_cov} m0 None gates 1.0 5.0"]
    assert set(filter_settings(ekf.PRESETS["default"])) >= {"g", "g0", "m0", "Rw", "Ra", "Rm",
                                                            "gyr_bias"}


@pytest.mark.parametrize("preset", sorted(ekf.PRESETS))
def test_the_settings_reach_the_filters_process_bit_for_bit(preset):
    settings = filter_settings(ekf.PRESETS[preset])
    back = settings_from_wire(settings_to_wire(settings))
    assert set(back) == set(settings)
    for key, value in settings.items():
        if isinstance(value, np.ndarray):
            assert back[key].dtype == value.dtype and np.array_equal(back[key], value)
        else:
            assert back[key] == value and type(back[key]) is type(value)


# ---- what step may return ------------------------------------------------------------------

def test_a_dict_with_P_lights_and_innovations(tmp_path):
    path = write_filter(tmp_path, "full", """
        import numpy as np
        class Filter:
            def step(self, t, gyr, acc, mag):
                out = {"q": np.array([-0.6, 0.0, 0.0, -0.8]), "P": 0.01 * np.eye(7),
                       "acc_disturbed": acc is not None, "mag_disturbed": False,
                       "standstill": True}
                if acc is not None:
                    out["innovations"] = {"acc": (np.ones(3), 4.0 * np.eye(3))}
                return out
    """)
    estimator = UserFilterEstimator(path)
    estimator.collect_innovations = True
    estimator.step(0.0, [0, 0, 0.1], [0, 0, 9.8], None)
    assert estimator.problem is None
    assert estimator.quat == pytest.approx([0.6, 0.0, 0.0, 0.8])   # w >= 0
    assert estimator.cov.shape == (4, 4) and estimator.cov[0, 0] == 0.01
    flags = estimator.flags
    assert flags.acc_rejected and not flags.mag_rejected and flags.at_rest
    assert flags.used_gyr and flags.used_acc and not flags.used_mag
    assert estimator.diagnostics.acc_nis == pytest.approx(0.75)
    t, sensor, nu, S, accepted = estimator.innovations[0]
    assert (t, sensor, accepted) == (0.0, "acc", False) and S.shape == (3, 3)


def test_switched_off_sensors_reach_the_filter_as_none(tmp_path):
    path = write_filter(tmp_path, "records", """
        class Filter:
            def step(self, t, gyr, acc, mag):
                print(gyr is None, acc is None, mag is None)
                return [1.0, 0.0, 0.0, 0.0]
    """)
    printed = []
    with UserFilterEstimator(path, sensors=("gyr", "mag"), on_output=printed.append) as estimator:
        estimator.step(0.0, [0, 0, 0], [0, 0, 9.8], [0, 20, -40])
        estimator.set_enabled(acc=True, mag=False)
        estimator.step(0.01, [0, 0, 0], [0, 0, 9.8], [0, 20, -40])
    assert printed == ["False True False", "False False True"]


def test_unknown_keys_are_a_note_not_a_pause(tmp_path):
    path = write_filter(tmp_path, "typo", """
        class Filter:
            def step(self, t, gyr, acc, mag):
                return {"q": [1.0, 0, 0, 0], "acc_disturbd": True}
    """)
    estimator = UserFilterEstimator(path)
    estimator.step(0.0, None, [0, 0, 9.8], None)
    assert estimator.problem is None
    assert "acc_disturbd" in estimator.notes[0]


# ---- errors --------------------------------------------------------------------------------

def test_an_exception_pauses_the_filter_with_file_line_and_message(tmp_path):
    path = write_filter(tmp_path, "raises")
    estimator, rows = _run(path)
    problem = estimator.problem
    assert problem.kind == "exception" and problem.file == str(path.resolve())
    assert problem.line == 11 and problem.function == "update"
    assert problem.message.startswith("raises.py:11 in update: ValueError:")
    assert problem.t_s == pytest.approx(1.51)
    assert "return self.update(acc)" in problem.details            # the user's frames
    assert "app/engine/userfilter" not in problem.details           # not ours
    calls = estimator.calls
    estimator.step(5.0, None, [0, 0, 9.8], None)                    # paused: not called again
    assert estimator.calls == calls == 52
    assert len(rows) == 300 and np.all(rows.quat[-1] == [1.0, 0, 0, 0])


def test_an_endless_loop_is_stopped_at_its_line(tmp_path):
    import time
    estimator = UserFilterEstimator(write_filter(tmp_path, "endless"), step_limit_s=0.2)
    started = time.monotonic()
    rows = run_offline(_samples(3.0), estimator)
    assert time.monotonic() - started < 5.0
    problem = estimator.problem
    assert problem.kind == "exception" and problem.line in (6, 7) and problem.function == "step"
    assert problem.message.startswith(f"endless.py:{problem.line} in step: UserCodeTimeout: "
                                      "step() ran for more than 0.2 s and was stopped")
    assert problem.t_s == pytest.approx(1.51) and len(rows) == 300


def test_the_watchdog_stops_the_call_and_nothing_else(tmp_path):
    """In your filter's process: the watchdog fires once into the endless call, and not again
    into the same thread once the call is over."""
    import time

    from app.engine.userfilter.watchdog import times_fired
    fired = times_fired()
    instance = FilterInstance(load_code(write_filter(tmp_path, "endless")), {}, step_limit_s=0.2)
    assert instance.step(1.0, None, None, None) is not None
    assert instance.step(1.6, None, None, None) is None
    assert "UserCodeTimeout" in instance.problem.message
    assert times_fired() == fired + 1
    # a negative wait, three limits' time of Python code running where a late
    # UserCodeTimeout would land
    deadline = time.monotonic() + 0.6
    while time.monotonic() < deadline:
        sum(range(1000))
    assert times_fired() == fired + 1


def test_a_file_or_constructor_that_never_returns_is_stopped(tmp_path, monkeypatch):
    import app.engine.userfilter.code as user_code
    monkeypatch.setattr(user_code, "LOAD_LIMIT_S", 0.2)   # (the filter's process is told too)
    body = """
        while True:
            pass
    """
    with pytest.raises(UserFilterError) as raised:
        load_code(write_filter(tmp_path, "hangs", body))
    assert "loading the file ran for more than 0.2 s" in raised.value.problem.message
    assert raised.value.problem.line in (2, 3)
    body = """
        class Filter:
            def __init__(self):
                while True:
                    pass
            def step(self, t, gyr, acc, mag):
                return [1.0, 0, 0, 0]
    """
    estimator = UserFilterEstimator(write_filter(tmp_path, "hangs_init", body))
    assert "Filter() ran for more than 0.2 s" in estimator.problem.message
    assert estimator.paused


@pytest.mark.parametrize("name, expected", [
    ("nan", "q is not finite"),
    ("shape", "q has shape (3,), expected 4 numbers (w, x, y, z)"),
    ("nonunit", "q is not a unit quaternion: |q| = 1.2"),
])
def test_garbage_returned_pauses_with_a_message_naming_it(tmp_path, name, expected):
    estimator, _ = _run(write_filter(tmp_path, name))
    problem = estimator.problem
    assert problem is not None and problem.kind == "output"
    assert expected in problem.message and problem.message.startswith(f"{name}.py: ")


@pytest.mark.parametrize("body, expected", [
    ("class Filter:\n    def step(self, t, gyr, acc, mag)\n        return [1, 0, 0, 0]\n",
     "bad.py:2: SyntaxError"),
    ("import numpy as np\nx = 1 / 0\n", "bad.py:2 in <module>: ZeroDivisionError"),
    ("def step(t, gyr, acc, mag):\n    return [1, 0, 0, 0]\n", "bad.py: no class Filter"),
])
def test_a_file_that_does_not_load_says_where(tmp_path, body, expected):
    path = tmp_path / "bad.py"
    path.write_text(body)
    with pytest.raises(UserFilterError) as caught:
        load_code(path)
    assert caught.value.problem.message.startswith(expected)
    assert caught.value.problem.kind == "load"


def test_a_constructor_that_raises_pauses_it_from_the_start(tmp_path):
    path = write_filter(tmp_path, "ctor", """
        class Filter:
            def __init__(self, settings):
                self.R = settings["no such key"]
            def step(self, t, gyr, acc, mag):
                return [1.0, 0, 0, 0]
    """)
    estimator = UserFilterEstimator(path)
    assert estimator.paused
    assert estimator.problem.message.startswith("ctor.py:4 in __init__: KeyError")


def test_not_implemented_in_a_helper_skips_the_sample_and_is_noted(tmp_path):
    path = write_filter(tmp_path, "helper", """
        class Filter:
            def step(self, t, gyr, acc, mag):
                if mag is not None:
                    return self.gate(mag)
                return [1.0, 0.0, 0.0, 0.0]
            def gate(self, mag):
                raise NotImplementedError("task 11")
    """)
    estimator, rows = _run(path)
    assert estimator.problem is None
    assert estimator.missing_steps() == ["gate (helper.py:8)"]
    assert np.all(rows.quat == [1.0, 0.0, 0.0, 0.0])


# ---- the rest of the Estimator protocol -------------------------------------------------------

def test_snapshot_restore_and_align_heading(tmp_path):
    path = write_filter(tmp_path, "count", """
        import math
        class Filter:
            def __init__(self):
                self.angle = 0.0
            def step(self, t, gyr, acc, mag):
                self.angle += 0.1
                return [math.cos(self.angle / 2), 0.0, 0.0, math.sin(self.angle / 2)]
    """)
    estimator = UserFilterEstimator(path)
    estimator.step(0.0)
    saved = estimator.snapshot()
    estimator.step(0.01)
    estimator.step(0.02)
    estimator.restore(saved)
    estimator.step(0.01)
    assert 2 * math.atan2(estimator.quat[3], estimator.quat[0]) == pytest.approx(0.2)
    estimator.align_heading(ekf.quaternion.IDENTITY)
    assert estimator.quat == pytest.approx([1.0, 0.0, 0.0, 0.0])
    estimator.reset()
    estimator.step(0.03)                                        # a new Filter object: 0.1
    # ... shown still turned by the alignment (-0.2)
    assert 2 * math.atan2(estimator.quat[3], estimator.quat[0]) == pytest.approx(-0.1)


def test_estimator_for_takes_names_files_and_objects(tmp_path):
    path = write_filter(tmp_path, "flat")
    assert estimator_for(str(path)).name == "flat.py"
    assert estimator_for("course").name == "course"
    estimator = UserFilterEstimator(path)
    assert estimator_for(estimator) is estimator
    assert textwrap.dedent(FILTERS["flat"]) in path.read_text()


def test_an_object_that_misbehaves_when_read_is_a_problem_not_a_crash(tmp_path):
    path = write_filter(tmp_path, "weird", """
        class Weird:
            def __array__(self, *args, **kwargs):
                raise RuntimeError("no array for you")
        class Filter:
            def step(self, t, gyr, acc, mag):
                return {"q": Weird()}
    """)
    estimator = UserFilterEstimator(path)
    estimator.step(0.0)
    assert estimator.paused and "no array for you" in estimator.problem.message
    assert estimator.problem.message.startswith("weird.py:4 in __array__: RuntimeError")


# ---- its process -----------------------------------------------------------------------------

def test_tunes_re_run_runs_your_filter_on_every_row(tmp_path):
    from app.engine.config import open_log
    from app.engine.offline.filtering import filter_log
    from app.engine.offline.refilter import refilter
    log_path = tmp_path / "log.txt"
    log_path.write_bytes(b"".join(log_lines(3.0)))
    log = open_log(log_path)
    course = Path(__file__).resolve().parents[1] / "examples" / "course_ekf.py"
    result = refilter(log, ekf.PRESETS["course"], str(course))
    with UserFilterEstimator(course, ekf.PRESETS["course"]) as estimator:
        rows = filter_log(log, estimator, ekf.PRESETS["course"])
    assert np.array_equal(result.rows.quat, rows.quat) and len(rows) == 300


def test_a_dropped_estimator_ends_its_process(tmp_path):
    import gc
    import os

    from waiting import wait_until
    estimator = UserFilterEstimator(write_filter(tmp_path, "flat"))
    pid = estimator.remote.process.pid
    os.kill(pid, 0)                                     # running
    del estimator
    gc.collect()

    def gone() -> bool:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        return False
    wait_until(gone, 10, "the filter's process to end")
