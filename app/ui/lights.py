"""The course kit's three lights: Acc, Mag and Standstill, with words and colours that agree.

* grey "off": the sensor is switched out of the filter, or no data has arrived for it yet;
* green "OK": the latest reading passed its gates;
* red (accelerometer) / amber (magnetometer) "disturbed": a gate fired; the tooltip names the
  gate (norm, NIS; strength, dip, settling, NIS) with the numbers behind it;
* Standstill: blue "still" / grey "moving" (neither good nor bad), grey "off" without gyro and
  accelerometer.
"""

from __future__ import annotations

import math

from PySide6 import QtCore, QtGui, QtWidgets

from ekf import diagnostics as outputs
from app.engine.snapshot import FilterStatus

STATE_COLORS = {
    "off": QtGui.QColor(150, 152, 158),
    "no data": QtGui.QColor(150, 152, 158),
    "ok": QtGui.QColor(40, 170, 70),
    "acc disturbed": QtGui.QColor(225, 55, 45),
    "mag disturbed": QtGui.QColor(240, 160, 20),
    "calibrating": QtGui.QColor(160, 100, 210),
    "moving": QtGui.QColor(150, 152, 158),
    "still": QtGui.QColor(60, 140, 245),
}
COMPACT_LAMP_PX = 14
CAPTIONS = {"off": "off", "no data": "no data", "ok": "OK", "acc disturbed": "disturbed",
            "mag disturbed": "disturbed", "calibrating": "calibrating", "moving": "moving",
            "still": "still"}


class Light(QtWidgets.QWidget):
    """A round lamp with a caption "<name> <state>"; `state` is one of STATE_COLORS. compact: a
    smaller lamp with the two lines of its caption beside it (a panel short of height)."""

    def __init__(self, name: str, parent: QtWidgets.QWidget | None = None,
                 compact: bool = False) -> None:
        super().__init__(parent)
        self.name = name
        self.state = "no data"
        self.compact = compact
        if compact:
            metrics = self.fontMetrics()
            text = max(metrics.horizontalAdvance(text) for text in (name, *CAPTIONS.values()))
            self.setMinimumSize(COMPACT_LAMP_PX + 8 + text, 2 * metrics.height() + 2)
        else:
            self.setMinimumSize(84, 60)
        self.setSizePolicy(QtWidgets.QSizePolicy.Policy.Preferred,
                           QtWidgets.QSizePolicy.Policy.Fixed)
        self.setToolTip(f"{name}: no data yet")

    @property
    def caption(self) -> str:
        return f"{self.name} {CAPTIONS[self.state]}"

    def set_state(self, state: str, reason: str) -> None:
        if state not in STATE_COLORS:
            raise ValueError(f"unknown light state {state!r}")
        if state != self.state:
            self.state = state
            self.update()
        tooltip = f"{self.caption}\n{reason}"
        if tooltip != self.toolTip():
            self.setToolTip(tooltip)

    def paintEvent(self, event: QtGui.QPaintEvent) -> None:  # noqa: N802 (Qt name)
        painter = QtGui.QPainter(self)
        painter.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing)
        color = STATE_COLORS[self.state]
        if self.compact:
            diameter = COMPACT_LAMP_PX
            x, y = 2.0, (self.height() - diameter) / 2
        else:
            diameter = 24
            x, y = (self.width() - diameter) / 2, 4.0
        gradient = QtGui.QRadialGradient(x + diameter * 0.35, y + diameter * 0.35,
                                         diameter * 0.7)
        gradient.setColorAt(0.0, color.lighter(150))
        gradient.setColorAt(1.0, color)
        painter.setBrush(QtGui.QBrush(gradient))
        painter.setPen(QtGui.QPen(color.darker(150), 1.5))
        painter.drawEllipse(QtCore.QRectF(x, y, diameter, diameter))
        painter.setPen(self.palette().color(QtGui.QPalette.ColorRole.WindowText))
        if self.compact:
            left = x + diameter + 5
            painter.drawText(QtCore.QRectF(left, 0, self.width() - left, self.height()),
                             QtCore.Qt.AlignmentFlag.AlignVCenter,
                             f"{self.name}\n{CAPTIONS[self.state]}")
        else:
            # two lines (the name, then its state), so a narrow dock never cuts the state off
            painter.drawText(QtCore.QRectF(0, 4 + diameter + 1, self.width(), 36),
                             QtCore.Qt.AlignmentFlag.AlignHCenter,
                             f"{self.name}\n{CAPTIONS[self.state]}")
        painter.end()


def _fmt(value: float, digits: int = 2) -> str:
    return "?" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _acc_light(status: FilterStatus, has_data: bool) -> tuple[str, str]:
    d = status.diagnostics
    if not status.sensors_enabled.get("acc", True):
        return "off", "accelerometer switched off"
    if not has_data or not math.isfinite(d.acc_norm):
        return "no data", "no accelerometer reading yet"
    numbers = (f"‖a‖ = {_fmt(d.acc_norm)} m/s², expected g = {_fmt(d.g)} m/s², "
               f"norm gate ±{_fmt(d.acc_gate)} m/s² (|‖a‖ − g| = {_fmt(abs(d.acc_norm - d.g))})")
    if not status.flags.acc_rejected:
        return "ok", numbers
    if d.acc_rejected_by == outputs.ACC_NIS_GATE:
        return "acc disturbed", f"NIS gate fired: NIS = {_fmt(d.acc_nis)}\n{numbers}"
    return "acc disturbed", f"norm gate fired: |‖a‖ − g| > gate\n{numbers}"


def _mag_light(status: FilterStatus, has_data: bool) -> tuple[str, str]:
    d = status.diagnostics
    if not status.sensors_enabled.get("mag", True):
        return "off", "magnetometer switched off"
    if not has_data or not math.isfinite(d.mag_norm):
        return "no data", "no magnetometer reading yet"
    strength = (f"‖m‖ = {_fmt(d.mag_norm, 1)} µT, expected L = {_fmt(d.mag_expected, 1)} µT, "
                f"strength gate ±{_fmt(d.mag_gate, 1)} µT")
    dip = (f"dip {_fmt(d.mag_dip_deg, 1)}° (reference {_fmt(d.mag_reference_dip_deg, 1)}°)"
           if math.isfinite(d.mag_dip_deg) else "")
    numbers = strength + (f"\n{dip}" if dip else "")
    if not status.flags.mag_rejected:
        return "ok", numbers
    if d.mag_rejected_by == outputs.MAG_UNCALIBRATED:
        return "calibrating", ("uncalibrated: beyond any Earth field; its offset is being "
                               "learned while the phone turns (turn it about every axis)\n"
                               + numbers)
    reason = {outputs.MAG_STRENGTH_GATE: "strength gate fired: |‖m‖ − L| > gate",
              outputs.MAG_DIP_GATE: "dip gate fired: the field's angle to up is off",
              outputs.MAG_SETTLING: "settling: readings pass the gates again, but not yet for "
                                    "long enough",
              outputs.MAG_NIS_GATE: f"NIS gate fired: NIS = {_fmt(d.mag_nis)}",
              }.get(d.mag_rejected_by, "rejected")
    return "mag disturbed", f"{reason}\n{numbers}"


def light_states(status: FilterStatus, has_data: bool = True) -> dict[str, tuple[str, str]]:
    """(state, reason) for the lights "acc", "mag" and "standstill" from one FilterStatus;
    has_data: the stream has delivered samples (else every light is grey "no data")."""
    enabled = status.sensors_enabled
    if not enabled.get("gyr", True) and not enabled.get("acc", True):
        standstill = ("off", "rest detection needs the gyroscope or the accelerometer")
    elif not has_data:
        standstill = ("no data", "no samples yet")
    elif status.flags.at_rest:
        standstill = ("still", "the phone is at rest (the gyroscope bias is being learned)")
    else:
        standstill = ("moving", "the phone is moving")
    return {"acc": _acc_light(status, has_data), "mag": _mag_light(status, has_data),
            "standstill": standstill}


class LightsPanel(QtWidgets.QWidget):
    """Three lights in a row: Acc, Mag, Standstill."""

    def __init__(self, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        layout = QtWidgets.QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self.lights = {"acc": Light("Acc"), "mag": Light("Mag"),
                       "standstill": Light("Standstill")}
        for light in self.lights.values():
            layout.addWidget(light)

    def update_status(self, status: FilterStatus, has_data: bool = True) -> None:
        for name, (state, reason) in light_states(status, has_data).items():
            self.lights[name].set_state(state, reason)

    def states(self) -> dict[str, str]:
        return {name: light.state for name, light in self.lights.items()}
