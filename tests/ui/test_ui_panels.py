"""Lights, switches and the connection panel: snapshot parts in, commands out."""

from __future__ import annotations

import pytest

from ui_helpers import status_of
from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.commands import (AcceptConnection, AlignHeading, IgnoreConnection, ReplayControl,
                                 ResetFilter, SetAllowedNetworks, SetComparisonsEnabled,
                                 SetEstimator, SetSensorEnabled)
from app.engine.snapshot import Comparison, FilterStatus, StreamHealth
from app.ui.connection import ConnectionPanel
from app.ui.controls import ControlsPanel
from app.ui.lights import LightsPanel, light_states


def _click_checkbox(qtbot, checkbox: QtWidgets.QCheckBox) -> None:
    # At the left edge, where the indicator is.
    qtbot.mouseClick(checkbox, QtCore.Qt.MouseButton.LeftButton,
                     pos=QtCore.QPoint(4, checkbox.height() // 2))


# ---- lights ------------------------------------------------------------------------------------

def test_lights_three_states_with_reasons():
    status = status_of(acc_rejected=True, acc_norm=12.3, g=9.81, acc_gate=0.5,
                          mag_norm=50.0, mag_expected=49.0, mag_gate=5.0, at_rest=False)
    states = light_states(status)
    assert states["acc"][0] == "disturbed"
    assert "‖a‖ = 12.30 m/s², g = 9.81, gate 0.50" in states["acc"][1]
    assert states["mag"] == ("ok", "‖m‖ = 50.0 µT, expected 49.0, gate 5.0")
    assert states["standstill"][0] == "moving"

    status.flags.at_rest = True
    status.sensors_enabled = {"gyr": True, "acc": False, "mag": False}
    states = light_states(status)
    assert states["acc"][0] == "off" and states["mag"][0] == "off"
    assert states["standstill"][0] == "still"

    status.sensors_enabled = {"gyr": False, "acc": False, "mag": True}
    assert light_states(status)["standstill"][0] == "off"


def test_lights_panel_shows_state_and_tooltip(qtbot):
    panel = LightsPanel()
    qtbot.addWidget(panel)
    panel.update_status(status_of(mag_rejected=True, mag_norm=80.0, mag_expected=50.0,
                                     mag_gate=5.0, at_rest=True))
    assert panel.states() == {"acc": "ok", "mag": "disturbed", "standstill": "still"}
    assert "‖m‖ = 80.0 µT" in panel.lights["mag"].toolTip()
    assert panel.lights["mag"].toolTip().startswith("Mag disturbed: disturbed")
    panel.update_status(FilterStatus())
    assert panel.states() == {"acc": "ok", "mag": "ok", "standstill": "moving"}
    assert "?" in panel.lights["acc"].toolTip()       # NaN norms say "unknown", not "nan"


# ---- controls ----------------------------------------------------------------------------------

@pytest.fixture
def controls(qtbot):
    sent: list[object] = []
    panel = ControlsPanel(sent.append)
    qtbot.addWidget(panel)
    panel.show()
    qtbot.waitExposed(panel)
    return panel, sent


def test_each_sensor_switch_sends_its_command(qtbot, controls):
    panel, sent = controls
    for sensor in ("gyr", "acc", "mag"):
        _click_checkbox(qtbot, panel.sensor_checkboxes[sensor])
    assert sent == [SetSensorEnabled("gyr", False), SetSensorEnabled("acc", False),
                    SetSensorEnabled("mag", False)]
    _click_checkbox(qtbot, panel.sensor_checkboxes["acc"])
    assert sent[-1] == SetSensorEnabled("acc", True)


def test_estimator_reset_align_and_comparison_switch(qtbot, controls):
    panel, sent = controls
    panel.estimator_combo.setCurrentIndex(panel.estimator_combo.findData("complementary"))
    assert sent[-1] == SetEstimator("complementary")
    qtbot.mouseClick(panel.reset_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent[-1] == ResetFilter()
    qtbot.mouseClick(panel.align_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent[-1] == AlignHeading()
    _click_checkbox(qtbot, panel.comparisons_checkbox)
    assert sent[-1] == SetComparisonsEnabled(False)
    assert [panel.estimator_combo.itemData(i) for i in range(panel.estimator_combo.count())] == [
        "ekf", "course", "complementary", "gyro", "accmag"]


def test_uncertainty_toggle_emits(qtbot, controls):
    panel, _ = controls
    with qtbot.waitSignal(panel.uncertainty_toggled) as blocker:
        _click_checkbox(qtbot, panel.uncertainty_checkbox)
    assert blocker.args == [False]


def test_switches_follow_the_engine_but_a_fresh_click_wins(controls, monkeypatch):
    panel, sent = controls
    status = FilterStatus(sensors_enabled={"gyr": True, "acc": False, "mag": True},
                          estimator="gyro")
    panel.update_status(status)
    assert not panel.sensor_checkboxes["acc"].isChecked()
    assert panel.estimator() == "gyro"
    assert sent == []                          # following the engine sends nothing back
    panel.sensor_checkboxes["mag"].setChecked(False)    # the user's click ...
    panel.update_status(status)                # ... and a snapshot from before it arrived
    assert not panel.sensor_checkboxes["mag"].isChecked()
    import app.ui.controls as controls_module
    monkeypatch.setattr(controls_module, "USER_PRIORITY_S", 0.0)
    panel.update_status(status)                # later, the engine's word counts again
    assert panel.sensor_checkboxes["mag"].isChecked()


def test_comparison_table_lists_every_combination(controls):
    panel, _ = controls
    names = ["gyr", "acc", "mag", "gyr+acc", "gyr+mag", "acc+mag", "gyr+acc+mag"]
    panel.update_comparisons([Comparison(name, None, angle_to_phone_deg=i * 1.25,
                                         rmse_deg=i * 2.0) for i, name in enumerate(names)])
    rows = panel.comparison_rows()
    assert len(rows) == 7
    assert rows[3] == ("gyr + acc", "3.8", "6.0")
    panel.update_comparisons([Comparison("acc+mag", None)])
    assert panel.comparison_rows() == [("acc + mag", "–", "–")]


# ---- connection --------------------------------------------------------------------------------

def test_connection_panel_shows_addresses_state_and_counters(qtbot):
    sent: list[object] = []
    panel = ConnectionPanel(sent.append)
    qtbot.addWidget(panel)
    health = StreamHealth(connection_state="waiting", listen_addresses=["192.168.1.10", "10.0.0.5"],
                          port=3400)
    panel.update_health(health)
    assert panel.address_text() == "192.168.1.10:3400, 10.0.0.5:3400"
    assert "waiting" in panel.state_label.text()
    panel.copy_address()
    assert QtGui.QGuiApplication.clipboard().text() == "192.168.1.10:3400"

    health.connection_state = "connected"
    health.peer = "192.168.1.23:51234"
    health.rates_hz = {"ACC": 99.6, "GYR": 100.2, "MAG": 0.0}
    health.damaged, health.unknown, health.out_of_order = 4, 2, 7
    health.clock_quirks = ["ACC clock +131072000 ms (aligned)"]
    panel.update_health(health)
    assert "connected from 192.168.1.23:51234" in panel.state_label.text()
    assert panel.rates_label.text() == "ACC 100 Hz  GYR 100 Hz"
    assert "4 damaged" in panel.problems_label.text()
    assert "7 out of order" in panel.problems_label.text()
    assert "131072000" in panel.quirks_label.text()
    assert not panel.replay_box.isVisibleTo(panel)
    assert sent == []


def test_connection_panel_asks_about_a_waiting_device_and_sets_who_may_connect(qtbot):
    sent: list[object] = []
    panel = ConnectionPanel(sent.append)
    qtbot.addWidget(panel)
    panel.show()
    health = StreamHealth(connection_state="connected", peer="192.168.1.23:51234", port=3400,
                          damaged=3, damaged_reasons={"ACC out of range": 2, "binary data": 1},
                          connections_closed={"nothing valid": 4},
                          recording="recording stopped: cannot write raw.txt: No space left")
    panel.update_health(health)
    assert not panel.waiting_box.isVisible()
    assert "3 damaged (2 ACC out of range, 1 binary data)" in panel.problems_label.text()
    assert "connections closed: 4 nothing valid" in panel.problems_label.text()
    assert "No space left" in panel.recording_label.text()

    health.waiting_peers = ["192.168.1.42:40000", "192.168.1.43:40001"]
    panel.update_health(health)
    assert panel.waiting_box.isVisible()
    assert panel.waiting_label.text().startswith(
        "A new device at 192.168.1.42 wants to stream: accept?")
    qtbot.mouseClick(panel.accept_button, QtCore.Qt.MouseButton.LeftButton)
    qtbot.mouseClick(panel.ignore_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent == [AcceptConnection("192.168.1.42:40000"), IgnoreConnection("192.168.1.42:40000")]
    health.waiting_peers = []
    panel.update_health(health)
    assert not panel.waiting_box.isVisible()

    sent.clear()
    panel.allow_field.setText("192.168.1.42, 10.0.0.0/8")
    qtbot.mouseClick(panel.allow_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent == [SetAllowedNetworks(("192.168.1.42/32", "10.0.0.0/8"))]
    panel.allow_field.setText("192.168.1.300")
    qtbot.mouseClick(panel.allow_button, QtCore.Qt.MouseButton.LeftButton)
    assert len(sent) == 1 and "not an address" in panel.allow_error.text()
    health.allowed = ["192.168.1.42/32"]
    panel.update_health(health)
    assert panel.allow_field.text() == "192.168.1.42/32"


def test_replay_controls_send_replay_commands(qtbot):
    sent: list[object] = []
    panel = ConnectionPanel(sent.append)
    qtbot.addWidget(panel)
    panel.show()
    panel.update_replay({"position_s": 5.0, "duration_s": 20.0, "speed": 1.0, "paused": False,
                         "loop": False})
    assert panel.replay_box.isVisible()
    assert panel.seek_slider.value() == 250
    assert panel.position_label.text() == "5.0 / 20.0 s"
    assert sent == []                                 # showing the position sends nothing
    qtbot.mouseClick(panel.play_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent[-1] == ReplayControl(paused=True)
    panel.speed_combo.activated.emit(panel.speed_combo.findData(10.0))
    assert sent[-1] == ReplayControl(speed=10.0)
    _click_checkbox(qtbot, panel.loop_checkbox)
    assert sent[-1] == ReplayControl(loop=True)
    panel.seek_slider.setValue(500)                   # a click on the groove
    assert sent[-1] == ReplayControl(seek_s=10.0)
    panel.update_replay(None)
    assert not panel.replay_box.isVisible()
    count = len(sent)
    panel.toggle_replay_paused()                     # nothing to pause without a replay
    assert len(sent) == count
