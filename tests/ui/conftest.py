"""Fixtures for the widget tests: a fake engine fed with hand-built snapshots (ui_helpers)."""

from __future__ import annotations

from pathlib import Path

import pytest
from PySide6 import QtCore

from ui_helpers import FakeEngine

# Several windows in one test process each get 3D views; pyqtgraph compiles its shaders once,
# so their GL contexts must share (the application does the same in app/ui/main.py). This has
# to happen before pytest-qt creates the QApplication.
QtCore.QCoreApplication.setAttribute(QtCore.Qt.ApplicationAttribute.AA_ShareOpenGLContexts)

@pytest.fixture(autouse=True)
def _qt_garbage_collected_between_tests():
    """After each test (and after pytest-qt has closed its widgets): collect the Python garbage
    and run the deferred deletions now. Left to the garbage collector, a dropped window's menus
    were once destroyed in the middle of the next test's layout pass (shiboken's deletion in
    the main thread), where QObject's destructor waited forever on a mutex: CI hung."""
    yield
    import gc

    from PySide6 import QtWidgets
    gc.collect()
    if QtWidgets.QApplication.instance() is not None:
        QtCore.QCoreApplication.sendPostedEvents(None, QtCore.QEvent.Type.DeferredDelete)
        QtCore.QCoreApplication.processEvents()


@pytest.fixture(autouse=True)
def data_folder(tmp_path: Path, monkeypatch) -> Path:
    """Profiles and logs the window writes go to tmp_path, never the user's data folder."""
    folder = tmp_path / "data"
    monkeypatch.setenv("ORIENTATION_LAB_DATA", str(folder))
    return folder


@pytest.fixture
def fake_engine() -> FakeEngine:
    return FakeEngine()


@pytest.fixture
def settings_file(tmp_path: Path) -> Path:
    return tmp_path / "settings.ini"


@pytest.fixture
def make_window(qtbot, settings_file):
    """Build MainWindows on INI settings in tmp_path; each is closed at teardown."""
    from app.ui.main_window import MainWindow
    windows = []

    def build(engine, use_gl=False, path: Path | None = None):
        settings = QtCore.QSettings(str(path or settings_file), QtCore.QSettings.Format.IniFormat)
        window = MainWindow(engine, settings=settings, use_gl=use_gl)
        qtbot.addWidget(window)
        windows.append(window)
        return window

    yield build
    for window in windows:
        window.shutdown()
