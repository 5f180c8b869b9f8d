"""Settings, state and outputs are declared once; the compiled layouts and the tables of
docs/filter.md are made from those declarations, never by hand."""

from __future__ import annotations

import math
import re
from dataclasses import fields, is_dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st

from ekf.fast import layout
from ekf.fast.layout import C, S, pack_settings, pack_state, unpack_state
from ekf.diagnostics import Diagnostics, Flags, output_rows
from ekf.settings import (GROUPS, PRESETS, EKFSettings, format_value, grouped_rows,
                          settings_rows, switch_text)
from ekf.state import EKFState, check_state, state_dict

FILTER_DOC = Path(__file__).resolve().parents[2] / "docs" / "filter.md"


def _size(shape: tuple[int, ...]) -> int:
    return int(np.prod(shape)) if shape else 1


# ---- metadata ---------------------------------------------------------------------------------
@pytest.mark.parametrize("cls", [EKFSettings, Flags, Diagnostics, EKFState])
def test_every_field_has_a_unit_and_a_one_line_explanation(cls):
    for f in fields(cls):
        assert f.metadata.get("unit"), f"{cls.__name__}.{f.name} has no unit"
        doc = f.metadata.get("doc", "")
        assert doc and "\n" not in doc, f"{cls.__name__}.{f.name} needs a one-line doc"


def test_settings_rows_list_every_setting_with_both_presets():
    rows = settings_rows()
    assert [r.name for r in rows] == [f.name for f in fields(EKFSettings)]
    for r in rows:
        assert r.default == getattr(PRESETS["default"], r.name)
        assert r.course == getattr(PRESETS["course"], r.name)
    assert format_value(math.inf) == "inf" and format_value(True) == "true"
    assert format_value([[3e-4, 0, 0], [0, 3e-4, 0], [0, 0, 3e-4]]) == "0.0003·I"


def test_relearn_docs_say_that_the_rejected_readings_must_agree():
    doc = {r.name: r.doc for r in settings_rows()}["mag_relearn_s"]
    assert "agree with each other" in doc


def test_settings_json_round_trip_and_choices_are_checked():
    for preset in PRESETS.values():
        assert EKFSettings.from_dict(preset.to_dict()) == preset
    with pytest.raises(ValueError, match="setting mag_strength_update = \"sometimes\": must be 'always' or 'accepted'"):
        EKFSettings.from_dict({"mag_strength_update": "sometimes"})
    with pytest.raises(ValueError, match="3x3"):
        EKFSettings.from_dict({"acc_noise_cov": [[1.0, 0.0], [0.0, 1.0]]})


# ---- the compiled layouts -------------------------------------------------------------------------
def _declared_state_slots() -> list[tuple[str, int]]:
    """(name, size) of every packed slot, in declaration order, then the work area."""
    slots = []
    for f in fields(EKFState):
        kind = f.metadata["kind"]
        if is_dataclass(kind):
            slots += [(g.name, 1) for g in fields(kind)]
        else:
            slots.append((f.name, _size(f.metadata["shape"])))
    return slots + [(name, length) for name, length, _ in layout.WORK]


def test_state_layout_gives_every_declared_field_its_own_slots():
    slots = _declared_state_slots()
    assert list(S._fields) == [name for name, _ in slots] + ["size"]
    covered = np.zeros(S.size, int)
    for name, size in slots:
        offset = getattr(S, name)
        covered[offset:offset + size] += 1
    assert np.all(covered == 1), "slots overlap or leave gaps"
    assert S.size == sum(size for _, size in slots)


def test_settings_layout_gives_every_number_and_coefficient_its_own_slots():
    expected = [(f.name, _size(f.metadata["shape"])) for f in fields(EKFSettings)
                if not f.metadata["choices"]]
    expected += [(name, 1) for name, _, _ in layout.COEFFICIENTS]
    assert list(C._fields) == [name for name, _ in expected] + ["size"]
    covered = np.zeros(C.size, int)
    for name, size in expected:
        covered[getattr(C, name):getattr(C, name) + size] += 1
    assert np.all(covered == 1)


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_packed_settings_hold_the_settings(preset):
    s = PRESETS[preset].with_changes(m0=(0.0, 16.0, -45.0),
                                     gyr_noise_cov=[[1e-4, 2e-5, 0], [2e-5, 3e-4, 0], [0, 0, 1]])
    c = pack_settings(s)
    assert c.shape == (C.size,)
    for f in fields(EKFSettings):
        if f.metadata["choices"]:
            continue
        n = _size(f.metadata["shape"])
        np.testing.assert_array_equal(c[getattr(C, f.name):getattr(C, f.name) + n],
                                      np.asarray(getattr(s, f.name), float).reshape(n))
    assert c[C.mag_strength_accepted] == float(s.mag_strength_update == "accepted")
    assert c[C.mag_strength_always] == float(s.mag_strength_update == "always")
    assert c[C.gyr_noise_isotropic] == 0.0
    assert pack_settings(PRESETS[preset])[C.gyr_noise_isotropic] == 1.0
    assert np.isnan(pack_settings(PRESETS[preset])[C.m0:C.m0 + 3]).all()   # m0 None


finite = st.floats(-1e6, 1e6, allow_nan=False)


@hsettings(max_examples=30, deadline=None)
@given(st.data())
def test_pack_unpack_round_trip(data):
    state = state_dict(EKFState.initial(PRESETS["default"], {"gyr": True, "acc": False,
                                                              "mag": True}))
    for f in fields(EKFState):
        kind, shape = f.metadata["kind"], f.metadata["shape"]
        if is_dataclass(kind):
            record = state[f.name]
            for g in fields(kind):
                gk = g.metadata["kind"]
                value = (data.draw(st.booleans()) if gk is bool else
                         data.draw(st.integers(0, 4)) if gk is int else data.draw(finite))
                setattr(record, g.name, value)
        elif shape:
            state[f.name] = np.array(data.draw(st.lists(finite, min_size=_size(shape),
                                                        max_size=_size(shape)))).reshape(shape)
        elif kind is bool:
            state[f.name] = data.draw(st.booleans())
        elif kind is int:
            state[f.name] = data.draw(st.sampled_from([4, 7]))
        else:
            state[f.name] = data.draw(st.one_of(finite, st.just(math.nan), st.just(-math.inf)))
    packed = pack_state(state)
    assert packed.shape == (S.size,)
    back = unpack_state(packed)
    check_state(EKFState, back)
    assert back.keys() == state.keys()
    for name, value in state.items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(back[name], value)
        elif is_dataclass(value):
            assert repr(back[name]) == repr(value)
        else:
            assert type(back[name]) is type(value) and repr(back[name]) == repr(value)


# ---- the tables of docs/filter.md ------------------------------------------------------------------
def _cell(text: str) -> str:
    return str(text).replace("|", "\\|")


SETTINGS_BEGIN = "<!-- the settings tables: generated from ekf/settings.py by tests/ekf/test_declarations.py -->"
SETTINGS_END = "<!-- end of the settings tables -->"


def settings_tables() -> str:
    """The settings section of docs/filter.md: per group its title, switch and what it does,
    then a table of its settings (`python tests/ekf/test_declarations.py` writes it)."""
    out = [SETTINGS_BEGIN]
    for group, rows in grouped_rows():
        if group.switch is None:
            state = ""
        else:
            on = {name: group.switch.holds(PRESETS[name]) for name in ("default", "course")}
            state = (f"; {'on' if on['default'] else 'off'} in the default preset, "
                     f"{'on' if on['course'] else 'off'} in the course preset")
        out += ["", f"### {group.title}", "",
                f"Group `{group.name}`: {group.doc}. Switch: {switch_text(group)}{state}.", "",
                "| setting | default | course | typical | unit | allowed | search range | "
                "meaning |", "|---|---|---|---|---|---|---|---|"]
        for r in rows:
            needs = f"*needs {r.requires}:* " if r.requires else ""
            out.append(f"| `{r.name}` | {_cell(format_value(r.default))} | "
                       f"{_cell(format_value(r.course))} | {_cell(r.typical)} | {_cell(r.unit)} "
                       f"| {_cell(r.allowed)} | {_cell(r.search)} | {_cell(needs + r.doc)} |")
    return "\n".join(out + ["", SETTINGS_END])


def _settings_section(text: str) -> str:
    begin, end = text.find(SETTINGS_BEGIN), text.find(SETTINGS_END)
    assert 0 <= begin < end, "docs/filter.md has no generated settings tables"
    return text[begin:end + len(SETTINGS_END)]


def test_filter_doc_settings_tables_are_the_declarations():
    expected = settings_tables()
    assert _settings_section(FILTER_DOC.read_text(encoding="utf-8")) == expected, (
        "docs/filter.md's settings tables differ from the declarations; write them with "
        "`.venv/bin/python tests/ekf/test_declarations.py`")


def test_every_setting_is_in_one_declared_group_and_every_group_has_settings():
    grouped = grouped_rows()
    assert [g.name for g, _ in grouped] == [g.name for g in GROUPS]
    assert sorted(r.name for _, rows in grouped for r in rows) == sorted(
        f.name for f in fields(EKFSettings))
    assert all(rows for _, rows in grouped)
    for group, rows in grouped:
        if group.switch is not None:      # a group's switch is one of its own settings
            assert group.switch.name in [r.name for r in rows], group.name
    for r in settings_rows():
        assert r.typical and "\n" not in r.typical, f"{r.name} needs a typical value"
        assert "with `" not in r.doc and "with '" not in r.doc, (
            f"{r.name}: a dependency belongs in its group's switch or its requires=")


def outputs_table(cls: type) -> str:
    if cls is Flags:   # booleans: no unit column
        lines = ["| flag | meaning |", "|---|---|"]
        lines += [f"| `{r.name}` | {_cell(r.doc)} |" for r in output_rows(cls)]
    else:
        lines = ["| diagnostic | unit | meaning |", "|---|---|---|"]
        lines += [f"| `{r.name}` | {_cell(r.unit)} | {_cell(r.doc)} |" for r in output_rows(cls)]
    return "\n".join(lines)


def _doc_table(first_header_cell: str) -> str:
    text = FILTER_DOC.read_text(encoding="utf-8")
    match = re.search(rf"^\| {first_header_cell} \|.*?(?=\n(?!\|))", text, re.M | re.S)
    assert match, f"docs/filter.md has no table starting with '| {first_header_cell} |'"
    return match.group(0)


@pytest.mark.parametrize("name,make", [("flag", lambda: outputs_table(Flags)),
                                       ("diagnostic", lambda: outputs_table(Diagnostics))])
def test_filter_doc_tables_are_the_declarations(name, make):
    expected = make()
    assert _doc_table(name) == expected, (
        f"docs/filter.md's {name} table differs from the declarations; it should read:\n{expected}")


def write_settings_tables() -> None:
    """Replace docs/filter.md's settings tables by the ones the declarations give."""
    text = FILTER_DOC.read_text(encoding="utf-8")
    FILTER_DOC.write_text(text.replace(_settings_section(text), settings_tables()),
                          encoding="utf-8")


if __name__ == "__main__":
    write_settings_tables()
