"""The course kit's three lights, three-state: Acc disturbed, Mag disturbed, Standstill.

States: "off" (the sensor behind the light is switched out of the filter), "ok", and
"disturbed" (for Standstill: "moving" / "still"). The tooltip gives the numbers behind the
decision, straight from FilterStatus.
"""

from __future__ import annotations

import math

from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.snapshot import FilterStatus

STATE_COLORS = {
    "off": QtGui.QColor(95, 98, 105),
    "ok": QtGui.QColor(40, 170, 70),
    "disturbed": QtGui.QColor(225, 55, 45),
    "moving": QtGui.QColor(40, 110, 60),
    "still": QtGui.QColor(60, 150, 255),
}


class Light(QtWidgets.QWidget):
    """A round lamp with a caption; `state` is one of STATE_COLORS."""

    def __init__(self, caption: str, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.caption = caption
        self.state = "off"
        self.setMinimumSize(96, 58)
        self.setSizePolicy(QtWidgets.QSizePolicy.Policy.Preferred,
                           QtWidgets.QSizePolicy.Policy.Fixed)

    def set_state(self, state: str, reason: str) -> None:
        if state not in STATE_COLORS:
            raise ValueError(f"unknown light state {state!r}")
        if state != self.state:
            self.state = state
            self.update()
        tooltip = f"{self.caption}: {state}\n{reason}"
        if tooltip != self.toolTip():
            self.setToolTip(tooltip)

    def paintEvent(self, event: QtGui.QPaintEvent) -> None:  # noqa: N802 (Qt name)
        painter = QtGui.QPainter(self)
        painter.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing)
        diameter = 26
        x = (self.width() - diameter) / 2
        color = STATE_COLORS[self.state]
        gradient = QtGui.QRadialGradient(x + diameter * 0.35, 4 + diameter * 0.35, diameter * 0.7)
        gradient.setColorAt(0.0, color.lighter(160))
        gradient.setColorAt(1.0, color)
        painter.setBrush(QtGui.QBrush(gradient))
        painter.setPen(QtGui.QPen(color.darker(160), 1.5))
        painter.drawEllipse(QtCore.QRectF(x, 4, diameter, diameter))
        painter.setPen(self.palette().color(QtGui.QPalette.ColorRole.WindowText))
        painter.drawText(QtCore.QRectF(0, 4 + diameter + 2, self.width(), 20),
                         QtCore.Qt.AlignmentFlag.AlignHCenter, self.caption)
        painter.end()


def _fmt(value: float, digits: int = 2) -> str:
    return "?" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def light_states(status: FilterStatus) -> dict[str, tuple[str, str]]:
    """(state, reason) for the lights "acc", "mag" and "standstill" from one FilterStatus."""
    enabled = status.sensors_enabled
    acc_reason = (f"‖a‖ = {_fmt(status.diagnostics.acc_norm)} m/s², g = {_fmt(status.diagnostics.g)}, "
                  f"gate {_fmt(status.diagnostics.acc_gate)}")
    if not enabled.get("acc", True):
        acc = ("off", "accelerometer switched off")
    else:
        acc = ("disturbed" if status.flags.acc_rejected else "ok", acc_reason)
    mag_reason = (f"‖m‖ = {_fmt(status.diagnostics.mag_norm, 1)} µT, expected {_fmt(status.diagnostics.mag_expected, 1)}, "
                  f"gate {_fmt(status.diagnostics.mag_gate, 1)}")
    if not enabled.get("mag", True):
        mag = ("off", "magnetometer switched off")
    else:
        mag = ("disturbed" if status.flags.mag_rejected else "ok", mag_reason)
    if not enabled.get("gyr", True) and not enabled.get("acc", True):
        standstill = ("off", "rest detection needs the gyroscope or the accelerometer")
    elif status.flags.at_rest:
        standstill = ("still", "the phone is at rest (gyro bias is being learned)")
    else:
        standstill = ("moving", "the phone is moving")
    return {"acc": acc, "mag": mag, "standstill": standstill}


class LightsPanel(QtWidgets.QWidget):
    """Three lights in a row: Acc disturbed, Mag disturbed, Standstill."""

    def __init__(self, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        layout = QtWidgets.QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self.lights = {"acc": Light("Acc disturbed"), "mag": Light("Mag disturbed"),
                       "standstill": Light("Standstill")}
        for light in self.lights.values():
            layout.addWidget(light)

    def update_status(self, status: FilterStatus) -> None:
        for name, (state, reason) in light_states(status).items():
            self.lights[name].set_state(state, reason)

    def states(self) -> dict[str, str]:
        return {name: light.state for name, light in self.lights.items()}
