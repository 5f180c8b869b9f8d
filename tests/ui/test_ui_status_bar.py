"""The status bar's message never runs into its permanent texts: it is cut with "…" to the
room they leave, whole in its tooltip and in currentMessage()."""

from __future__ import annotations

from PySide6 import QtWidgets

LONG = ("recording stopped: [Errno 28] No space left on device: '/home/student/OrientationLab/"
        "sessions/2026-12-04_101500/raw.txt' (the stream and the estimates go on) " * 2).strip()


def _shown(bar: QtWidgets.QStatusBar) -> str:
    """The text Qt paints (QStatusBar's own message, not the override's whole one)."""
    return QtWidgets.QStatusBar.currentMessage(bar)


def _first_permanent_left(window) -> int:
    return min(label.geometry().left() for label in
               (window.state_status, window.time_status, window.rates_status, window.fps_status))


def test_a_long_message_is_cut_before_the_permanent_texts_at_1280(make_window, fake_engine,
                                                                   qtbot):
    window = make_window(fake_engine)
    window.resize(1280, 720)
    window.show()
    window.rates_status.setText("ACC 100 Hz  GYR 100 Hz  MAG 50 Hz  ORI 100 Hz")
    qtbot.waitUntil(lambda: window.rates_status.geometry().width() > 200)
    bar = window.statusBar()
    bar.showMessage(LONG, 8000)
    shown = _shown(bar)
    assert shown.endswith("…") and len(shown) < len(LONG)
    assert bar.fontMetrics().horizontalAdvance(shown) < _first_permanent_left(window) - 6
    assert bar.currentMessage() == LONG and bar.toolTip() == LONG


def test_the_message_is_cut_again_when_the_room_changes_and_a_short_one_whole(
        make_window, fake_engine, qtbot):
    window = make_window(fake_engine)
    window.resize(1920, 1080)
    window.show()
    bar = window.statusBar()
    bar.showMessage(LONG, 8000)
    wide = _shown(bar)
    window.resize(1280, 720)
    qtbot.waitUntil(lambda: _shown(bar) != wide)
    assert len(_shown(bar)) < len(wide)
    assert bar.fontMetrics().horizontalAdvance(_shown(bar)) < _first_permanent_left(window) - 6
    bar.showMessage("filter reset", 4000)
    assert _shown(bar) == "filter reset" == bar.currentMessage()
    bar.clearMessage()
    assert bar.currentMessage() == "" and bar.toolTip() == ""
