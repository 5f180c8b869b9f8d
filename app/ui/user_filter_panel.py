"""The YOURS panel: your own filter as the engine runs it, and the buttons to load one.

Shows the file or MATLAB folder (name and content hash), what it is doing (running / paused / catching up /
failed to load), its three lights as the course kit's (setAccDist, setMagDist, setStandStill;
"no data" where the filter does not report one), its time per sample (and, when it cannot keep up,
how much of the stream it got), its error against PHONE, the course steps not written yet, and
a problem with file, line and message, the traceback on demand and a copy button.

Draws snapshots and sends commands only: ``send`` is the window's ``engine.send``.
Mount: ``panel = UserFilterPanel(window.send, settings=window.settings)``; each frame
``panel.update_status(snapshot.user)``; File -> Load filter... calls
``load_filter_dialog(window, window.send)``. A MATLAB filter (a folder of .m files) runs in GNU
Octave: the panel says which one, or how to install it, and its Octave… button chooses another
(kept in the window's settings under OCTAVE_KEY; ``--octave`` wins for its session).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.commands import LoadUserFilter, UnloadUserFilter
from app.engine.snapshot import UserFilterStatus
from app.engine.userfilter.matlab_template import write_matlab_template
from app.engine.userfilter.octave import (OctaveNotFound, chosen_octave, filter_folder,
                                          find_octave, is_matlab_filter,
                                          use_octave)
from app.engine.userfilter.template import write_template
from app.ui.lights import Light

Send = Callable[[object], None]
FILE_FILTER = "Python filter (*.py)"
LOAD_FILTER = "Your filter: Python, or any .m file of a MATLAB folder (*.py *.m)"
OCTAVE_KEY = "your_filter/octave"        # the window's setting: the octave-cli chosen
PROBLEM_CHARACTERS = 240     # a longer message is cut in the panel (whole in the traceback)
STATE_COLOURS = {"running": "#2a9d4a", "paused": "#d9412e", "catching up": "#c98a00",
                 "failed to load": "#d9412e", "loading": "#c98a00"}
PRINTED_LINES = 3              # of what your filter printed, under its numbers


def load_filter_dialog(parent: QtWidgets.QWidget | None, send: Send,
                       directory: str = "") -> str | None:
    """Ask for a filter file (a .py, or any .m file of a MATLAB filter's folder) and send
    LoadUserFilter; the chosen path (the folder for a .m file; None: cancelled)."""
    path, _ = QtWidgets.QFileDialog.getOpenFileName(parent, "Load your filter", directory,
                                                    LOAD_FILTER)
    if not path:
        return None
    if is_matlab_filter(path):
        path = str(filter_folder(path))
    send(LoadUserFilter(path))
    return path


def new_matlab_filter_dialog(parent: QtWidgets.QWidget | None, send: Send,
                             directory: str = "") -> tuple[str | None, str]:
    """Ask for a new folder, write the course's MATLAB functions into it (never over a file)
    and load it. Returns (folder or None, what happened)."""
    path, _ = QtWidgets.QFileDialog.getSaveFileName(
        parent, "New MATLAB filter: a folder of the course's functions",
        str(Path(directory) / "my_filter"), "Folder (*)",
        options=QtWidgets.QFileDialog.Option.DontConfirmOverwrite)
    if not path:
        return None, ""
    try:
        folder = write_matlab_template(path)
    except (FileExistsError, NotADirectoryError) as error:
        return None, f"{error}: not overwritten (Load it instead)"
    except OSError as error:
        return None, f"cannot write {path}: {error.strerror or error}"
    send(LoadUserFilter(str(folder)))
    return str(folder), (f"wrote the course's functions to {folder.name}: open them in your "
                         "editor (its README.md says what to write); they run in GNU Octave")


def new_filter_dialog(parent: QtWidgets.QWidget | None, send: Send,
                      directory: str = "") -> tuple[str | None, str]:
    """Ask where to write the template, write it (never over an existing file) and load it.
    Returns (path or None, what happened)."""
    path, _ = QtWidgets.QFileDialog.getSaveFileName(
        parent, "New filter from the template", str(Path(directory) / "my_filter.py"),
        FILE_FILTER, options=QtWidgets.QFileDialog.Option.DontConfirmOverwrite)
    if not path:
        return None, ""
    if not path.lower().endswith(".py"):
        path += ".py"
    try:
        write_template(path)
    except FileExistsError:
        return None, f"{Path(path).name} exists already: not overwritten (Load it instead)"
    except OSError as error:
        return None, f"cannot write {path}: {error.strerror or error}"
    send(LoadUserFilter(path))
    return path, f"wrote {Path(path).name} from the template: open it in your editor"


def _light_state(value: bool | None, disturbed: str, calm: str, key: str) -> tuple[str, str]:
    if value is None:
        return "no data", (f"your filter does not report this light (return \"{key}\" from "
                           "step to show it)")
    return (disturbed, "your filter says so") if value else (calm, "your filter says so")


def _degrees(value: float) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.1f}°"


class UserFilterPanel(QtWidgets.QGroupBox):
    """Your filter (YOURS): status, lights, problem, and Load / New / Unload buttons."""

    def __init__(self, send: Send, parent: QtWidgets.QWidget | None = None,
                 settings: QtCore.QSettings | None = None) -> None:
        super().__init__("", parent)        # the dock's title says "Your filter"
        self.setFlat(True)
        self.setObjectName("user_filter_panel")
        self.send = send
        self.settings = settings
        self.status: UserFilterStatus | None = None
        if chosen_octave() is None and settings is not None and settings.value(OCTAVE_KEY):
            use_octave(str(settings.value(OCTAVE_KEY)))     # --octave wins for this session
        layout = QtWidgets.QVBoxLayout(self)
        self.file_label = QtWidgets.QLabel("no filter loaded")
        self.file_label.setWordWrap(True)
        self.file_label.setTextInteractionFlags(QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        self.state_label = QtWidgets.QLabel("")
        header = QtWidgets.QHBoxLayout()
        header.addWidget(self.file_label, 1)
        header.addWidget(self.state_label)
        layout.addLayout(header)
        layout.addLayout(self._buttons())
        # a problem first: it is what the panel has to say then (the dock is short on a
        # 720-pixel screen)
        layout.addWidget(self._problem_box())
        self.lights = {"acc": Light("Acc", compact=True), "mag": Light("Mag", compact=True),
                       "standstill": Light("Standstill", compact=True)}
        row = QtWidgets.QHBoxLayout()
        for light in self.lights.values():
            row.addWidget(light)
        layout.addLayout(row)
        self.speed_label = QtWidgets.QLabel("")
        self.error_label = QtWidgets.QLabel("")
        self.missing_label = QtWidgets.QLabel("")
        self.message_label = QtWidgets.QLabel("")
        self.action_label = QtWidgets.QLabel("")     # what this panel's own buttons did
        for label in (self.speed_label, self.error_label, self.missing_label, self.message_label,
                      self.action_label):
            label.setWordWrap(True)
            layout.addWidget(label)
        self.printed_label = QtWidgets.QLabel("")     # the last lines your filter printed
        self.printed_label.setFont(QtGui.QFontDatabase.systemFont(
            QtGui.QFontDatabase.SystemFont.FixedFont))
        self.printed_label.setTextFormat(QtCore.Qt.TextFormat.PlainText)
        self.printed_label.setTextInteractionFlags(
            QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        layout.addWidget(self.printed_label)
        layout.addLayout(self._octave_row())
        layout.addStretch(1)
        self.update_status(None)

    def _buttons(self) -> QtWidgets.QHBoxLayout:
        row = QtWidgets.QHBoxLayout()
        self.load_button = QtWidgets.QPushButton("Load…")
        self.load_button.setToolTip("Run a filter file of yours beside ours (File → Load filter…)")
        self.load_button.clicked.connect(lambda: load_filter_dialog(self, self.send))
        self.new_button = QtWidgets.QPushButton("New…")
        self.new_button.setToolTip("Write the course template (tu_qw, mu_g, mu_m, "
                                   "mu_normalizeQ as stubs), in Python or MATLAB, and run it")
        menu = QtWidgets.QMenu(self.new_button)
        self.new_python_action = menu.addAction("Python file…", self._new)
        self.new_matlab_action = menu.addAction("MATLAB folder (runs in GNU Octave)…",
                                                self._new_matlab)
        self.new_button.setMenu(menu)
        self.unload_button = QtWidgets.QPushButton("Unload")
        self.unload_button.clicked.connect(lambda: self.send(UnloadUserFilter()))
        for button in (self.load_button, self.new_button, self.unload_button):
            row.addWidget(button)
        row.addStretch(1)
        return row

    def _problem_box(self) -> QtWidgets.QWidget:
        box = QtWidgets.QWidget()
        layout = QtWidgets.QVBoxLayout(box)
        layout.setContentsMargins(0, 0, 0, 0)
        self.problem_label = QtWidgets.QLabel("")
        self.problem_label.setWordWrap(True)
        self.problem_label.setStyleSheet("color: #d9412e;")
        self.problem_label.setTextInteractionFlags(
            QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        buttons = QtWidgets.QHBoxLayout()
        self.details_button = QtWidgets.QPushButton("Show traceback")
        self.details_button.setCheckable(True)
        self.details_button.toggled.connect(self._show_details)
        self.copy_button = QtWidgets.QPushButton("Copy")
        self.copy_button.clicked.connect(self.copy_problem)
        buttons.addWidget(self.details_button)
        buttons.addWidget(self.copy_button)
        buttons.addStretch(1)
        self.details = QtWidgets.QPlainTextEdit()
        self.details.setReadOnly(True)
        self.details.setMinimumHeight(140)
        self.details.setFont(QtGui.QFontDatabase.systemFont(
            QtGui.QFontDatabase.SystemFont.FixedFont))
        self.details.setVisible(False)
        layout.addWidget(self.problem_label)
        layout.addLayout(buttons)
        layout.addWidget(self.details)
        self.problem_box = box
        return box

    def _octave_row(self) -> QtWidgets.QHBoxLayout:
        row = QtWidgets.QHBoxLayout()
        self.octave_label = QtWidgets.QLabel("")
        self.octave_label.setWordWrap(True)
        self.octave_button = QtWidgets.QPushButton("Octave…")
        self.octave_button.setToolTip("Choose GNU Octave's octave-cli, which runs a MATLAB filter "
                                      "(a folder of .m files); found on PATH otherwise")
        self.octave_button.clicked.connect(self._choose_octave)
        row.addWidget(self.octave_label, 1)
        row.addWidget(self.octave_button)
        self.show_octave()
        return row

    def show_octave(self) -> None:
        """Say which Octave a MATLAB filter runs in, or how to install one."""
        try:
            text = f"MATLAB filters run in {find_octave()}"
        except OctaveNotFound as error:
            text = f"MATLAB filters: {error}"
        self._set(self.octave_label, text)

    # -- actions --------------------------------------------------------------------------------

    def _new(self) -> None:
        _, text = new_filter_dialog(self, self.send)
        if text:
            self.action_label.setText(text)

    def _new_matlab(self) -> None:
        _, text = new_matlab_filter_dialog(self, self.send)
        if text:
            self.action_label.setText(text)

    def _choose_octave(self) -> None:
        path, _ = QtWidgets.QFileDialog.getOpenFileName(self, "GNU Octave's octave-cli",
                                                        str(chosen_octave() or ""))
        if path:
            self.set_octave(path)

    def set_octave(self, path: str) -> None:
        """Run MATLAB filters in this octave-cli from now on (kept in the window's settings);
        a MATLAB filter loaded now starts again in it."""
        try:
            found = find_octave(path)
        except OctaveNotFound as error:
            self.action_label.setText(str(error))
            return
        use_octave(found)
        if self.settings is not None:
            self.settings.setValue(OCTAVE_KEY, str(found))
        self.show_octave()
        self.action_label.setText(f"MATLAB filters run in {found} from now on")
        status = self.status
        if status is not None and is_matlab_filter(status.path):
            self.send(LoadUserFilter(status.path))

    def _show_details(self, shown: bool) -> None:
        self.details.setVisible(shown)
        self.details_button.setText("Hide traceback" if shown else "Show traceback")

    def copy_problem(self) -> None:
        problem = self.status.problem if self.status is not None else None
        if problem is not None:
            QtWidgets.QApplication.clipboard().setText(
                f"{problem.message}\n\n{problem.details}".rstrip() + "\n")

    # -- drawing --------------------------------------------------------------------------------

    def update_status(self, status: UserFilterStatus | None) -> None:
        """Show one snapshot's UserFilterStatus (None: no filter loaded)."""
        self.status = status
        self.unload_button.setEnabled(status is not None)
        if status is None:
            self._set(self.file_label, "no filter loaded: Load… one of yours, or start from "
                                       "the course template with New…")
            self._set(self.state_label, "")
            for label in (self.speed_label, self.error_label, self.missing_label,
                          self.printed_label):
                self._set(label, "")
            for light in self.lights.values():
                light.set_state("off", "no filter loaded")
            self.problem_box.setVisible(False)
            return
        digest = f" ({status.sha256[:8]})" if status.sha256 else ""
        self._set(self.file_label, f"<b>{status.name}</b>{digest}")
        self.file_label.setToolTip(status.path)
        state = status.state
        if state == "catching up" and status.progress is not None:
            state = f"catching up {status.progress:.0%}"
        colour = STATE_COLOURS.get(status.state, "gray")
        self._set(self.state_label, f"<span style='color:{colour}'><b>{state}</b></span>")
        self._update_lights(status)
        self._update_numbers(status)
        self._update_problem(status)

    def _update_lights(self, status: UserFilterStatus) -> None:
        states = {"acc": _light_state(status.acc_disturbed, "acc disturbed", "ok",
                                      "acc_disturbed"),
                  "mag": _light_state(status.mag_disturbed, "mag disturbed", "ok",
                                      "mag_disturbed"),
                  "standstill": _light_state(status.standstill, "still", "moving",
                                             "standstill")}
        for name, (state, reason) in states.items():
            self.lights[name].set_state(state, reason)

    def _update_numbers(self, status: UserFilterStatus) -> None:
        per = status.time_per_sample_s
        speed = "" if not math.isfinite(per) else (
            f"{per * 1e6:.0f} µs per sample" if per < 1e-3 else f"{per * 1e3:.1f} ms per sample")
        lag = status.lag_s
        if speed and math.isfinite(lag) and status.state == "running":
            speed += f", {lag * 1e3:.0f} ms behind OWN"
        if status.slow:
            speed = (f"<span style='color:#d9412e'>too slow for the stream: {speed}, so only "
                     f"{status.used_fraction:.0%} of the samples are used (decimated)</span>")
        self._set(self.speed_label, speed)
        self._set(self.error_label, f"to PHONE {_degrees(status.angle_to_phone_deg)}, "
                                    f"RMSE {_degrees(status.rmse_deg)}")
        missing = ", ".join(status.missing_steps)
        lines = [f"Not written yet (skipped): {missing}"] if missing else []
        lines += status.notes
        self._set(self.missing_label, "\n".join(lines))
        self._set(self.message_label, status.message)
        self._set(self.printed_label, "\n".join(status.printed[-PRINTED_LINES:]))
        self.printed_label.setToolTip("\n".join(status.printed))

    def _update_problem(self, status: UserFilterStatus) -> None:
        problem = status.problem
        self.problem_box.setVisible(problem is not None)
        if problem is None:
            return
        then = ("fix it and save the file: it loads again by itself" if problem.kind == "load"
                else "paused until you save the file again; everything else goes on")
        message = problem.message
        if len(message) > PROBLEM_CHARACTERS:      # the whole of it: Show traceback, Copy
            message = message[:PROBLEM_CHARACTERS].rstrip() + "… (Show traceback: all of it)"
        self._set(self.problem_label, f"{message}\n({then})")
        self.problem_label.setToolTip(problem.message)
        if self.details.toPlainText() != problem.details:
            self.details.setPlainText(problem.details)

    @staticmethod
    def _set(label: QtWidgets.QLabel, text: str) -> None:
        if label.text() != text:
            label.setText(text)
