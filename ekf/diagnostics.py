"""What an estimator did with its latest samples, declared once.

* :class:`Flags`: booleans, the lights and which sensors were used;
* :class:`Diagnostics`: numbers, the reasons behind the lights (norms, gates, innovation
  statistics, the field's dip, and which gate fired).

Every estimator exposes ``.flags`` and ``.diagnostics`` as plain copies of these (safe to keep).
Each field's unit and one-line explanation are in its metadata; :func:`output_rows` lists them
(the tables in docs/filter.md). The EKF packs both into its state (``ekf.state``), so
snapshots carry them.

A flag keeps the decision of the latest sample of its sensor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import NamedTuple

# ---- which gate fired (Diagnostics.acc_rejected_by / mag_rejected_by) -----------------------
NOT_REJECTED = 0
ACC_NORM_GATE = 1       # | ||y_a|| - g | > acc_gate (task 8)
ACC_NIS_GATE = 2        # normalised innovation squared > acc_nis_gate
ACC_CLIPPED = 3         # an axis at the sensor's range (acc_range): the reading is not the force
MAG_STRENGTH_GATE = 1   # | ||y_m|| - L_k | > mag_gate (task 11)
MAG_DIP_GATE = 2        # | dip - reference dip | > mag_dip_gate_deg
MAG_SETTLING = 3        # passing the gates, but not yet for mag_settle_s
MAG_NIS_GATE = 4        # normalised innovation squared > mag_nis_gate
MAG_UNCALIBRATED = 5    # beyond any Earth field from the start: the offset is being acquired

ACC_REJECTED_BY = {NOT_REJECTED: "not rejected", ACC_NORM_GATE: "norm gate",
                   ACC_NIS_GATE: "NIS gate", ACC_CLIPPED: "clipped"}
MAG_REJECTED_BY = {NOT_REJECTED: "not rejected", MAG_STRENGTH_GATE: "strength gate",
                   MAG_DIP_GATE: "dip gate", MAG_SETTLING: "settling", MAG_NIS_GATE: "NIS gate",
                   MAG_UNCALIBRATED: "uncalibrated"}


def _output(default: object, kind: type, unit: str, doc: str):
    return field(default=default, metadata={"kind": kind, "unit": unit, "doc": doc})


def _flag(doc: str):
    return _output(False, bool, "-", doc)


def _number(unit: str, doc: str):
    return _output(math.nan, float, unit, doc)


def _code(doc: str):
    return _output(NOT_REJECTED, int, "-", doc)


@dataclass
class Flags:
    """The lights (Standstill, Acc disturbed, Mag disturbed) and which sensors were used."""

    acc_rejected: bool = _flag(
        "the latest accelerometer reading failed a gate (acc disturbed); with the low-pass only "
        "the norm gate counts and the reading is still averaged")
    mag_rejected: bool = _flag(
        "the latest magnetometer reading failed a gate or is still settling (mag disturbed)")
    at_rest: bool = _flag(
        "gyroscope and accelerometer have been still for `rest_min_duration` (standstill)")
    used_gyr: bool = _flag("the latest time update was driven by a gyroscope sample")
    used_acc: bool = _flag(
        "the latest accelerometer sample was used in an update (or, with the low-pass, averaged)")
    used_mag: bool = _flag("the latest magnetometer sample was used in an update")


@dataclass
class Diagnostics:
    """The numbers behind the flags, from the latest sample of each sensor (NaN: none yet)."""

    acc_norm: float = _number("m/s²", "‖y_a‖ of the latest accelerometer reading")
    g: float = _number("m/s²", "expected ‖y_a‖ at rest (setting `g`)")
    acc_gate: float = _number("m/s²", "the accelerometer norm gate in use (setting `acc_gate`)")
    acc_nis: float = _number(
        "-", "normalised innovation squared of the latest accelerometer update")
    acc_rejected_by: int = _code(
        "which gate rejected the latest accelerometer reading: 0 none, 1 norm gate, 2 NIS gate, "
        "3 clipped (an axis at the sensor's range)")
    mag_norm: float = _number("µT", "‖y_m‖ of the latest magnetometer reading")
    mag_expected: float = _number("µT", "L_k, the learned field strength (AR(1), task 11)")
    mag_gate: float = _number("µT", "the field-strength gate in use (setting `mag_gate`)")
    mag_nis: float = _number(
        "-", "normalised innovation squared of the latest magnetometer update")
    mag_dip_deg: float = _number(
        "deg", "measured angle between the latest field reading and up")
    mag_reference_dip_deg: float = _number(
        "deg", "angle between the reference field m0 and up: the dip gate's centre")
    mag_rejected_by: int = _code(
        "which gate rejected the latest magnetometer reading: 0 none, 1 strength gate, "
        "2 dip gate, 3 settling, 4 NIS gate, 5 uncalibrated (beyond any Earth field from the "
        "start: its offset is being acquired)")
    mag_offset_norm: float = _number(
        "µT", "‖b_m‖, the online hard-iron estimate subtracted from the readings")
    refused_samples: int = _output(
        0, int, "-", "samples refused as degenerate (a non-finite time or value, an axis beyond "
        "1e6, a zero-length acc or mag reading): each left the estimate as it was")


class OutputRow(NamedTuple):
    name: str
    unit: str
    doc: str


def output_rows(cls: type) -> list[OutputRow]:
    """The fields of :class:`Flags` or :class:`Diagnostics` with unit and explanation."""
    return [OutputRow(f.name, f.metadata["unit"], f.metadata["doc"]) for f in fields(cls)]
