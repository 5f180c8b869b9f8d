"""The window's sessions with pytest-qt: the transport bar's keys (Space, arrows, Shift, Ctrl,
Home/End), speed, a marker clicked on the slider, M and its label box, the record button and
its status, a recording that stops on an error, File → Open and drops (the --replay
resolution), and the whole session drawn in the plots."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.commands import (AddMarker, ReplayControl, SetMarkerLabel, StartRecording,
                                 StopRecording)
from app.engine.sessions.session import Marker
from app.engine.sessions.index import SessionPlot
from app.ui.transport import TransportBar

from ui_helpers import FakeEngine, make_chunk, make_snapshot


def _press(qtbot, window, sequence: str) -> None:
    if QtWidgets.QApplication.activeWindow() is not window:
        window.activateWindow()
        qtbot.waitUntil(lambda: QtWidgets.QApplication.activeWindow() is window, timeout=2000)
    combination = QtGui.QKeySequence(sequence)[0]
    target = QtWidgets.QApplication.focusWidget() or window
    qtbot.keyClick(target, combination.key(), combination.keyboardModifiers())


REPLAY = {"position_s": 5.0, "duration_s": 20.0, "speed": 1.0, "paused": True, "loop": False,
          "finished": False, "name": "session", "session_file": "/tmp/x/session.json",
          "following_timeline": True, "indexed": True}


def _replaying(window, engine, seq: int = 1, **changes):
    snapshot = make_snapshot(seq, 4.0)
    snapshot.replay = {**REPLAY, **changes}
    engine.snapshots.append(snapshot)
    window.tick()
    return snapshot


@pytest.fixture
def window(make_window, fake_engine, qtbot):
    window = make_window(fake_engine)
    window.show()
    qtbot.waitExposed(window)
    return window


def test_keys_drive_the_replay(window, fake_engine, qtbot):
    _replaying(window, fake_engine)
    sent = fake_engine.commands
    _press(qtbot, window, "Right")
    assert sent[-1] == ReplayControl(seek_s=6.0)
    _press(qtbot, window, "Shift+Right")
    assert sent[-1] == ReplayControl(seek_s=16.0)
    _press(qtbot, window, "Shift+Right")
    assert sent[-1] == ReplayControl(seek_s=20.0)              # clamped at the end
    _press(qtbot, window, "Left")
    assert sent[-1] == ReplayControl(seek_s=19.0)
    _press(qtbot, window, "Shift+Left")
    assert sent[-1] == ReplayControl(seek_s=9.0)
    _press(qtbot, window, "Home")
    assert sent[-1] == ReplayControl(seek_s=0.0)
    _press(qtbot, window, "End")
    assert sent[-1] == ReplayControl(seek_s=20.0)
    _press(qtbot, window, "Ctrl+Right")
    assert sent[-1] == ReplayControl(paused=True, step=1)       # one sample forward
    _press(qtbot, window, "Ctrl+Left")
    assert sent[-1] == ReplayControl(paused=True, step=-1)      # one sample back
    _replaying(window, fake_engine, 2, paused=False)
    _press(qtbot, window, "Space")
    assert sent[-1] == ReplayControl(paused=True)


def test_buttons_speed_and_timeline(window, fake_engine, qtbot):
    _replaying(window, fake_engine)
    bar = window.transport
    sent = fake_engine.commands
    qtbot.mouseClick(bar.step_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent[-1] == ReplayControl(paused=True, step=1)
    qtbot.mouseClick(bar.step_back_button, QtCore.Qt.MouseButton.LeftButton)
    assert sent[-1] == ReplayControl(paused=True, step=-1)
    bar.speed_combo.setFocus()
    for _ in range(bar.speed_combo.count()):                     # down to "max"
        qtbot.keyClick(bar.speed_combo, QtCore.Qt.Key.Key_Down)
    assert sent[-1] == ReplayControl(speed=0.0)
    bar.speed_combo.activated.emit(bar.speed_combo.findData(0.1))
    assert sent[-1] == ReplayControl(speed=0.1)
    assert bar.position_label.text() == "0:05.0 / 0:20.0"


def test_markers_on_the_slider_jump_when_clicked(window, fake_engine, qtbot):
    snapshot = make_snapshot(1, 4.0)
    snapshot.replay = dict(REPLAY)
    snapshot.markers = (Marker(1, 10_000, 10.0, "turn"), Marker(2, 15_000, 15.0))
    fake_engine.snapshots.append(snapshot)
    window.tick()
    slider = window.transport.slider
    assert [title for _, title in slider.markers] == ["1: turn", "2"]
    x = slider.marker_x(0.5)
    qtbot.mouseClick(slider, QtCore.Qt.MouseButton.LeftButton,
                     pos=QtCore.QPoint(x + 2, slider.height() // 2))
    assert fake_engine.commands[-1] == ReplayControl(seek_s=10.0)
    # a click away from the markers jumps to where it is
    qtbot.mouseClick(slider, QtCore.Qt.MouseButton.LeftButton,
                     pos=QtCore.QPoint(slider.marker_x(0.25), slider.height() // 2))
    command = fake_engine.commands[-1]
    assert isinstance(command, ReplayControl) and command.seek_s == pytest.approx(5.0, abs=0.3)
    # the plots draw them as labelled lines
    assert len(window.plots._marker_lines["acc"]) == 2


def test_m_drops_a_marker_and_asks_for_a_label(window, fake_engine, qtbot):
    _replaying(window, fake_engine)
    _press(qtbot, window, "M")
    assert fake_engine.commands[-1] == AddMarker()
    box = window.sessions.marker_box
    assert box.isVisible() and "Marker 1" in box.title.text()
    qtbot.keyClicks(box.field, "mm lift off")     # typing M (or arrows) in the box is text
    qtbot.keyClick(box.field, QtCore.Qt.Key.Key_Left)
    qtbot.keyClick(box.field, QtCore.Qt.Key.Key_Return)
    assert fake_engine.commands[-1] == SetMarkerLabel(1, "mm lift off") and not box.isVisible()
    assert len(fake_engine.commands_of(AddMarker)) == 1
    assert not fake_engine.commands_of(ReplayControl)
    _press(qtbot, window, "M")
    qtbot.keyClick(window.sessions.marker_box.field, QtCore.Qt.Key.Key_Escape)
    assert not window.sessions.marker_box.isVisible()
    assert fake_engine.commands_of(SetMarkerLabel) == [SetMarkerLabel(1, "mm lift off")]


def test_record_button_and_shortcut_show_the_recording(window, fake_engine, qtbot):
    bar = window.transport
    assert bar.record_button.isEnabled() and not bar.play_button.isEnabled()   # live
    qtbot.mouseClick(bar.record_button, QtCore.Qt.MouseButton.LeftButton)
    assert fake_engine.commands[-1] == StartRecording()
    snapshot = make_snapshot(1, 0.0)
    snapshot.recording = {"folder": "/data/sessions/2026-12-01_10-00-00", "elapsed_s": 72.4,
                          "bytes": 3 * 2**20, "lines": 12345, "error": None, "active": True}
    fake_engine.snapshots.append(snapshot)
    window.tick()
    assert bar.record_label.text() == "REC 1:12 · 3.0 MB · 12,345 lines"
    assert bar.record_button.isChecked() and bar.record_button.text() == "■ Stop"
    _press(qtbot, window, "Ctrl+Shift+R")
    assert fake_engine.commands[-1] == StopRecording()


def test_a_recording_that_stops_on_an_error_says_so(window, fake_engine):
    snapshot = make_snapshot(1, 0.0)
    snapshot.recording = {"folder": "/media/stick/s", "elapsed_s": 5.0, "bytes": 10,
                          "lines": 3, "error": "cannot write /media/stick/s/raw.txt: No space "
                                                "left on device", "active": False}
    fake_engine.snapshots.append(snapshot)
    window.tick()
    assert "No space left" in window.transport.record_label.text()
    assert "No space left" in window.sessions.last_message
    boxes = [w for w in QtWidgets.QApplication.topLevelWidgets()
             if w.objectName() == "session_message" and w.isVisible()]
    assert boxes and not boxes[0].isModal()
    for box in boxes:
        box.close()


def test_open_and_drop_use_the_replay_resolution(window, tmp_path, qtbot):
    opened: list[str] = []

    def factory(path: str):
        from app.engine.config import open_replay
        open_replay(path)                     # the one resolution: ConfigError for junk
        opened.append(path)
        return FakeEngine()

    window.sessions.engine_factory = factory
    junk = tmp_path / "notes.txt"
    junk.write_text("shopping list\nmilk\n")
    assert not window.sessions.open(str(junk))
    assert "notes.txt: not a phone log" in window.sessions.last_message
    assert "expected a recorded session folder" in window.sessions.last_message
    session = tmp_path / "rec"
    session.mkdir()
    (session / "raw.txt").write_text("1000\tACC\t0\t0\t9.81\n1010\tACC\t0\t0\t9.81\n")
    mime = QtCore.QMimeData()
    mime.setUrls([QtCore.QUrl.fromLocalFile(str(session))])
    drop = QtGui.QDropEvent(QtCore.QPointF(50, 50), QtCore.Qt.DropAction.CopyAction, mime,
                            QtCore.Qt.MouseButton.NoButton, QtCore.Qt.KeyboardModifier.NoModifier)
    window.dropEvent(drop)
    assert opened == [str(session)] and isinstance(window.engine, FakeEngine)
    assert window.engine.started and window.sessions.recent()[0] == session
    for widget in QtWidgets.QApplication.topLevelWidgets():
        if widget.objectName() == "session_message":
            widget.close()


def test_the_whole_session_is_drawn_when_paused(window, fake_engine):
    """A replay's whole session (the index's plot data) replaces the rolling buffers: paused,
    the user can look at any part of it."""
    plot = SessionPlot()
    for start in range(0, 600, 2):                     # 10 minutes at 100 Hz
        plot.add(make_chunk(float(start), count=200))
    plot.finish()
    snapshot = make_snapshot(1, 300.0)
    snapshot.replay = {**REPLAY, "duration_s": 600.0}
    snapshot.session_plot = plot
    fake_engine.snapshots.append(snapshot)
    window.tick()
    plots = window.plots
    assert plots.session is plot and len(plots.buffers["acc"].t) == 60_000
    assert plots.latest_time() == pytest.approx(300.5)           # follows the replay
    plots.set_paused(True)
    plots.set_x_range(10.0, 20.0)                                # far back, before the window
    plots.refresh()
    curve = next(c for spec, c in plots.curves if spec.stream == "acc" and spec.column == 0)
    x, _ = curve.getData()
    assert x[0] <= 10.01 and x[-1] >= 19.99
    assert np.shares_memory(plots.buffers["acc"].t, plot.streams["acc"][0])   # no copy


def test_transport_bar_alone_greys_out_replay_controls_but_not_recording(qtbot):
    sent: list[object] = []
    bar = TransportBar(sent.append)
    qtbot.addWidget(bar)
    bar.show()
    bar.update_replay(None, "connected from 192.168.1.23:5000")
    assert all(not w.isEnabled() for w in bar.replay_widgets)
    assert bar.record_button.isEnabled()
    bar.update_replay({**REPLAY, "indexed": False, "index_progress": 0.42})
    assert bar.source_label.text() == "indexing 42 %"


def test_dragging_the_slider_shows_where_it_is_before_the_release(window, fake_engine):
    snapshot = make_snapshot(1, 4.0)
    snapshot.replay = dict(REPLAY)
    fake_engine.snapshots.append(snapshot)
    window.tick()
    transport = window.transport
    before = transport.position_label.text()
    transport.slider.setSliderDown(True)              # (emits sliderPressed)
    transport.slider.setValue(transport.slider.maximum() // 2)
    assert transport.position_label.text() != before
    assert transport.position_label.text().startswith("0:10.0")     # half of 20 s
    again = make_snapshot(2, 4.1)
    again.replay = dict(REPLAY)
    fake_engine.snapshots.append(again)
    window.tick()                                    # the replay goes on: the label stays
    assert transport.position_label.text().startswith("0:10.0")
    commands = len(fake_engine.commands)
    transport.slider.setSliderDown(False)             # (emits sliderReleased): one seek
    assert fake_engine.commands[commands:] == [ReplayControl(seek_s=10.0)]


def test_ctrl_l_clears_the_plots_and_says_so(window, fake_engine, qtbot):
    fake_engine.snapshots.append(make_snapshot(1, 4.0))
    window.tick()
    window.clear_action.trigger()
    assert "plots cleared" in window.statusBar().currentMessage()


def _wheel_zoom(plots, key: str) -> None:
    """Turn the mouse wheel over a plot, as a user zooms it."""
    group = next(g for g in plots.groups.values() if key in g.plots)
    view_box = plots.plots[key].getViewBox()
    centre = view_box.sceneBoundingRect().center()
    viewport = group.graphics.viewport()
    pos = QtCore.QPointF(group.graphics.mapFromScene(centre))
    event = QtGui.QWheelEvent(pos, QtCore.QPointF(viewport.mapToGlobal(pos.toPoint())),
                              QtCore.QPoint(0, 0), QtCore.QPoint(0, 240),
                              QtCore.Qt.MouseButton.NoButton,
                              QtCore.Qt.KeyboardModifier.NoModifier,
                              QtCore.Qt.ScrollPhase.NoScrollPhase, False)
    QtWidgets.QApplication.sendEvent(viewport, event)


def _session_at(window, engine, seq: int, position_s: float, plot, paused: bool = False):
    snapshot = make_snapshot(seq, position_s)
    snapshot.t_ms, snapshot.t0_ms = int(position_s * 1000), 0
    snapshot.replay = {**REPLAY, "duration_s": 60.0, "position_s": position_s, "paused": paused}
    snapshot.session_plot = plot
    engine.snapshots.append(snapshot)
    window.tick()


def test_a_zoom_stops_following_visibly_and_home_then_play_follow_the_replay_again(
        window, fake_engine, qtbot):
    """Issue 51, item 3: after a zoom, Home and Play, the plot stayed at 52-54 s while the
    replay played at 8 s, with nothing but a "Paused" button to say why."""
    plot = SessionPlot()
    for start in range(0, 60, 2):
        plot.add(make_chunk(float(start), count=200))
    plot.finish()
    plots = window.plots
    _session_at(window, fake_engine, 1, 53.0, plot)
    assert plots.x_range()[1] == pytest.approx(53.0) and not plots.follow_note.isVisible()
    assert not plots.follow_button.isEnabled()               # following: nothing to resume
    _wheel_zoom(plots, "acc")
    assert plots.paused and plots.pause_reason == "zoomed"
    low, high = plots.x_range()
    assert high - low < plots.window_s                        # zoomed in
    note = plots.follow_note
    assert note.isVisible() and "not following (zoomed by hand)" in note.text()
    assert f"{low:.1f} – {high:.1f} s" in note.text()
    assert plots.follow_button.isEnabled()
    _press(qtbot, window, "Home")
    assert fake_engine.commands[-1] == ReplayControl(seek_s=0.0)
    _session_at(window, fake_engine, 2, 0.0, plot, paused=True)
    _press(qtbot, window, "Space")                            # Play
    assert fake_engine.commands[-1] == ReplayControl(paused=False)
    _session_at(window, fake_engine, 3, 8.0, plot)
    assert not plots.paused and not note.isVisible()
    assert plots.x_range() == pytest.approx((8.0 - plots.window_s, 8.0))


def test_a_seek_follows_again_but_a_step_keeps_the_zoom(window, fake_engine, qtbot):
    plot = SessionPlot()
    for start in range(0, 60, 2):
        plot.add(make_chunk(float(start), count=200))
    plot.finish()
    plots = window.plots
    _session_at(window, fake_engine, 1, 30.0, plot, paused=True)
    _wheel_zoom(plots, "gyr")
    zoomed = plots.x_range()
    _press(qtbot, window, "Ctrl+Right")                       # one sample: still inspecting
    assert fake_engine.commands[-1] == ReplayControl(paused=True, step=1)
    _session_at(window, fake_engine, 2, 30.01, plot, paused=True)
    assert plots.paused and plots.x_range() == pytest.approx(zoomed)
    _press(qtbot, window, "Right")                            # a jump: show where it went
    _session_at(window, fake_engine, 3, 31.0, plot, paused=True)
    assert not plots.paused and plots.x_range()[1] == pytest.approx(31.0)


def _recorded_session(folder, label=None):
    import json
    folder.mkdir(parents=True)
    (folder / "raw.txt").write_text("1000\tACC\t0\t0\t9.81\n1010\tACC\t0\t0\t9.81\n")
    data = {"format": 2, "app_version": "0.1.0", "timeline": []}
    if label is not None:
        data["label"] = label
    (folder / "session.json").write_text(json.dumps(data))
    return folder


def test_exports_are_named_after_the_session_not_raw_export(tmp_path):
    """Issue 51: File → Export suggested raw_export.* for every recorded session."""
    from app.ui.sessions import export_path
    plain = _recorded_session(tmp_path / "2026-12-01_10-00-00")
    assert export_path(plain / "raw.txt", "csv") == plain / "2026-12-01_10-00-00_export.csv"
    assert export_path(plain, "mat") == plain / "2026-12-01_10-00-00_export.mat"
    labelled = _recorded_session(tmp_path / "2026-12-02_09-30-00", label="Lab 2: rotation!")
    assert export_path(labelled / "session.json", "log") == \
        labelled / "Lab_2_rotation_2026-12-02_09-30-00_export.txt"
    log = tmp_path / "demo_session.txt.gz"
    assert export_path(log, "csv") == tmp_path / "demo_session_export.csv"
    assert export_path(tmp_path / "walk.txt", "csv") == tmp_path / "walk_export.csv"


def test_a_session_is_labelled_and_named_by_its_label(window, fake_engine, tmp_path):
    """Issue 51: sessions were named by their time stamp only."""
    import types

    from app.engine.sessions.session import read_session, session_label
    old = _recorded_session(tmp_path / "2026-12-01_10-00-00")          # no label: loads
    assert session_label(old) == "" and read_session(old / "session.json")
    replayed = types.SimpleNamespace(path=str(old / "raw.txt"), kind="replay", name="raw.txt")
    fake_engine.source = types.SimpleNamespace(**vars(replayed), played=lambda: replayed)
    controls = window.sessions
    assert controls.label_session("  Lab 2:\n rotation  ")
    assert session_label(old) == "Lab 2: rotation"
    assert read_session(old / "session.json").timeline == []          # the rest kept
    assert window.windowTitle() == "Orientation Lab — Lab 2: rotation (2026-12-01_10-00-00)"
    controls._fill_recent()
    texts = [a.text() for a in controls.recent_menu.actions()]
    assert texts[0] == "Lab 2: rotation (2026-12-01_10-00-00)"
    assert controls.recent_menu.actions()[0].toolTip() == str(old)
    assert controls.label_session("")                                   # removed again
    assert session_label(old) == ""
    walk = types.SimpleNamespace(path=str(tmp_path / "walk.txt"), kind="replay")
    fake_engine.source = types.SimpleNamespace(**vars(walk), played=lambda: walk)
    assert not controls.label_session("x")                              # a phone's own log
    assert "no session.json" in controls.last_message
    for widget in QtWidgets.QApplication.topLevelWidgets():
        if widget.objectName() == "session_message":
            widget.close()
