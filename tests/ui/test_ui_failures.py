"""An engine failure is shown: the message, the traceback on demand, a "Copy details" button."""

from __future__ import annotations

from PySide6 import QtCore, QtWidgets

from app.engine.errors import EngineFailure
from ui_helpers import make_snapshot


def _failure(number: int, fatal: bool = False) -> EngineFailure:
    return EngineFailure(number, "ZeroDivisionError: float division by zero (fast.py, line 12, "
                         "in _update)", "Traceback (most recent call last):\n  ...\n"
                         "ZeroDivisionError: float division by zero\n", "2026-12-01T10:00:00",
                         fatal)


def test_failure_dialog_shows_message_details_and_copies_them(qtbot, make_window, fake_engine):
    window = make_window(fake_engine)
    window.show()
    snapshot = make_snapshot(1, 0.0)
    snapshot.failures = [_failure(1)]
    fake_engine.snapshots.append(snapshot)
    window.tick()
    dialog = window.failure_dialog
    assert dialog.isVisible()
    assert "float division by zero" in dialog.message.text()
    assert "goes on" in dialog.outcome.text()
    assert not dialog.details.isVisible()
    qtbot.mouseClick(dialog.details_button, QtCore.Qt.MouseButton.LeftButton)
    assert dialog.details.isVisible()
    assert "Traceback (most recent call last)" in dialog.details.toPlainText()
    qtbot.mouseClick(dialog.copy_button, QtCore.Qt.MouseButton.LeftButton)
    copied = QtWidgets.QApplication.clipboard().text()
    assert copied.startswith("ZeroDivisionError") and "Traceback" in copied
    assert "engine error" in window.statusBar().currentMessage()


def test_the_same_failure_is_shown_once_and_a_fatal_one_says_the_engine_stopped(
        qtbot, make_window, fake_engine):
    window = make_window(fake_engine)
    window.show()
    first = make_snapshot(1, 0.0)
    first.failures = [_failure(1)]
    fake_engine.snapshots.append(first)
    window.tick()
    window.failure_dialog.hide()
    again = make_snapshot(2, 0.5)
    again.failures = [_failure(1)]
    fake_engine.snapshots.append(again)
    window.tick()
    assert not window.failure_dialog.isVisible()      # nothing new: not shown again
    fatal = make_snapshot(3, 1.0)
    fatal.failures = [_failure(1), _failure(2, fatal=True)]
    fake_engine.snapshots.append(fatal)
    window.tick()
    assert window.failure_dialog.isVisible()
    assert "engine stopped" in window.failure_dialog.outcome.text()
