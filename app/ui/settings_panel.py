"""The settings panel: every filter setting with its value, unit, default and course value, under
the title of its group, and below the table what the chosen one means, all taken from the
declarations (``ekf.settings.grouped_rows()``, no second copy), editable live. A setting that
has no effect in the settings shown (its group's switch is off, or the setting it requires) is
greyed out, and says why.

A change is parsed and checked (``EKFSettings.from_dict``, the rules of `--settings` files) and
sent as ``SetSettings`` (the engine applies it at the next batch and records it in the session
timeline); a bad value is refused with a one-line message and the cell goes back. Reset to the
default or the course preset, save/load settings files (the one loader,
``app.engine.config.load_settings``) and apply/save named profiles.

Mounting: ``SettingsPanel(send=engine.send, settings=current)``; call :meth:`set_settings` when
the settings change elsewhere (the calibration workspace, the tuner), without sending.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from PySide6 import QtCore, QtGui, QtWidgets

import ekf
from ekf.settings import Group, SettingRow, format_value, grouped_rows, inactive_reason, switch_text
from app.engine import config
from app.engine.commands import SetSettings
from app.engine.offline.outputs import check_output, write_output
from app.engine.tuning.profiles import Profile, ProfileStore

COLUMNS = ("setting", "value", "unit", "default", "course")
VALUE = 1
MAX_VALUE_COLUMN_PX = 120    # a long vector or matrix is cut ("…"), whole in its tooltip
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|[-+]?inf"


def _numbers(text: str) -> list[float]:
    return [float(x) for x in re.findall(_NUMBER, text)]


def parse_value(current: Any, text: str) -> Any:
    """A cell's text -> a value of the kind of `current` (the setting's present value):
    numbers ("inf" allowed), vectors "(a, b, c)" (or "none" where allowed), matrices "r·I",
    "diag(a, b, c)" or nine numbers "[a b c; d e f; g h i]". ValueError with a one-line reason.
    """
    text = text.strip()
    if isinstance(current, bool):
        if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
            raise ValueError(f"expected true or false, got {text!r}")
        return text.lower() in ("true", "1", "yes")
    if isinstance(current, str):
        return text
    if isinstance(current, list) or (isinstance(current, tuple) and current
                                     and isinstance(current[0], (list, tuple))):
        return _parse_matrix(text)
    if isinstance(current, tuple) or current is None:
        if text.lower() in ("none", ""):
            return None
        values = _numbers(text)
        if len(values) != 3:
            raise ValueError(f"expected 3 numbers, got {text!r}")
        return values
    values = _numbers(text)
    if len(values) != 1:
        raise ValueError(f"expected a number, got {text!r}")
    return values[0]


def _parse_matrix(text: str) -> list[list[float]]:
    values = _numbers(text)
    lowered = text.lower().replace(" ", "")
    if len(values) == 1 and (lowered.endswith("i") or re.fullmatch(_NUMBER, text.strip())):
        r = values[0]
        return [[r if i == j else 0.0 for j in range(3)] for i in range(3)]
    if len(values) == 3 and lowered.startswith("diag"):
        return [[values[i] if i == j else 0.0 for j in range(3)] for i in range(3)]
    if len(values) == 9:
        return [values[0:3], values[3:6], values[6:9]]
    raise ValueError(f"expected r·I, diag(a, b, c) or 9 numbers, got {text!r}")


class SettingsPanel(QtWidgets.QWidget):
    """See the module's docstring. send(command): the engine's send; settings: the settings in
    use (None: the default preset); store: profiles (None: the user's data folder)."""

    settingsChanged = QtCore.Signal(object)     # the new ekf.EKFSettings, after it was sent

    def __init__(self, send: Callable[[Any], None], settings: ekf.EKFSettings | None = None,
                 store: ProfileStore | None = None,
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self._send = send
        self.store = store or ProfileStore()
        self.settings = settings if settings is not None else ekf.PRESETS["default"]
        # the table's rows: each group's title, then its settings
        self.lines: list[Group | SettingRow] = [
            line for group, rows in grouped_rows() for line in (group, *rows)]
        self.rows = [line for line in self.lines if isinstance(line, SettingRow)]
        self._filling = False
        self.table = QtWidgets.QTableWidget(len(self.lines), len(COLUMNS))
        self.table.setHorizontalHeaderLabels([c.capitalize() for c in COLUMNS])
        self.table.verticalHeader().setVisible(False)
        self.table.setHorizontalScrollBarPolicy(QtCore.Qt.ScrollBarPolicy.ScrollBarAsNeeded)
        self.table.itemChanged.connect(self._on_item_changed)
        # what the current row's setting means (the declaration's doc), below the table
        self.meaning = QtWidgets.QLabel("")
        self.meaning.setObjectName("setting_meaning")
        self.meaning.setWordWrap(True)
        self.meaning.setStyleSheet("color: #444;")
        self.meaning.setMinimumHeight(3 * self.meaning.fontMetrics().lineSpacing())
        self.meaning.setAlignment(QtCore.Qt.AlignmentFlag.AlignLeft
                                  | QtCore.Qt.AlignmentFlag.AlignTop)
        self.table.currentCellChanged.connect(lambda row, *_: self.show_meaning(row))
        self.message = QtWidgets.QLabel("")
        self.message.setWordWrap(True)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addLayout(self._buttons())
        layout.addWidget(self.table, 1)
        layout.addWidget(self.meaning)
        layout.addWidget(self.message)
        self._fill()

    # -- construction -------------------------------------------------------------------------

    def _buttons(self) -> QtWidgets.QLayout:
        row = QtWidgets.QVBoxLayout()
        self.reset_default = QtWidgets.QPushButton("Reset to default")
        self.reset_course = QtWidgets.QPushButton("Reset to course")
        self.reset_default.clicked.connect(lambda: self.reset_to("default"))
        self.reset_course.clicked.connect(lambda: self.reset_to("course"))
        self.save_button = QtWidgets.QPushButton("Save…")
        self.load_button = QtWidgets.QPushButton("Load…")
        self.save_button.clicked.connect(self._save_dialog)
        self.load_button.clicked.connect(self._load_dialog)
        self.profiles = QtWidgets.QComboBox()
        self.profiles.setMinimumContentsLength(14)
        self.apply_profile_button = QtWidgets.QPushButton("Apply profile")
        self.apply_profile_button.clicked.connect(
            lambda: self.apply_profile(self.profiles.currentText()))
        self.save_profile_button = QtWidgets.QPushButton("Save as profile…")
        self.save_profile_button.clicked.connect(self._save_profile_dialog)
        # Two rows, so the panel fits beside the A/B plots on a 1280-pixel screen.
        presets, profiles = QtWidgets.QHBoxLayout(), QtWidgets.QHBoxLayout()
        for widget in (self.reset_default, self.reset_course, self.save_button,
                       self.load_button):
            presets.addWidget(widget)
        for widget in (QtWidgets.QLabel("Profile:"), self.profiles,
                       self.apply_profile_button, self.save_profile_button):
            profiles.addWidget(widget)
        for line in (presets, profiles):
            line.addStretch(1)
            row.addLayout(line)
        self.refresh_profiles()
        return row

    def _fill(self) -> None:
        self._filling = True
        try:
            for r, line in enumerate(self.lines):
                if isinstance(line, Group):
                    self._fill_group(r, line)
                else:
                    self._fill_setting(r, line)
            self.table.resizeColumnsToContents()
            for column in (VALUE, 3, 4):
                if self.table.columnWidth(column) > MAX_VALUE_COLUMN_PX:
                    self.table.setColumnWidth(column, MAX_VALUE_COLUMN_PX)
        finally:
            self._filling = False
        self.show_meaning(self.table.currentRow())

    def _item(self, r: int, c: int) -> QtWidgets.QTableWidgetItem:
        item = self.table.item(r, c)
        if item is None:      # an item the table owns already stays where it is
            item = QtWidgets.QTableWidgetItem()
            self.table.setItem(r, c, item)
        return item

    def _fill_group(self, r: int, group: Group) -> None:
        off = group.switch is not None and not group.switch.holds(self.settings)
        item = self._item(r, 0)
        item.setText(group.title + (" (off)" if off else ""))
        item.setToolTip(self._group_text(group))
        item.setFlags(QtCore.Qt.ItemFlag.ItemIsEnabled)
        font = item.font()
        font.setBold(True)
        item.setFont(font)
        if self.table.columnSpan(r, 0) != len(COLUMNS):
            self.table.setSpan(r, 0, 1, len(COLUMNS))

    def _fill_setting(self, r: int, row: SettingRow) -> None:
        value = getattr(self.settings, row.name)
        inactive = inactive_reason(self.settings, row.name)
        cells = (row.name, format_value(value), row.unit, format_value(row.default),
                 format_value(row.course))
        for c, text in enumerate(cells):
            item = self._item(r, c)
            item.setText(text)
            shown = f"{COLUMNS[c]}: {text}\n" if c in (VALUE, 3, 4) else ""
            item.setToolTip(f"{shown}{self._setting_text(row)}")
            flags = QtCore.Qt.ItemFlag.ItemIsEnabled | QtCore.Qt.ItemFlag.ItemIsSelectable
            if c == VALUE:
                flags |= QtCore.Qt.ItemFlag.ItemIsEditable
            item.setFlags(flags)
            font = item.font()
            font.setBold(c == VALUE and value != row.default)
            item.setFont(font)
            item.setForeground(self.palette().color(
                QtGui.QPalette.ColorGroup.Disabled if inactive else QtGui.QPalette.ColorGroup.Active,
                QtGui.QPalette.ColorRole.Text))

    def _setting_text(self, row: SettingRow) -> str:
        """A setting's unit, meaning, typical value and what it allows, and why it has no
        effect now when it has none (tooltips and the line below the table)."""
        text = (f"{row.name} [{row.unit}]: {row.doc} (typical: {row.typical}; allowed: "
                f"{row.allowed})")
        if row.requires:
            text += f"; needs {row.requires}"
        inactive = inactive_reason(self.settings, row.name)
        return text + (f". No effect now: it {inactive}." if inactive else "")

    def _group_text(self, group: Group) -> str:
        switch = switch_text(group).replace("`", "")
        state = ""
        if group.switch is not None:
            state = "; on now" if group.switch.holds(self.settings) else "; off now"
        return f"{group.title}: {group.doc.replace('`', '')}. Switch: {switch}{state}."

    def show_meaning(self, row: int) -> None:
        """Below the table: what the setting (or group) of table row `row` means, its unit,
        typical and allowed values (the first setting's while none is chosen)."""
        line = self.lines[row] if 0 <= row < len(self.lines) else self.rows[0]
        if isinstance(line, Group):
            text = self._group_text(line)
        else:
            text = self._setting_text(line)
            text = f"<b>{line.name}</b>" + text[len(line.name):]
        if self.meaning.text() != text:
            self.meaning.setText(text)

    def columns_width(self) -> int:
        """The table's width showing every column whole."""
        table = self.table
        header = table.horizontalHeader()
        natural = [max(table.sizeHintForColumn(c), header.sectionSizeHint(c))
                   for c in range(len(COLUMNS))]
        natural = [min(width, MAX_VALUE_COLUMN_PX) if c in (VALUE, 3, 4) else width
                   for c, width in enumerate(natural)]
        return (sum(natural) + table.verticalScrollBar().sizeHint().width()
                + 2 * table.frameWidth())

    # -- edits --------------------------------------------------------------------------------

    def row_of(self, name: str) -> int:
        """The table row of setting `name`."""
        return [line.name if isinstance(line, SettingRow) else None
                for line in self.lines].index(name)

    def edit(self, name: str, text: str) -> bool:
        """Set one setting from text, as typing it in the cell does; True when it was sent."""
        before = self.settings
        self.table.item(self.row_of(name), VALUE).setText(text)
        return self.settings is not before

    def _on_item_changed(self, item: QtWidgets.QTableWidgetItem) -> None:
        line = self.lines[item.row()]
        if self._filling or item.column() != VALUE or not isinstance(line, SettingRow):
            return
        name = line.name
        try:
            value = parse_value(getattr(self.settings, name), item.text())
            data = self.settings.to_dict()
            data[name] = value
            new = ekf.EKFSettings.from_dict(data)
        except (ValueError, TypeError) as error:
            self.message.setText(str(error) if isinstance(error, ekf.SettingsError)
                                 else f"{name}: {error}")
            self._fill()
            return
        self.message.setText(f"{name} = {format_value(getattr(new, name))} (applied from the "
                             "next sample)")
        self.apply(new, source="panel")

    def apply(self, settings: ekf.EKFSettings, source: str = "panel",
              calibration: dict | None = None) -> None:
        """Send new settings to the engine and show them."""
        self._send(SetSettings(settings, calibration=calibration, source=source))
        self.set_settings(settings)
        self.settingsChanged.emit(settings)

    def set_settings(self, settings: ekf.EKFSettings) -> None:
        """Show `settings` (changed elsewhere); nothing is sent."""
        self.settings = settings
        self._fill()

    def reset_to(self, preset: str) -> None:
        self.apply(ekf.PRESETS[preset], source=f"reset to {preset}")
        self.message.setText(f"reset to the {preset} preset")

    # -- files and profiles -------------------------------------------------------------------

    def save_to(self, path: str | Path) -> None:
        try:
            write_output(check_output(path), json.dumps(self.settings.to_dict(), indent=2) + "\n")
        except config.ConfigError as error:
            self.message.setText(str(error))
            return
        self.message.setText(f"saved {path}")

    def load_from(self, path: str | Path) -> bool:
        try:
            settings = config.load_settings(str(path))
        except config.ConfigError as error:
            self.message.setText(str(error))
            return False
        self.apply(settings, source=f"loaded {Path(path).name}")
        self.message.setText(f"loaded {path}")
        return True

    def refresh_profiles(self) -> None:
        current = self.profiles.currentText()
        self.profiles.clear()
        self.profiles.addItems(self.store.names())
        if current:
            self.profiles.setCurrentText(current)

    def apply_profile(self, name: str) -> bool:
        """The profile applied onto the settings in use, sent with the profile for the session."""
        if not name:
            self.message.setText("no profile chosen")
            return False
        try:
            profile = self.store.load(name)
            settings = profile.to_settings(self.settings)
        except (config.ConfigError, ValueError, TypeError) as error:
            self.message.setText(f"profile {name!r}: {error}")
            return False
        self.apply(settings, source="profile", calibration=profile.to_dict())
        self.message.setText(f"profile {name!r} applied")
        return True

    def save_profile(self, name: str) -> Path | None:
        """The settings in use kept as a profile of that name."""
        try:
            path = self.store.save(Profile(name, settings=self.settings.to_dict()))
        except config.ConfigError as error:
            self.message.setText(str(error))
            return None
        self.refresh_profiles()
        self.profiles.setCurrentText(name)
        self.message.setText(f"profile {name!r} saved to {path}")
        return path

    def _save_dialog(self) -> None:
        path, _ = QtWidgets.QFileDialog.getSaveFileName(self, "Save settings", "settings.json",
                                                        "JSON (*.json)")
        if path:
            self.save_to(path)

    def _load_dialog(self) -> None:
        path, _ = QtWidgets.QFileDialog.getOpenFileName(self, "Load settings", "",
                                                        "JSON (*.json)")
        if path:
            self.load_from(path)

    def _save_profile_dialog(self) -> None:
        name, ok = QtWidgets.QInputDialog.getText(self, "Save as profile", "Profile name:")
        if ok and name.strip():
            self.save_profile(name.strip())
