"""Lights, switches, the combination table, the connection panel and the transport bar:
snapshot parts in, commands out."""

from __future__ import annotations

import pytest

from ui_helpers import status_of
from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.commands import (AcceptConnection, AlignHeading, IgnoreConnection, ReplayControl,
                                 ResetFilter, SetAllowedNetworks, SetComparisonsEnabled,
                                 SetEstimator, SetSensorEnabled)
from ekf import diagnostics as outputs
from app.engine.snapshot import Comparison, FilterStatus, StreamHealth
from app.ui.connection import ConnectionPanel
from app.ui.controls import ComparisonPanel, FilterPanel
from app.ui.lights import STATE_COLORS, LightsPanel, light_states
from app.ui.transport import TransportBar, position_text


def _click_checkbox(qtbot, checkbox: QtWidgets.QCheckBox) -> None:
    # At the left edge, where the indicator is.
    qtbot.mouseClick(checkbox, QtCore.Qt.MouseButton.LeftButton,
                     pos=QtCore.QPoint(4, checkbox.height() // 2))


# ---- lights ------------------------------------------------------------------------------------

def test_lights_say_off_ok_or_disturbed_with_the_gate_that_fired():
    status = status_of(acc_rejected=True, acc_rejected_by=outputs.ACC_NORM_GATE, acc_norm=12.3,
                       g=9.81, acc_gate=0.5, mag_norm=44.7, mag_expected=42.3, mag_gate=5.0,
                       mag_dip_deg=70.0, mag_reference_dip_deg=58.0, at_rest=False)
    states = light_states(status)
    assert states["acc"][0] == "acc disturbed"
    assert states["acc"][1].startswith("norm gate fired")
    assert "‖a‖ = 12.30 m/s², expected g = 9.81 m/s², norm gate ±0.50 m/s²" in states["acc"][1]
    assert states["mag"][0] == "ok" and "‖m‖ = 44.7 µT, expected L = 42.3 µT" in states["mag"][1]
    assert states["standstill"][0] == "moving"
    # the dip gate fired: inside the strength gate, and the tooltip says why
    status.flags.mag_rejected = True
    status.diagnostics.mag_rejected_by = outputs.MAG_DIP_GATE
    states = light_states(status)
    assert states["mag"][0] == "mag disturbed"
    assert states["mag"][1].startswith("dip gate fired") and "reference 58.0°" in states["mag"][1]
    status.diagnostics.mag_rejected_by = outputs.MAG_SETTLING
    assert light_states(status)["mag"][1].startswith("settling")
    # a raw magnetometer whose offset is being acquired is not "disturbed"
    status.diagnostics.mag_rejected_by = outputs.MAG_UNCALIBRATED
    state, reason = light_states(status)["mag"]
    assert state == "calibrating" and reason.startswith("uncalibrated") and "µT" in reason

    status.flags.at_rest = True
    status.sensors_enabled = {"gyr": True, "acc": False, "mag": False}
    states = light_states(status)
    assert states["acc"][0] == "off" and states["mag"][0] == "off"
    assert states["standstill"][0] == "still"
    status.sensors_enabled = {"gyr": False, "acc": False, "mag": True}
    assert light_states(status)["standstill"][0] == "off"


def test_no_data_is_grey_and_disturbed_is_never_green():
    states = light_states(FilterStatus(), has_data=False)
    assert {state for state, _ in states.values()} == {"no data"}
    green = STATE_COLORS["ok"]
    for state in ("acc disturbed", "mag disturbed", "calibrating", "off", "no data"):
        color = STATE_COLORS[state]
        assert not (color.green() > 1.5 * color.red() and color.green() > 1.5 * color.blue()), \
            state
    assert green.green() > 1.5 * green.red()


def test_lights_panel_shows_caption_and_tooltip(qtbot):
    panel = LightsPanel()
    qtbot.addWidget(panel)
    assert panel.states() == {"acc": "no data", "mag": "no data", "standstill": "no data"}
    panel.update_status(status_of(mag_rejected=True, mag_rejected_by=outputs.MAG_STRENGTH_GATE,
                                  mag_norm=80.0, mag_expected=50.0, mag_gate=5.0, at_rest=True,
                                  acc_norm=9.8, g=9.81, acc_gate=2.0))
    assert panel.states() == {"acc": "ok", "mag": "mag disturbed", "standstill": "still"}
    assert panel.lights["mag"].caption == "Mag disturbed"
    assert panel.lights["acc"].caption == "Acc OK"
    tooltip = panel.lights["mag"].toolTip()
    assert tooltip.startswith("Mag disturbed\nstrength gate fired") and "‖m‖ = 80.0 µT" in tooltip
    panel.update_status(FilterStatus(), has_data=True)
    assert panel.states()["acc"] == "no data"          # a NaN norm: no reading yet


# ---- controls ----------------------------------------------------------------------------------

@pytest.fixture
def controls(qtbot):
    sent: list[object] = []
    panel = FilterPanel(sent.append)
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


def test_estimator_reset_and_align(qtbot, controls):
    panel, sent = controls
    panel.estimator_combo.setCurrentIndex(panel.estimator_combo.findData("complementary"))
    assert sent[-1] == SetEstimator("complementary")
    qtbot.mouseClick(panel.reset_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent[-1] == ResetFilter()
    qtbot.mouseClick(panel.align_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent[-1] == AlignHeading()
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


def test_comparison_table_runs_the_chosen_estimator_with_three_errors(qtbot):
    sent: list[object] = []
    panel = ComparisonPanel(sent.append)
    qtbot.addWidget(panel)
    panel.show()
    names = ["gyr+acc+mag", "gyr+acc", "gyr+mag", "acc+mag", "gyr", "acc", "mag"]
    panel.update_comparisons([Comparison(name, None, rmse_deg=(i * 2.0, i * 1.5, 0.5),
                                         samples=100 if i else 10)
                              for i, name in enumerate(names)], "ekf")
    rows = panel.rows()
    assert len(rows) == 7
    assert rows[0] == ("gyr+acc+mag", "—", "—", "—")           # too little data yet
    assert rows[1] == ("gyr+acc", "2.0", "1.5", "0.5")
    assert "EKF (default preset)" in panel.caption.text()
    assert [panel.table.horizontalHeaderItem(c).text() for c in range(4)] == [
        "Sensors", "total (°)", "heading (°)", "inclination (°)"]
    panel.estimator_combo.setCurrentIndex(panel.estimator_combo.findData("course"))
    assert sent[-1] == SetComparisonsEnabled(True, "course")
    assert "course preset" in panel.caption.text()
    _click_checkbox(qtbot, panel.comparisons_checkbox)
    assert sent[-1] == SetComparisonsEnabled(False, "course")
    panel.update_comparisons([], "gyro")        # the engine's word, once the click is old
    assert panel.estimator() == "course"        # a fresh click wins


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


def test_transport_bar_sends_replay_commands_and_greys_out_when_live(qtbot):
    sent: list[object] = []
    bar = TransportBar(sent.append)
    qtbot.addWidget(bar)
    bar.show()
    assert not bar.play_button.isEnabled() and bar.position_label.text() == "live"
    bar.update_replay({"position_s": 5.0, "duration_s": 20.0, "speed": 1.0, "paused": False,
                       "loop": False})
    assert bar.play_button.isEnabled() and bar.play_button.text() == "Pause"
    assert bar.slider.value() == 2500
    assert bar.position_label.text() == "0:05.0 / 0:20.0"          # m:ss.s since the start
    assert sent == []                                 # showing the position sends nothing
    qtbot.mouseClick(bar.play_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent[-1] == ReplayControl(paused=True) and bar.play_button.text() == "Play"
    bar.speed_combo.activated.emit(bar.speed_combo.findData(10.0))
    assert sent[-1] == ReplayControl(speed=10.0)
    bar.speed_combo.activated.emit(bar.speed_combo.findData(0.0))
    assert sent[-1] == ReplayControl(speed=0.0)        # "max": as fast as possible
    _click_checkbox(qtbot, bar.loop_checkbox)
    assert sent[-1] == ReplayControl(loop=True)
    bar.slider.setValue(5000)                          # a click on the groove
    assert sent[-1] == ReplayControl(seek_s=10.0)
    # at the end the button offers Play again, which starts from the beginning
    bar.update_replay({"position_s": 20.0, "duration_s": 20.0, "speed": 1.0, "paused": False,
                       "loop": False, "finished": True})
    assert bar.play_button.text() == "Play"
    bar.toggle_paused()
    assert sent[-1] == ReplayControl(paused=False, seek_s=0.0)
    bar.update_replay(None, "connected from 192.168.1.23:5000")
    assert not bar.slider.isEnabled() and "connected" in bar.source_label.text()
    count = len(sent)
    bar.toggle_paused()                                # nothing to pause without a replay
    assert len(sent) == count


def test_position_text_is_minutes_and_seconds_since_the_start():
    assert position_text(5.0, 20.0) == "0:05.0 / 0:20.0"
    assert position_text(75.25, 166.0) == "1:15.2 / 2:46.0"
    assert position_text(3723.44, 3600.0 * 1.5) == "1:02:03.4 / 1:30:00.0"


def test_connection_panel_forwards_to_the_matlab_kit_and_shows_what_was_sent(qtbot):
    from app.engine.commands import SetForward
    from app.stream.forwarder import ForwardStatus

    sent: list[object] = []
    panel = ConnectionPanel(sent.append)
    qtbot.addWidget(panel)
    panel.show()
    health = StreamHealth(connection_state="connected", peer="192.168.1.23:51234", port=3400)
    panel.update_health(health)
    assert panel.forward_status.text() == "off" and panel.forward_button.text() == "Forward"

    panel.forward_field.setText("localhost")                 # no port: said, nothing sent
    qtbot.mouseClick(panel.forward_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent == [] and "port" in panel.forward_status.text()
    panel.forward_field.setText(":3401")
    qtbot.mouseClick(panel.forward_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent == [SetForward("127.0.0.1:3401")]

    health.forward = ForwardStatus("127.0.0.1:3401", state="connected", lines_forwarded=1200,
                                   dropped_full=3)
    panel.update_health(health)
    assert panel.forward_button.text() == "Stop"
    assert panel.forward_status.text() == "connected, 1200 lines sent, 3 dropped"
    qtbot.mouseClick(panel.forward_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent[-1] == SetForward(None)
    health.forward = None
    panel.update_health(health)
    assert panel.forward_button.text() == "Forward" and panel.forward_status.text() == "off"

    health.connection_state = "replaying"                    # a replay has no phone lines
    health.forward = ForwardStatus("127.0.0.1:3401", state="connected")
    panel.update_health(health)
    assert "live phone stream only" in panel.forward_status.text()
