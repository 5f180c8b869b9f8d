"""The main window with a fake engine: snapshots drive the widgets, actions send commands,
layout and switches persist, closing stops the engine."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.commands import (AlignHeading, ReplayControl, ResetFilter, SetComparisonsEnabled,
                                 SetEstimator, SetSensorEnabled)

from ui_helpers import make_snapshot


def _press(qtbot, window, sequence: str) -> None:
    """Type a key sequence into the active window (shortcuts only reach the active window)."""
    if QtWidgets.QApplication.activeWindow() is not window:
        window.activateWindow()
        qtbot.waitUntil(lambda: QtWidgets.QApplication.activeWindow() is window, timeout=2000)
    combination = QtGui.QKeySequence(sequence)[0]
    target = QtWidgets.QApplication.focusWidget() or window
    qtbot.keyClick(target, combination.key(), combination.keyboardModifiers())


def _feed(window, engine, count: int, start_s: float = 0.0) -> None:
    for seq in range(1, count + 1):
        engine.snapshots.append(make_snapshot(seq, start_s + 0.5 * (seq - 1)))
    for _ in range(count):
        window.tick()


def test_window_builds_offscreen_with_placeholders(make_window, fake_engine):
    window = make_window(fake_engine)
    assert window.own_view.gl_view is None and window.phone_view.gl_view is None
    assert "OWN" in window.own_view.placeholder.text()
    assert window.findChild(QtCore.QObject, "filter_dock") is window.filter_dock
    assert fake_engine.commands == []         # default settings: nothing to tell the engine


def test_snapshot_stream_drives_views_lights_plots_and_counters(make_window, fake_engine, qtbot):
    from app.ui.main_window import PANEL_INTERVAL_S
    window = make_window(fake_engine)
    window.show()
    _feed(window, fake_engine, 4)
    snapshot = make_snapshot(5, 2.0, acc_rejected=True, acc_norm=12.3, at_rest=True)
    snapshot.health.damaged = 17
    snapshot.health.warnings = ["ACC rate dropped to 20 Hz"]
    fake_engine.snapshots.append(snapshot)
    window.tick()
    # Text panels follow at their own pace, even when no new snapshot comes (the window's timer
    # ticks on).
    qtbot.waitUntil(lambda: "17 damaged" in window.connection.problems_label.text(),
                    timeout=int(1000 * PANEL_INTERVAL_S) + 2000)
    assert window.snapshots_received == 5
    np.testing.assert_allclose(window.own_view.quat, snapshot.own_quat)
    np.testing.assert_allclose(window.phone_view.quat, snapshot.phone_quat)
    assert "σ" in window.own_view.detail_label.text()          # from own_cov
    assert window.lights.states() == {"acc": "acc disturbed", "mag": "ok", "standstill": "still"}
    assert "12.30" in window.lights.lights["acc"].toolTip()
    assert window.plots.buffers["acc"].size == 250
    assert window.plots.x_range()[1] == pytest.approx(2.493)
    assert "17 damaged" in window.connection.problems_label.text()
    assert window.connection.address_text() == "192.168.1.10:3400"
    assert "connected from 192.168.1.23:51234" in window.state_status.text()
    assert window.time_status.text() == "t = 2.5 s"
    assert "ACC 100 Hz" in window.rates_status.text()
    assert window.statusBar().currentMessage() == "ACC rate dropped to 20 Hz"
    fake_engine.snapshots.append(make_snapshot(6, 2.5, phone_quat=None))
    window.tick()
    assert window.phone_view.quat is None
    assert "no ORI in this stream" in window.phone_view.no_data_text


def test_text_panels_follow_at_a_lower_rate_and_only_change_when_the_text_does(
        make_window, fake_engine, qtbot, monkeypatch):
    from app.ui.main_window import PANEL_INTERVAL_S
    window = make_window(fake_engine)
    window.show()
    _feed(window, fake_engine, 1)
    assert "3 out of order" in window.connection.problems_label.text()   # the first at once
    # Snapshots at display rate: the 3D views and plots take each one, the counters do not.
    for seq in range(2, 6):
        snapshot = make_snapshot(seq, 0.5 * (seq - 1))
        snapshot.health.out_of_order = 100 + seq
        fake_engine.snapshots.append(snapshot)
        window.tick()
        np.testing.assert_allclose(window.own_view.quat, snapshot.own_quat)
    assert window.plots.buffers["acc"].size == 5 * 50
    assert "3 out of order" in window.connection.problems_label.text()
    qtbot.waitUntil(lambda: "105 out of order" in window.connection.problems_label.text(),
                    timeout=int(1000 * PANEL_INTERVAL_S) + 2000)
    # The same text again does not touch the labels.
    calls = []
    original = QtWidgets.QLabel.setText
    monkeypatch.setattr(QtWidgets.QLabel, "setText",
                        lambda label, text: (calls.append(text), original(label, text)))
    refreshed = []
    refresh_panels = window.refresh_panels
    monkeypatch.setattr(window, "refresh_panels",
                        lambda: (refresh_panels(), refreshed.append(window.ticks)))
    repeat = make_snapshot(5, 2.0)
    repeat.health.out_of_order = 105
    fake_engine.snapshots.append(repeat)
    window.tick()
    qtbot.waitUntil(lambda: bool(refreshed), timeout=int(1000 * PANEL_INTERVAL_S) + 2000)
    assert window.snapshots_received == 6                   # the panels have shown the repeat
    assert not [text for text in calls if "out of order" in text or text.startswith("t = ")]


def test_frame_rate_counts_painted_frames_not_timer_ticks(make_window, fake_engine, qtbot):
    window = make_window(fake_engine)
    window.timer.stop()                         # ticks by hand only
    window.show()
    qtbot.waitExposed(window)

    quiet = [0]                                 # rounds in a row that painted nothing

    def settled() -> bool:                      # the empty plots painted, the layout settled:
        before = window.frames_painted          # ticks with nothing new paint nothing, three
        window.tick()                           # rounds in a row (a loaded machine delivers
        QtWidgets.QApplication.processEvents()  # the first paints late)
        quiet[0] = quiet[0] + 1 if before > 0 and window.frames_painted == before else 0
        return quiet[0] >= 3
    qtbot.waitUntil(settled, timeout=10000)
    painted, ticks = window.frames_painted, window.ticks
    for _ in range(5):                          # ticks with nothing new draw nothing
        window.tick()
    QtWidgets.QApplication.processEvents()
    assert window.frames_painted == painted and window.ticks == ticks + 5
    _feed(window, fake_engine, 1)               # new samples: one frame, however many paints
    qtbot.waitUntil(lambda: window.frames_painted == painted + 1, timeout=2000)
    qtbot.wait(50)          # a negative wait: the other widgets' paints are not more frames
    assert window.frames_painted == painted + 1
    assert window.frames_per_second() >= 1


def test_shortcuts_send_commands(make_window, fake_engine, qtbot):
    window = make_window(fake_engine)
    window.show()
    qtbot.waitExposed(window)
    _press(qtbot, window, "Ctrl+R")
    _press(qtbot, window, "Ctrl+H")
    _press(qtbot, window, "Ctrl+1")
    _press(qtbot, window, "Ctrl+2")
    _press(qtbot, window, "Ctrl+3")
    _press(qtbot, window, "Ctrl+3")
    assert fake_engine.commands == [ResetFilter(), AlignHeading(), SetSensorEnabled("gyr", False),
                                    SetSensorEnabled("acc", False), SetSensorEnabled("mag", False),
                                    SetSensorEnabled("mag", True)]


def test_space_pauses_plots_or_the_replay(make_window, fake_engine, qtbot):
    window = make_window(fake_engine)
    window.show()
    qtbot.waitExposed(window)
    _feed(window, fake_engine, 2)
    _press(qtbot, window, "Space")
    assert window.plots.paused
    frozen = window.plots.x_range()
    _feed(window, fake_engine, 3, start_s=10.0)
    assert window.plots.x_range() == pytest.approx(frozen)
    _press(qtbot, window, "Space")
    window.tick()
    assert not window.plots.paused
    assert window.plots.x_range()[1] == pytest.approx(11.493)
    # While replaying, Space is the replay's play/pause.
    snapshot = make_snapshot(9, 12.0)
    snapshot.replay = {"position_s": 3.0, "duration_s": 60.0, "speed": 1.0, "paused": False,
                       "loop": False}
    fake_engine.snapshots.append(snapshot)
    window.tick()
    _press(qtbot, window, "Space")
    assert fake_engine.commands[-1] == ReplayControl(paused=True)
    assert not window.plots.paused


def _change_everything(window) -> None:
    window.resize(1201, 655)
    window.plots.set_window_s(25)
    window.plots.set_current_group("error")
    window.controls.set_estimator("accmag")
    window.controls.sensor_checkboxes["gyr"].setChecked(False)
    window.controls.uncertainty_checkbox.setChecked(False)
    window.comparison.comparisons_checkbox.setChecked(False)
    window.filter_dock.hide()


def test_layout_persists_but_switches_start_at_their_defaults(make_window, fake_engine,
                                                              settings_file):
    from ui_helpers import FakeEngine
    window = make_window(fake_engine)
    window.show()
    _change_everything(window)
    window.close()
    assert fake_engine.stop_calls == 1

    second_engine = FakeEngine()
    again = make_window(second_engine)
    again.show()
    assert again.size() == QtCore.QSize(1201, 655)
    assert again.plots.window_s == 25 and again.plots.current_group() == "error"
    assert not again.controls.uncertainty_checkbox.isChecked()
    assert not again.own_view.uncertainty_visible
    assert not again.filter_dock.isVisible()
    # not remembered: the filter starts as the user expects it, silently nothing changed
    assert again.controls.estimator() == "ekf"
    assert all(box.isChecked() for box in again.controls.sensor_checkboxes.values())
    assert second_engine.commands == []
    assert settings_file.exists()


def test_remember_my_set_up_restores_the_switches_as_commands(make_window, fake_engine):
    from ui_helpers import FakeEngine
    window = make_window(fake_engine)
    window.show()
    window.remember_action.trigger()
    assert window.remember_action.isChecked()
    assert "restored at the next start" in window.statusBar().currentMessage()
    _change_everything(window)
    window.close()
    second_engine = FakeEngine()
    again = make_window(second_engine)
    assert again.remember_action.isChecked()
    assert again.controls.estimator() == "accmag"
    assert not again.controls.sensor_checkboxes["gyr"].isChecked()
    assert SetEstimator("accmag") in second_engine.commands
    assert SetSensorEnabled("gyr", False) in second_engine.commands
    assert SetComparisonsEnabled(False, "ekf") in second_engine.commands


def test_menu_items_show_their_state_and_the_status_bar_confirms(make_window, fake_engine, qtbot):
    window = make_window(fake_engine)
    window.show()
    assert all(action.isCheckable() and action.isChecked()
               for action in window.sensor_actions.values())
    window.sensor_actions["mag"].trigger()
    assert not window.sensor_actions["mag"].isChecked()
    assert not window.controls.sensor_checkboxes["mag"].isChecked()
    assert fake_engine.commands[-1] == SetSensorEnabled("mag", False)
    assert window.statusBar().currentMessage() == "magnetometer out of the filter"
    window.controls.sensor_checkboxes["mag"].setChecked(True)      # the switch drives the menu
    assert window.sensor_actions["mag"].isChecked()
    window.estimator_actions["gyro"].trigger()
    assert fake_engine.commands[-1] == SetEstimator("gyro")
    assert window.controls.estimator() == "gyro" and window.estimator_actions["gyro"].isChecked()
    window.align_action.trigger()
    assert fake_engine.commands[-1] == AlignHeading()
    assert "aligning" in window.statusBar().currentMessage()
    window.link_cameras_action.trigger()
    assert window.link_cameras_action.isChecked() and "linked" in window.statusBar().currentMessage()
    window.unwrap_action.trigger()
    assert window.plots.unwrapped and window.plots.unwrap_checkbox.isChecked()


def test_named_layouts_save_apply_delete_and_reset_to_defaults(make_window, fake_engine):
    window = make_window(fake_engine)
    window.show()
    window.plots.set_current_group("orientation")
    window.connection_dock.hide()
    window.save_layout_as("lecture")
    assert window.layouts.names() == ["lecture"]
    window.reset_to_defaults()
    assert window.connection_dock.isVisible() and window.plots.current_group() == "sensors"
    window.controls.set_estimator("gyro")
    window.reset_to_defaults()
    assert window.controls.estimator() == "ekf"
    window.apply_layout("lecture")
    assert not window.connection_dock.isVisible()
    assert window.plots.current_group() == "orientation"
    window.delete_layout("lecture")
    assert window.layouts.names() == []


def test_the_first_start_fits_the_screen(make_window, fake_engine, monkeypatch):
    from PySide6 import QtGui as Gui
    screen = Gui.QGuiApplication.primaryScreen()
    monkeypatch.setattr(type(screen), "availableGeometry",
                        lambda self: QtCore.QRect(0, 0, 1280, 680))
    window = make_window(fake_engine)
    assert window.width() <= 1280 and window.height() <= 680
    assert window.height() >= 600


def test_close_stops_the_engine_once(make_window, fake_engine):
    window = make_window(fake_engine)
    window.close()
    window.shutdown()
    assert fake_engine.stop_calls == 1
    assert not window.timer.isActive()


def test_about_names_the_versions(make_window, fake_engine):
    import pyqtgraph
    import PySide6

    import app
    text = make_window(fake_engine).about_text()
    for version in (app.__version__, PySide6.__version__, pyqtgraph.__version__, np.__version__,
                    QtCore.qVersion()):
        assert version in text
    assert "Python 3." in text


def test_the_timer_polls_the_engine(make_window, fake_engine, qtbot):
    window = make_window(fake_engine)
    fake_engine.snapshots.extend(make_snapshot(seq, 0.5 * seq) for seq in range(1, 4))
    qtbot.waitUntil(lambda: window.snapshots_received == 3, timeout=2000)
    assert not fake_engine.snapshots


def test_while_the_engine_prepares_its_kernels_the_views_say_so(make_window, fake_engine):
    from app.engine.snapshot import Snapshot
    window = make_window(fake_engine)
    fake_engine.snapshots.append(Snapshot(seq=1, preparing=True))
    window.tick()
    assert window.own_view.no_data_text.startswith("preparing the filter")
    assert window.phone_view.no_data_text.startswith("preparing the filter")
    fake_engine.snapshots.append(Snapshot(seq=2))
    window.tick()
    assert window.own_view.no_data_text == "waiting for data"
