"""A stream without one of the sensors (a real walking log had ACC, MAG and ORI only): its
switch, its plot and the combination rows that use it say "no gyroscope in this stream" instead
of a ticked switch, an empty 0-1 axis and the other sensors' figures; when the sensor's samples
arrive the notes go away and the switch is as the user left it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ui_helpers import make_snapshot

from app.engine.processing.runner import COMBINATIONS, combination_name
from app.engine.snapshot import Comparison

NO_GYR = {"acc": 250, "mag": 125, "ori": 250}


def _snapshot(seq: int, t_s: float, gyr: int = 0, **status):
    """make_snapshot of a stream that has delivered `gyr` GYR samples in this session (none:
    its plot chunk has no gyroscope samples), with the seven combinations' figures."""
    snapshot = make_snapshot(seq, t_s, **status)
    if not gyr:
        snapshot.plot.t_gyr = np.empty(0)
        snapshot.plot.gyr = np.empty((0, 3))
    snapshot.session_samples = {"gyr": gyr, **NO_GYR}
    snapshot.comparisons = [Comparison(combination_name(combo), None, (75.0 + k, 4.0, 2.0),
                                       samples=250) for k, combo in enumerate(COMBINATIONS)]
    return snapshot


def _show(window, fake_engine, snapshot) -> None:
    fake_engine.snapshots.append(snapshot)
    window.tick()
    window.refresh_panels()


def _gyr_rows(window) -> dict[str, tuple[str, ...]]:
    return {row[0]: row[1:] for row in window.comparison.rows()}


def test_no_gyroscope_on_the_switch_the_plot_and_the_rows_until_it_arrives(
        make_window, fake_engine):
    window = make_window(fake_engine)
    window.show()
    switch = window.controls.sensor_checkboxes["gyr"]
    # the session is young: nothing said yet
    _show(window, fake_engine, _snapshot(1, 0.5))
    assert switch.isEnabled() and window.plots.no_data_text("gyr") == ""
    assert _gyr_rows(window)["gyr"] == ("79.0", "4.0", "2.0")
    # 3 s of ACC, MAG and ORI without a single GYR sample
    _show(window, fake_engine, _snapshot(2, 2.5))
    assert not switch.isEnabled() and switch.isChecked()         # the choice is kept
    assert "no gyroscope in this stream" in switch.toolTip()
    assert not window.controls.sensor_note.isHidden()
    assert window.controls.sensor_note.text() == "no gyroscope in this stream"
    assert not window.sensor_actions["gyr"].isEnabled()
    assert window.sensor_actions["gyr"].isChecked()
    for sensor in ("acc", "mag"):
        assert window.controls.sensor_checkboxes[sensor].isEnabled()
        assert window.plots.no_data_text(sensor) == ""
    assert window.plots.no_data_text("gyr") == "no gyroscope in this stream"
    item = window.plots.no_data_items["gyr"]
    assert item.isVisible()
    box = window.plots.plots["gyr"].getViewBox().boundingRect()
    centre = item.mapRectToParent(item.boundingRect()).center()
    assert abs(centre.x() - box.center().x()) < 2 and abs(centre.y() - box.center().y()) < 2
    rows = _gyr_rows(window)
    for name, figures in rows.items():
        if "gyr" in name.split("+"):
            assert figures == ("no gyroscope",) * 3, name
        else:
            assert "no gyroscope" not in figures and figures[0].endswith(".0"), name
    assert window.comparison.table.columnSpan(0, 1) == 3        # one text over the figures
    assert "gyroscope" in window.comparison.table.item(0, 1).toolTip()
    # GYR arrives: the notes go, the figures come back, the switch is on as it was
    _show(window, fake_engine, _snapshot(3, 3.0, gyr=50))
    assert switch.isEnabled() and switch.isChecked() and switch.toolTip() == ""
    assert window.controls.sensor_note.isHidden()
    assert window.sensor_actions["gyr"].isEnabled()
    assert window.plots.no_data_text("gyr") == "" and not item.isVisible()
    assert _gyr_rows(window)["gyr+acc"] == ("76.0", "4.0", "2.0")
    assert window.comparison.table.columnSpan(0, 1) == 1


def test_a_switch_the_user_turned_off_stays_off_when_the_sensor_arrives(make_window,
                                                                         fake_engine):
    from app.engine.commands import SetSensorEnabled
    window = make_window(fake_engine)
    window.show()
    switch = window.controls.sensor_checkboxes["gyr"]
    switch.click()                        # the user takes the gyroscope out
    assert fake_engine.commands_of(SetSensorEnabled)[-1] == SetSensorEnabled("gyr", False)
    off = {"gyr": False, "acc": True, "mag": True}
    _show(window, fake_engine, _snapshot(1, 2.5, sensors_enabled=off))
    assert not switch.isEnabled() and not switch.isChecked()
    _show(window, fake_engine, _snapshot(2, 3.0, gyr=50, sensors_enabled=off))
    assert switch.isEnabled() and not switch.isChecked()
    assert len(fake_engine.commands_of(SetSensorEnabled)) == 1   # nothing sent on its own


@pytest.mark.parametrize("sensor", ["acc", "mag"])
def test_any_absent_sensor_is_named(make_window, fake_engine, sensor):
    window = make_window(fake_engine)
    window.show()
    snapshot = _snapshot(1, 2.5, gyr=250)
    snapshot.session_samples[sensor] = 0
    _show(window, fake_engine, snapshot)
    name = {"acc": "accelerometer", "mag": "magnetometer"}[sensor]
    assert window.plots.no_data_text(sensor) == f"no {name} in this stream"
    assert window.plots.no_data_text("gyr") == ""
    assert not window.controls.sensor_checkboxes[sensor].isEnabled()
    rows = _gyr_rows(window)
    assert rows[sensor] == (f"no {name}",) * 3
    assert rows["gyr"] == ("79.0", "4.0", "2.0")


def _write_log(path: Path, session, keep=lambda t_ms, tag: True) -> Path:
    from app.stream.protocol import Sample, format_line
    with open(path, "w", newline="\n") as file:
        for t_ms, tag, values in session.to_rows():
            if keep(int(t_ms), tag):
                file.write(format_line(Sample(int(t_ms), tag, tuple(float(v) for v in values)))
                           + "\n")
    return path


def test_a_real_replay_without_a_gyroscope_says_so_everywhere(make_window, tmp_path, qtbot):
    from ekf.simulate import simulate

    from app.engine.live.worker import Engine
    from app.stream.sources import LogFileSource
    log = _write_log(tmp_path / "walk.txt", simulate(duration_s=6.0, seed=4,
                                                      rates_hz={"gyr": 0.0}))
    assert "GYR" not in log.read_text()
    engine = Engine(LogFileSource(log, speed=0.0))
    engine.start()
    window = make_window(engine)
    try:
        window.show()
        qtbot.waitUntil(lambda: window.plots.no_data_text("gyr") != "", timeout=60000)
        assert window.plots.no_data_text("gyr") == "no gyroscope in this stream"
        assert not window.controls.sensor_checkboxes["gyr"].isEnabled()
        assert window.controls.sensor_checkboxes["gyr"].isChecked()

        def rows_say_so():
            rows = _gyr_rows(window)
            return len(rows) == 7 and rows["gyr+acc"] == ("no gyroscope",) * 3
        qtbot.waitUntil(rows_say_so, timeout=15000)
        rows = _gyr_rows(window)
        assert rows["gyr"] == rows["gyr+mag"] == rows["gyr+acc+mag"] == ("no gyroscope",) * 3
        assert rows["acc+mag"][0] not in ("no gyroscope", "")
        assert window.plots.no_data_text("acc") == window.plots.no_data_text("mag") == ""
    finally:
        window.close()


def test_a_gyroscope_that_starts_late_ends_the_notes(make_window, tmp_path, qtbot):
    from ekf.simulate import simulate

    from app.engine.live.worker import Engine
    from app.stream.sources import LogFileSource
    session = simulate(duration_s=7.0, seed=5, t0_ms=1_000_000)
    log = _write_log(tmp_path / "late.txt", session,
                     keep=lambda t_ms, tag: tag != "GYR" or t_ms >= 1_004_500)
    engine = Engine(LogFileSource(log, speed=1.0), comparisons=False)
    engine.start()
    window = make_window(engine)
    try:
        window.show()
        qtbot.waitUntil(lambda: window.plots.no_data_text("gyr") != "", timeout=60000)
        assert not window.controls.sensor_checkboxes["gyr"].isEnabled()
        qtbot.waitUntil(lambda: window.plots.no_data_text("gyr") == "", timeout=60000)
        assert window.last_snapshot.session_samples["gyr"] > 0
        assert window.controls.sensor_checkboxes["gyr"].isEnabled()
        assert window.controls.sensor_checkboxes["gyr"].isChecked()
        assert window.controls.sensor_note.isHidden()
    finally:
        window.close()
