"""The window's sessions: open (File → Open, recent sessions, a file dropped on the window),
record (a click or Ctrl+Shift+R), markers (M, with an optional label typed in a small box),
the replay keys, and exports (File → Export).

:class:`SessionControls` builds the File and Replay menus' actions on the main window and
follows the snapshots for what they show (recording errors, saved sessions for the recent
list). Opening a replay builds a new engine through the window's engine factory (the same
resolution as ``--replay``: app.engine.config.open_replay) and swaps it in.
"""

from __future__ import annotations

import re
import threading
from pathlib import Path
from typing import Any, Callable

from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.commands import AddMarker, SetMarkerLabel
from app.engine.config import ConfigError, open_replay
from app.engine.processing.configuration import replayed_setup
from app.engine.sessions.session import session_json_of, session_label, sessions_dir, write_label
from app.engine.snapshot import Snapshot

MAX_RECENT = 10
SHORTCUTS = {"record": "Ctrl+Shift+R", "marker": "M", "open": "Ctrl+O"}
REPLAY_KEYS = (("Back 1 s", "Left", ("jump_by", -1.0)), ("Forward 1 s", "Right", ("jump_by", 1.0)),
               ("Back 10 s", "Shift+Left", ("jump_by", -10.0)),
               ("Forward 10 s", "Shift+Right", ("jump_by", 10.0)),
               ("One sample back", "Ctrl+Left", ("step", -1)),
               ("One sample forward", "Ctrl+Right", ("step", 1)),
               ("To the start", "Home", ("seek_to", 0.0)),
               ("To the end", "End", ("seek_to", float("inf"))))


EXPORT_SUFFIXES = {"csv": ".csv", "log": ".txt", "mat": ".mat"}


def session_folder(path: str | Path) -> Path | None:
    """The recorded session a path names (its folder, raw.txt or session.json); None for a
    phone's own log."""
    found = session_json_of(path)
    return found.parent if found is not None else None


def session_title(path: str | Path) -> str:
    """How a session is named to the user: "label (2026-12-01_10-00-00)" for a labelled one,
    else its folder's (or the log's) name."""
    path = Path(path)
    folder = session_folder(path)
    if folder is None:
        return path.name
    label = session_label(folder)
    return f"{label} ({folder.name})" if label else folder.name


def _file_stem(text: str) -> str:
    """A label as part of a file name: letters, digits, - and _ (spaces become _)."""
    return re.sub(r"[^\w\-]+", "", re.sub(r"\s+", "_", text.strip()))[:60]


def export_path(source: str | Path, fmt: str) -> Path:
    """Where File → Export suggests writing: named after the session (its label and time
    stamp, or its folder; a log's own name), never raw_export.*; beside the session's files."""
    base = Path(source)
    suffix = EXPORT_SUFFIXES[fmt]
    folder = session_folder(base)
    if folder is not None:
        label = _file_stem(session_label(folder))
        stem = f"{label}_{folder.name}" if label else folder.name
        return folder / f"{stem}_export{suffix}"
    name = base.name
    for ending in (".txt.gz", ".gz", ".txt"):
        if name.lower().endswith(ending):
            name = name[:-len(ending)]
            break
    return base.parent / f"{name or 'session'}_export{suffix}"


def default_engine_factory(path: str):
    from app.engine.live.worker import Engine
    return Engine(open_replay(path))


def scipy_available() -> bool:
    try:
        import scipy.io  # noqa: F401
    except ImportError:
        return False
    return True


class MarkerLabelBox(QtWidgets.QFrame):
    """A small non-modal box for a marker's label: Enter saves it, Esc (or focus elsewhere)
    leaves the marker without one."""

    def __init__(self, parent: QtWidgets.QWidget, on_label: Callable[[int, str], None]) -> None:
        super().__init__(parent)
        self.setObjectName("marker_label_box")
        self.setFrameShape(QtWidgets.QFrame.Shape.StyledPanel)
        self.setAutoFillBackground(True)
        self._on_label = on_label
        self.marker_id = 0
        layout = QtWidgets.QHBoxLayout(self)
        layout.setContentsMargins(6, 4, 6, 4)
        self.title = QtWidgets.QLabel("")
        self.field = QtWidgets.QLineEdit()
        self.field.setPlaceholderText("label (Enter), Esc: none")
        self.field.setMinimumWidth(220)
        self.field.returnPressed.connect(self._save)
        layout.addWidget(self.title)
        layout.addWidget(self.field)
        QtGui.QShortcut(QtGui.QKeySequence("Esc"), self.field, self.hide,
                        context=QtCore.Qt.ShortcutContext.WidgetShortcut)
        self.hide()

    def ask(self, marker_id: int, where: str, anchor: QtCore.QPoint) -> None:
        self.marker_id = marker_id
        self.title.setText(f"Marker {marker_id} at {where}:")
        self.field.clear()
        self.adjustSize()
        self.move(anchor)
        self.show()
        self.raise_()
        self.field.setFocus()

    def _save(self) -> None:
        text = self.field.text().strip()
        if text:
            self._on_label(self.marker_id, text)
        self.hide()


class ExportDialog(QtWidgets.QDialog):
    """What to export: format, range (whole / between markers / the visible range), CSV
    separator and decimal comma."""

    def __init__(self, parent: QtWidgets.QWidget, fmt: str, markers: list[Any],
                 visible: tuple[float, float]) -> None:
        super().__init__(parent)
        self.setWindowTitle({"csv": "Export CSV", "log": "Export phone log",
                             "mat": "Export MATLAB .mat"}[fmt])
        self.fmt = fmt
        self.visible = visible
        form = QtWidgets.QFormLayout(self)
        self.range_combo = QtWidgets.QComboBox()
        self.range_combo.addItem("Whole session", "whole")
        if len(markers) >= 1:
            self.range_combo.addItem("Between two markers", "markers")
        self.range_combo.addItem(f"Visible range ({visible[0]:.1f} s to {visible[1]:.1f} s)",
                                 "visible")
        form.addRow("Range", self.range_combo)
        self.from_marker = QtWidgets.QComboBox()
        self.to_marker = QtWidgets.QComboBox()
        for combo in (self.from_marker, self.to_marker):
            combo.addItem("start" if combo is self.from_marker else "end", None)
            for marker in markers:
                combo.addItem(marker.title, str(marker.id))
        form.addRow("From marker", self.from_marker)
        form.addRow("To marker", self.to_marker)
        self.separator = QtWidgets.QComboBox()
        for label, value in (("comma ,", "comma"), ("semicolon ;", "semicolon"), ("tab", "tab")):
            self.separator.addItem(label, value)
        self.decimal_comma = QtWidgets.QCheckBox("Decimal comma (3,14)")
        self.decimal_comma.toggled.connect(
            lambda on: on and self.separator.currentData() == "comma"
            and self.separator.setCurrentIndex(1))
        if fmt == "csv":
            form.addRow("Separator", self.separator)
            form.addRow("", self.decimal_comma)
        buttons = QtWidgets.QDialogButtonBox(QtWidgets.QDialogButtonBox.StandardButton.Ok
                                             | QtWidgets.QDialogButtonBox.StandardButton.Cancel)
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        form.addRow(buttons)

    def options(self) -> dict[str, Any]:
        choice = self.range_combo.currentData()
        out: dict[str, Any] = {"separator": self.separator.currentData(),
                               "decimal_comma": self.decimal_comma.isChecked()}
        if choice == "markers":
            out["from_marker"] = self.from_marker.currentData()
            out["to_marker"] = self.to_marker.currentData()
        elif choice == "visible":
            out["from_s"], out["to_s"] = max(0.0, self.visible[0]), max(0.0, self.visible[1])
        return out


class _Relay(QtCore.QObject):
    """Results of a background export, delivered in the GUI thread."""

    done = QtCore.Signal(str, bool)


class SessionControls(QtCore.QObject):
    """File/Replay actions of the main window (see the module docstring)."""

    def __init__(self, window: Any, engine_factory: Callable[[str], Any] | None = None) -> None:
        super().__init__(window)
        self.window = window
        self.engine_factory = engine_factory or default_engine_factory
        self.marker_box = MarkerLabelBox(window, self._label_marker)
        self._relay = _Relay()
        self._relay.done.connect(self._export_done)
        self._errors_shown: set[str] = set()
        self._saved_shown: set[str] = set()
        self.export_thread: threading.Thread | None = None
        self.last_export: str | None = None

    # ---- menus -------------------------------------------------------------------------------

    def build_file_menu(self, menu: QtWidgets.QMenu) -> None:
        window = self.window
        self.open_action = window.add_action(menu, "&Open session or log…", SHORTCUTS["open"],
                                             self.choose_and_open)
        self.recent_menu = menu.addMenu("Open &recent")
        self.recent_menu.aboutToShow.connect(self._fill_recent)
        window.add_action(menu, "Open the &sessions folder…", None,
                          lambda: self.choose_and_open(str(sessions_dir())))
        menu.addSeparator()
        self.record_action = window.add_action(menu, "Start / stop &recording", SHORTCUTS["record"],
                                               window.transport.toggle_recording)
        self.marker_action = window.add_action(menu, "Add a &marker", SHORTCUTS["marker"],
                                               self.add_marker)
        self.label_action = window.add_action(menu, "&Label this session…", None,
                                              lambda: self.label_session())
        menu.addSeparator()
        export = menu.addMenu("&Export")
        self.export_actions = {
            "csv": window.add_action(export, "CSV of measurements and estimates…", None,
                                     lambda: self.export_with_dialog("csv")),
            "log": window.add_action(export, "Phone log (the app's text format)…", None,
                                     lambda: self.export_with_dialog("log")),
            "mat": window.add_action(export, "MATLAB .mat (meas, xhat)…", None,
                                     lambda: self.export_with_dialog("mat"))}
        if not scipy_available():
            action = self.export_actions["mat"]
            action.setText("MATLAB .mat (needs scipy: pip install scipy)")
            action.setEnabled(False)
        menu.addSeparator()

    def build_replay_menu(self, menu: QtWidgets.QMenu) -> None:
        transport = self.window.transport
        self.replay_actions = []
        for text, key, (method, value) in REPLAY_KEYS:
            target = getattr(transport, method)
            if value == float("inf"):
                def slot(checked=False):
                    transport.seek_to(transport.duration_s())
            else:
                def slot(checked=False, t=target, v=value):
                    t(v)
            self.replay_actions.append(self.window.add_action(menu, text, key, slot))

    # ---- open --------------------------------------------------------------------------------

    def choose_and_open(self, folder: str | None = None) -> None:
        start = folder or str(self.recent()[0] if self.recent() else sessions_dir())
        path, _ = QtWidgets.QFileDialog.getOpenFileName(
            self.window, "Open a session or a phone log", start,
            "Sessions and logs (raw.txt session.json *.txt *.txt.gz);;All files (*)")
        if path:
            self.open(path)

    def open(self, path: str | Path) -> bool:
        """Replay `path` (a session folder, raw.txt, session.json or a phone's log) in place
        of the current source; a one-line message when it cannot be."""
        window = self.window
        try:
            engine = self.engine_factory(str(path))
        except ConfigError as error:
            self.complain("Cannot open", str(error))
            return False
        window.swap_engine(engine)
        self.add_recent(path)
        self._show_title(path)
        window.statusBar().showMessage(f"replaying {path}", 5000)
        return True

    def _show_title(self, path: str | Path | None) -> None:
        if path is not None and session_folder(path) is not None:
            self.window.setWindowTitle(f"Orientation Lab — {session_title(path)}")

    # ---- labels --------------------------------------------------------------------------------

    def label_target(self) -> Path | None:
        """The session File → Label names: the one replayed, else the latest recording once it
        has stopped (a recording in progress rewrites its session.json itself)."""
        source = self.export_source()
        if source is None:
            return None
        snapshot = self.window.last_snapshot
        recording = snapshot.recording if snapshot is not None else None
        if (recording and recording.get("active")
                and Path(str(recording.get("folder", ""))) == session_folder(source)):
            return None
        return session_folder(source)

    def label_session(self, label: str | None = None) -> bool:
        """Give the session a label (asked for when None): kept in its session.json, shown in
        Open recent, the window's title and export names."""
        folder = self.label_target()
        if folder is None:
            self.complain("Label a session", "Open a recorded session (or stop the recording) "
                                             "to label it: a phone's own log has no "
                                             "session.json to keep a label in.")
            return False
        if label is None:
            label, ok = QtWidgets.QInputDialog.getText(
                self.window, "Label this session", f"A name for {folder.name} (empty: none):",
                text=session_label(folder))
            if not ok:
                return False
        try:
            written = write_label(folder / "session.json", label)
        except (OSError, ValueError) as error:
            self.complain("Label a session", f"cannot write {folder / 'session.json'}: "
                                             f"{getattr(error, 'strerror', None) or error}")
            return False
        self.add_recent(folder)
        engine_source = getattr(getattr(self.window.engine, "source", None), "path", None)
        if engine_source is not None and session_folder(engine_source) == folder:
            self._show_title(folder)
        self.window.statusBar().showMessage(
            f"{folder.name} labelled {written!r}" if written else f"{folder.name}: label removed",
            5000)
        return True

    def recent(self) -> list[Path]:
        value = self.window.settings.value("sessions/recent") or []
        if isinstance(value, str):
            value = [value]
        return [Path(p) for p in value if p]

    def add_recent(self, path: str | Path) -> None:
        path = Path(path)
        if path.name in ("raw.txt", "session.json"):
            path = path.parent
        items = [str(path)] + [str(p) for p in self.recent() if p != path]
        self.window.settings.setValue("sessions/recent", items[:MAX_RECENT])

    def _fill_recent(self) -> None:
        menu = self.recent_menu
        menu.clear()
        recent = [p for p in self.recent() if p.exists()]
        if not recent:
            menu.addAction("(none yet)").setEnabled(False)
        for path in recent:
            title = session_title(path)
            action = menu.addAction(title if title != path.name else str(path),
                                    lambda p=path: self.open(p))
            action.setToolTip(str(path))

    def drop_paths(self, mime: QtCore.QMimeData) -> list[str]:
        return [url.toLocalFile() for url in mime.urls() if url.isLocalFile()] \
            if mime.hasUrls() else []

    # ---- markers -------------------------------------------------------------------------------

    def add_marker(self) -> None:
        """A marker now (the engine stamps it with the latest sample); then its label box."""
        window = self.window
        snapshot = window.last_snapshot
        markers = snapshot.markers if snapshot is not None else ()
        number = max((m.id for m in markers), default=0) + 1
        window.send(AddMarker())
        where = "–"
        if snapshot is not None and snapshot.t_ms is not None and snapshot.t0_ms is not None:
            where = f"{(snapshot.t_ms - snapshot.t0_ms) / 1000.0:.1f} s"
        bar = window.transport
        anchor = bar.mapTo(window, QtCore.QPoint(max(0, bar.width() // 2 - 180), -40))
        self.marker_box.ask(number, where, anchor)

    def _label_marker(self, number: int, label: str) -> None:
        self.window.send(SetMarkerLabel(number, label))

    # ---- snapshots -----------------------------------------------------------------------------

    def follow(self, snapshot: Snapshot) -> None:
        """A recording that stopped on an error says so once, clearly; a saved recording goes
        into the recent list."""
        recording = snapshot.recording
        if not recording:
            return
        folder = str(recording.get("folder", ""))
        error = recording.get("error")
        key = f"{folder}|{error}|{recording.get('at', '')}"
        if error and key not in self._errors_shown:
            self._errors_shown.add(key)
            self.complain("Recording stopped",
                          f"{error}\n\nThe stream and the estimates go on; what was recorded "
                          f"until then is in {folder}.")
        elif not recording.get("active") and folder and folder not in self._saved_shown:
            self._saved_shown.add(folder)
            self.add_recent(folder)

    def complain(self, title: str, text: str) -> None:
        """Say what went wrong: its first line in the status bar, the whole in a message box
        that does not block the window."""
        self.window.statusBar().showMessage(text.splitlines()[0], 15000)
        box = QtWidgets.QMessageBox(QtWidgets.QMessageBox.Icon.Warning, title, text,
                                    QtWidgets.QMessageBox.StandardButton.Ok, self.window)
        box.setModal(False)
        box.setObjectName("session_message")
        box.show()
        self.last_message = text

    last_message: str = ""

    # ---- exports -------------------------------------------------------------------------------

    def export_source(self) -> str | None:
        """What File → Export exports: the replayed file, else the latest recording."""
        engine = self.window.engine
        source = getattr(engine, "source", None)
        path = getattr(source.played(), "path", None) if source is not None else None
        if path is not None:
            return str(path)
        snapshot = self.window.last_snapshot
        if snapshot is not None and snapshot.recording and snapshot.recording.get("folder"):
            return str(snapshot.recording["folder"])
        return None

    def export_with_dialog(self, fmt: str) -> None:
        source = self.export_source()
        if source is None:
            self.complain("Nothing to export", "Open a session or record one first.")
            return
        snapshot = self.window.last_snapshot
        markers = list(snapshot.markers) if snapshot is not None else []
        dialog = ExportDialog(self.window, fmt, markers, self.window.plots.x_range())
        if dialog.exec() != QtWidgets.QDialog.DialogCode.Accepted:
            return
        out, _ = QtWidgets.QFileDialog.getSaveFileName(self.window, dialog.windowTitle(),
                                                       str(export_path(source, fmt)))
        if out:
            # the replayed session holds what the replay shows: its configuration over time
            setup = replayed_setup(self.window.configuration, source)
            self.export(source, fmt, out, setup=setup, **dialog.options())

    def export(self, source: str, fmt: str, out: str, **options: Any) -> None:
        """Export in a background thread; the status bar says what was written."""
        from app.engine.offline.export import export_session

        def run() -> None:
            try:
                self._relay.done.emit(export_session(source, fmt, out, **options), True)
            except ConfigError as error:
                self._relay.done.emit(str(error), False)
            except Exception as error:   # noqa: BLE001 (shown, not swallowed)
                self._relay.done.emit(f"export failed: {type(error).__name__}: {error}", False)

        self.window.statusBar().showMessage(f"exporting {source} …", 5000)
        self.export_thread = threading.Thread(target=run, name="export", daemon=True)
        self.export_thread.start()

    def _export_done(self, message: str, ok: bool) -> None:
        self.last_export = message
        if ok:
            self.window.statusBar().showMessage(f"exported {message}", 10000)
        else:
            self.complain("Export", message)
