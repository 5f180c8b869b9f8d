"""The YOURS panel: what your filter is doing, its lights and problem (traceback on demand), and
the Load / New / Unload buttons that send the engine's commands."""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtWidgets

from app.engine.commands import LoadUserFilter, UnloadUserFilter
from app.engine.snapshot import UserFilterStatus, UserProblem
from app.ui.user_filter_panel import UserFilterPanel

CLICK = QtCore.Qt.MouseButton.LeftButton


def _panel(qtbot):
    sent = []
    panel = UserFilterPanel(sent.append)
    qtbot.addWidget(panel)
    panel.show()
    return panel, sent


def _running(**changes) -> UserFilterStatus:
    status = UserFilterStatus(name="mine.py", path="/home/me/mine.py", sha256="ab12cd34ef",
                              state="running", quat=np.array([1.0, 0, 0, 0]),
                              acc_disturbed=True, mag_disturbed=False, standstill=None,
                              missing_steps=["mu_m (mine.py:88)"], time_per_sample_s=42e-6,
                              angle_to_phone_deg=3.25, rmse_deg=4.5, message="loaded")
    for key, value in changes.items():
        setattr(status, key, value)
    return status


def test_nothing_loaded(qtbot):
    panel, _ = _panel(qtbot)
    assert "no filter loaded" in panel.file_label.text()
    assert not panel.unload_button.isEnabled() and not panel.problem_box.isVisible()
    assert {name: light.state for name, light in panel.lights.items()} == {
        "acc": "off", "mag": "off", "standstill": "off"}


def test_a_running_filter(qtbot):
    panel, _ = _panel(qtbot)
    panel.update_status(_running())
    assert "mine.py" in panel.file_label.text() and "ab12cd34" in panel.file_label.text()
    assert "running" in panel.state_label.text()
    assert panel.lights["acc"].state == "acc disturbed" and panel.lights["mag"].state == "ok"
    assert panel.lights["standstill"].state == "no data"        # not reported by this filter
    assert "does not report this light" in panel.lights["standstill"].toolTip()
    assert panel.speed_label.text() == "42 µs per sample"
    assert panel.error_label.text() == "to PHONE 3.2°, RMSE 4.5°"
    assert "Not written yet (skipped): mu_m (mine.py:88)" in panel.missing_label.text()
    assert not panel.problem_box.isVisible() and panel.unload_button.isEnabled()


def test_its_lag_and_what_it_printed(qtbot):
    panel, _ = _panel(qtbot)
    printed = [f"line {k}" for k in range(20)]
    panel.update_status(_running(lag_s=0.012, printed=printed, printed_total=120))
    assert panel.speed_label.text() == "42 µs per sample, 12 ms behind OWN"
    assert panel.printed_label.text() == "line 17\nline 18\nline 19"
    assert panel.printed_label.toolTip() == "\n".join(printed)
    panel.update_status(_running(state="paused", lag_s=0.012))
    assert panel.speed_label.text() == "42 µs per sample" and panel.printed_label.text() == ""


def test_a_slow_filter_says_how_much_of_the_stream_it_gets(qtbot):
    panel, _ = _panel(qtbot)
    panel.update_status(_running(time_per_sample_s=3.1e-3, slow=True, used_fraction=0.22))
    text = panel.speed_label.text()
    assert "too slow" in text and "3.1 ms per sample" in text and "22%" in text


def test_a_paused_filter_shows_file_line_message_and_the_traceback_on_demand(qtbot):
    panel, _ = _panel(qtbot)
    problem = UserProblem("exception", "mine.py:61 in mu_g: ValueError: shapes (3,) (4,)",
                          "Traceback (most recent call last):\n  File \"mine.py\", line 61\n"
                          "ValueError: shapes (3,) (4,)\n", "/home/me/mine.py", 61, "mu_g", 2.5)
    panel.update_status(_running(state="paused", problem=problem))
    assert panel.problem_box.isVisible() and "paused" in panel.state_label.text()
    assert "mine.py:61 in mu_g: ValueError" in panel.problem_label.text()
    assert "save the file" in panel.problem_label.text()
    assert not panel.details.isVisible()
    qtbot.mouseClick(panel.details_button, CLICK)
    assert panel.details.isVisible() and "line 61" in panel.details.toPlainText()
    qtbot.mouseClick(panel.copy_button, CLICK)
    assert QtWidgets.QApplication.clipboard().text().startswith("mine.py:61 in mu_g")
    panel.update_status(_running())                               # saved and running again
    assert not panel.problem_box.isVisible()


def test_catching_up_shows_its_progress(qtbot):
    panel, _ = _panel(qtbot)
    panel.update_status(_running(state="catching up", progress=0.4))
    assert "catching up 40%" in panel.state_label.text()


def test_load_new_and_unload_send_commands(qtbot, tmp_path, monkeypatch):
    panel, sent = _panel(qtbot)
    chosen = tmp_path / "theirs.py"
    monkeypatch.setattr(QtWidgets.QFileDialog, "getOpenFileName",
                        lambda *args, **kwargs: (str(chosen), ""))
    qtbot.mouseClick(panel.load_button, CLICK)
    assert sent == [LoadUserFilter(str(chosen))]
    new = tmp_path / "mine"
    monkeypatch.setattr(QtWidgets.QFileDialog, "getSaveFileName",
                        lambda *args, **kwargs: (str(new), ""))
    panel.new_python_action.trigger()                            # New… > Python file…
    assert sent[-1] == LoadUserFilter(str(new) + ".py")
    assert "def tu_qw(x, P, omega, T, Rw):" in (tmp_path / "mine.py").read_text()
    (tmp_path / "mine.py").write_text("mine, keep")
    panel.new_python_action.trigger()                            # never overwritten
    assert (tmp_path / "mine.py").read_text() == "mine, keep" and len(sent) == 2
    assert "not overwritten" in panel.action_label.text()
    panel.update_status(_running())
    qtbot.mouseClick(panel.unload_button, CLICK)
    assert sent[-1] == UnloadUserFilter()


def test_a_matlab_filter_is_loaded_and_made_as_a_folder(qtbot, tmp_path, monkeypatch):
    panel, sent = _panel(qtbot)
    assert [a.text() for a in panel.new_button.menu().actions()] == [
        "Python file…", "MATLAB folder (runs in GNU Octave)…"]
    folder = tmp_path / "mine"
    monkeypatch.setattr(QtWidgets.QFileDialog, "getSaveFileName",
                        lambda *args, **kwargs: (str(folder), ""))
    panel.new_matlab_action.trigger()
    assert sent == [LoadUserFilter(str(folder))]
    assert (folder / "tu_qw.m").read_text().startswith(
        "function [x, P] = tu_qw(x, P, omega, T, Rw)")
    assert "README.md" in panel.action_label.text()
    (folder / "mu_g.m").write_text("% mine, keep")
    panel.new_matlab_action.trigger()                            # never overwritten
    assert (folder / "mu_g.m").read_text() == "% mine, keep" and len(sent) == 1
    assert "not overwritten" in panel.action_label.text()
    # Load…: any .m file of the folder loads the folder
    monkeypatch.setattr(QtWidgets.QFileDialog, "getOpenFileName",
                        lambda *args, **kwargs: (str(folder / "mu_m.m"), ""))
    qtbot.mouseClick(panel.load_button, CLICK)
    assert sent[-1] == LoadUserFilter(str(folder))


def test_the_octave_matlab_filters_run_in_is_shown_chosen_and_kept(qtbot, tmp_path, monkeypatch):
    from app.engine.userfilter import octave
    monkeypatch.setattr(octave, "_chosen", None)
    settings = QtCore.QSettings(str(tmp_path / "settings.ini"), QtCore.QSettings.Format.IniFormat)
    sent = []
    monkeypatch.setenv("PATH", str(tmp_path))                    # no Octave on PATH
    monkeypatch.setattr(octave, "_installed_elsewhere", lambda: [])
    panel = UserFilterPanel(sent.append, settings=settings)
    qtbot.addWidget(panel)
    assert panel.octave_label.text().startswith("MATLAB filters: GNU Octave is not installed")
    assert "install" in panel.octave_label.text()
    program = tmp_path / "octave-cli"
    program.write_text("#!/bin/sh\n")
    program.chmod(0o755)
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "tu_qw.m").write_text("% mine")
    panel.update_status(_running(name="mine", path=str(folder)))
    monkeypatch.setattr(QtWidgets.QFileDialog, "getOpenFileName",
                        lambda *args, **kwargs: (str(program), ""))
    qtbot.mouseClick(panel.octave_button, CLICK)
    assert panel.octave_label.text() == f"MATLAB filters run in {program}"
    assert settings.value("your_filter/octave") == str(program)
    assert octave.chosen_octave() == str(program)
    assert sent == [LoadUserFilter(str(folder))]                 # the MATLAB filter restarts in it
    panel.set_octave(str(tmp_path / "nothing"))
    assert "Octave not found at" in panel.action_label.text()
    assert octave.chosen_octave() == str(program)
    # the next window starts with the Octave chosen
    monkeypatch.setattr(octave, "_chosen", None)
    again = UserFilterPanel(sent.append, settings=settings)
    qtbot.addWidget(again)
    assert octave.chosen_octave() == str(program)
    octave.use_octave(None)
