"""The window and the engine's configuration (issue 51): what of a replayed recording is yours
in one line, the way back to it, and nothing kept of its own."""

from __future__ import annotations

import dataclasses

from ui_helpers import make_snapshot

import ekf
from app.engine.commands import SetFollowTimeline
from app.engine.processing.configuration import Config, ConfigurationView, Setup, summary_line

TUNED = dataclasses.replace(ekf.PRESETS["default"], acc_gate=0.7)


def _view(version: int, overridden: tuple[str, ...], replaying: bool = True,
          recorded: bool = True) -> ConfigurationView:
    return ConfigurationView(version, replaying, recorded, Setup(settings=TUNED),
                             Config(settings=TUNED), overridden, 0,
                             summary_line(overridden, 0), "/tmp/raw.txt")


def test_the_filter_dock_says_what_is_yours_and_offers_the_way_back(make_window, fake_engine,
                                                                    qtbot):
    window = make_window(fake_engine)
    window.show()
    controls = window.controls
    assert not controls.configuration_row.isVisible()           # no replayed recording
    snapshot = make_snapshot(1, 0.0, settings=TUNED)
    snapshot.configuration = _view(1, ())
    window.apply_snapshot(snapshot)
    assert controls.configuration_row.isVisible()
    assert controls.configuration_label.text() == "Replay: everything as recorded"
    assert not controls.follow_button.isEnabled()
    assert not window.follow_recording_action.isEnabled()
    snapshot = make_snapshot(2, 0.5, settings=TUNED)
    snapshot.configuration = _view(2, ("settings",))
    window.apply_snapshot(snapshot)
    assert controls.configuration_label.text() == \
        "Replay: settings: yours; switches, estimator, combinations: recorded"
    assert controls.follow_button.isEnabled() and window.follow_recording_action.isEnabled()
    controls.follow_button.click()
    window.follow_recording_action.trigger()
    assert fake_engine.commands_of(SetFollowTimeline) == [SetFollowTimeline(True)] * 2
    snapshot = make_snapshot(3, 1.0, settings=TUNED)
    snapshot.configuration = _view(3, ("settings",), replaying=False, recorded=False)
    window.apply_snapshot(snapshot)                                # live: nothing to go back to
    assert not controls.configuration_row.isVisible()
    assert not window.follow_recording_action.isEnabled()


def test_tune_takes_the_configuration_from_the_snapshot(make_window, fake_engine):
    window = make_window(fake_engine)
    snapshot = make_snapshot(1, 0.0, settings=TUNED)
    snapshot.configuration = _view(1, ("settings",))
    window.apply_snapshot(snapshot)
    assert window.tune.configuration is snapshot.configuration
    assert window.tune.settings_panel.settings is TUNED and window.filter_settings is TUNED


def test_the_filter_dock_makes_room_for_the_replay_line_at_1280x720(make_window, fake_engine,
                                                                    qtbot):
    """The line and its button appear once a replayed recording is overridden: the Filter
    dock grows to show them whole (it was left scrolling, the line cut in half)."""
    from PySide6 import QtWidgets
    from clipping import clipped, scrolls
    window = make_window(fake_engine)
    window.resize(1280, 720)
    window.arrange_default_layout()
    window.show()
    scroll = window.filter_dock.widget()
    qtbot.waitUntil(lambda: not scrolls(scroll), timeout=2000)
    snapshot = make_snapshot(1, 0.5, settings=TUNED)
    snapshot.configuration = _view(1, ("settings",))
    window.apply_snapshot(snapshot)
    QtWidgets.QApplication.processEvents()
    assert window.controls.configuration_row.isVisibleTo(window)
    qtbot.waitUntil(lambda: not scrolls(scroll), timeout=2000)
    cut = [finding for finding in clipped(window, whole=(scroll,)) if "filter_dock" in finding
           or "configuration_summary" in finding or "Back to the recording" in finding]
    assert cut == []
