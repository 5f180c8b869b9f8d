"""The settings panel, driven with pytest-qt: rows from the declarations, live edits sent as
SetSettings, bad values refused, resets, files and profiles."""

from __future__ import annotations

import pytest
from PySide6 import QtCore, QtGui

import ekf
from app.engine.commands import SetSettings
from app.engine.tuning.profiles import Profile, ProfileStore
from app.ui.settings_panel import SettingsPanel, parse_value
from ekf.settings import grouped_rows


@pytest.fixture
def panel(qtbot, tmp_path):
    sent = []
    widget = SettingsPanel(sent.append, store=ProfileStore(tmp_path / "profiles"))
    qtbot.addWidget(widget)
    widget.sent = sent
    return widget


def test_every_setting_is_listed_under_its_group_with_unit_default_course_and_doc(panel):
    groups = grouped_rows()
    assert panel.table.rowCount() == len(groups) + len(ekf.settings_rows())
    r = 0
    for group, rows in groups:           # the group's title over its settings, in order
        assert panel.table.item(r, 0).text().startswith(group.title)
        assert panel.table.columnSpan(r, 0) == panel.table.columnCount()
        assert not panel.table.item(r, 0).flags() & QtCore.Qt.ItemFlag.ItemIsEditable
        for row in rows:
            r += 1
            assert panel.row_of(row.name) == r
            assert panel.table.item(r, 0).text() == row.name
            assert panel.table.item(r, 2).text() == row.unit
            assert row.doc in panel.table.item(r, 0).toolTip()   # the declaration's own doc
            assert row.typical in panel.table.item(r, 0).toolTip()
        r += 1
    assert panel.table.columnCount() == 5
    panel.table.setCurrentCell(panel.row_of("acc_gate"), 1)
    assert panel.meaning.text().startswith("<b>acc_gate</b> [m/s²]: ")
    assert {r.name: r for r in ekf.settings_rows()}["acc_gate"].doc in panel.meaning.text()
    assert panel.table.item(panel.row_of("acc_gate"), 3).text() == "2"
    assert panel.table.item(panel.row_of("acc_gate"), 4).text() == "1"


def test_a_switched_off_group_greys_its_settings_and_says_why(panel):
    def grey(name: str) -> bool:
        color = panel.table.item(panel.row_of(name), 0).foreground().color()
        return color == panel.palette().color(QtGui.QPalette.ColorGroup.Disabled,
                                              QtGui.QPalette.ColorRole.Text)

    assert not grey("acc_noise_adapt") and not grey("mag_noise_adapt_clip")
    panel.reset_to("course")                 # no low-pass, no unevenness adaptation
    assert grey("acc_noise_adapt") and not grey("acc_lowpass_s")
    assert "No effect now: it needs `acc_lowpass_s` > 0" in (
        panel.table.item(panel.row_of("acc_noise_adapt"), 0).toolTip())
    assert grey("mag_noise_adapt_clip")      # its requires=, inside an always-on group
    title = panel.table.item(panel.row_of("acc_lowpass_s") - 1, 0)
    assert title.text() == "Accelerometer low-pass (off)"
    assert panel.edit("acc_lowpass_s", "0.5")
    assert not grey("acc_noise_adapt")
    assert panel.table.item(panel.row_of("acc_lowpass_s") - 1, 0).text() == (
        "Accelerometer low-pass")


def test_an_edit_is_sent_as_set_settings_and_shown_bold(panel, qtbot):
    with qtbot.waitSignal(panel.settingsChanged) as signal:
        assert panel.edit("acc_gate", "3.5")
    assert signal.args[0].acc_gate == 3.5
    command = panel.sent[-1]
    assert isinstance(command, SetSettings) and command.source == "panel"
    assert command.settings.acc_gate == 3.5
    assert panel.table.item(panel.row_of("acc_gate"), 1).font().bold()
    assert panel.edit("gyr_noise_cov", "2e-4·I")
    assert panel.settings.gyr_noise_cov[1][1] == 2e-4
    assert panel.edit("mag_hard_iron", "(1, -2, 30)")
    assert panel.settings.mag_hard_iron == (1.0, -2.0, 30.0)
    assert panel.edit("mag_dip_gate_deg", "inf")


def test_a_bad_value_is_refused_and_the_cell_goes_back(panel):
    assert not panel.edit("acc_gate", "fast")
    assert "acc_gate" in panel.message.text()
    assert panel.table.item(panel.row_of("acc_gate"), 1).text() == "2"
    assert not panel.edit("mag_strength_update", "sometimes")
    assert "must be" in panel.message.text()
    assert panel.sent == []


@pytest.mark.parametrize("name,text,allowed", [
    ("acc_gate", "-1", 'a number ≥ 0 or "inf"'), ("g", "0", "a finite number 1..100"),
    ("acc_noise_cov", "[1 2 0; 2 1 0; 0 0 1]", "positive-definite"),
    ("acc_lowpass_s", "inf", "a finite number ≥ 0")])
def test_a_value_outside_its_declaration_is_refused_with_what_is_allowed(panel, name, text,
                                                                        allowed):
    before = panel.settings
    assert not panel.edit(name, text)
    assert panel.message.text().startswith(f"setting {name} = ")
    assert allowed in panel.message.text()
    assert panel.settings is before and panel.sent == []


def test_reset_to_course_and_default(panel):
    panel.edit("acc_gate", "4")
    panel.reset_course.click()
    assert panel.sent[-1].settings == ekf.PRESETS["course"]
    assert panel.sent[-1].source == "reset to course"
    panel.reset_default.click()
    assert panel.settings == ekf.PRESETS["default"]


def test_save_and_load_a_settings_file(panel, tmp_path):
    panel.edit("acc_gate", "4")
    path = tmp_path / "mine.json"
    panel.save_to(path)
    panel.reset_to("default")
    assert panel.load_from(path)
    assert panel.settings.acc_gate == 4.0
    assert not panel.load_from(tmp_path / "missing.json")
    assert "not found" in panel.message.text()


def test_profiles_are_saved_listed_and_applied_with_the_calibration(panel):
    panel.edit("mag_gate", "7")
    assert panel.save_profile("Pixel 7") is not None
    assert panel.profiles.findText("Pixel 7") >= 0
    panel.store.save(Profile("desk", mag={"offset": [1, 2, 3], "soft_iron": [[1, 0, 0], [0, 1, 0],
                                                                             [0, 0, 1]],
                                          "nothing_to_correct": False}))
    panel.refresh_profiles()
    assert panel.apply_profile("desk")
    command = panel.sent[-1]
    assert command.calibration["name"] == "desk" and command.source == "profile"
    assert command.settings.mag_hard_iron == (1.0, 2.0, 3.0)
    assert not panel.apply_profile("nobody")


@pytest.mark.parametrize("current,text,expected", [
    (1.0, "2.5", 2.5), (1.0, "inf", float("inf")), (True, "false", False),
    ((0.0, 0.0, 0.0), "1 2 3", [1.0, 2.0, 3.0]), (None, "none", None),
    ([[1.0] * 3] * 3, "diag(1, 2, 3)", [[1, 0, 0], [0, 2, 0], [0, 0, 3]]),
    ([[1.0] * 3] * 3, "[1 2 3; 4 5 6; 7 8 9]", [[1, 2, 3], [4, 5, 6], [7, 8, 9]]),
])
def test_parse_value(current, text, expected):
    assert parse_value(current, text) == expected
