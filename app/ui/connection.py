"""Connection panel: where the phone should connect, what arrives, and replay controls.

Shows StreamHealth from the snapshot (addresses, port, state, rates, counters, clock quirks)
and, while replaying, play/pause, speed, loop and a seek slider that send ReplayControl.
"""

from __future__ import annotations

from typing import Any, Callable

from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.commands import ReplayControl
from app.engine.snapshot import StreamHealth

SEEK_STEPS = 1000
SPEEDS = (0.25, 0.5, 1.0, 2.0, 5.0, 10.0)
STATE_COLORS = {"waiting": "#b07d00", "connected": "#1e8c3a", "disconnected": "#b3261e",
                "replaying": "#1f5fbf", "finished": "#555555"}


def connection_text(health: StreamHealth) -> str:
    """One line for the state: waiting / connected from ADDRESS / disconnected / replaying."""
    state = health.connection_state
    if state == "connected":
        return f"connected from {health.peer}" if health.peer else "connected"
    if state == "waiting":
        return f"waiting for the phone on port {health.port}" if health.port else "waiting"
    return state


class ConnectionPanel(QtWidgets.QWidget):
    """Stream health and replay controls. `send(command)` forwards ReplayControl commands."""

    def __init__(self, send: Callable[[object], None],
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self._send = send
        self._seeking = False
        self._replay: dict[str, Any] | None = None
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)

        listen_box = QtWidgets.QGroupBox("Phone connects to")
        listen_layout = QtWidgets.QHBoxLayout(listen_box)
        self.address_field = QtWidgets.QLineEdit()
        self.address_field.setReadOnly(True)
        self.address_field.setPlaceholderText("not listening")
        self.address_field.setToolTip("Type one of these addresses and the port into the "
                                      "Sensor Fusion app")
        self.copy_button = QtWidgets.QPushButton("Copy")
        self.copy_button.clicked.connect(self.copy_address)
        listen_layout.addWidget(self.address_field, 1)
        listen_layout.addWidget(self.copy_button)
        layout.addWidget(listen_box)

        stream_box = QtWidgets.QGroupBox("Stream")
        form = QtWidgets.QFormLayout(stream_box)
        self.state_label = QtWidgets.QLabel("waiting")
        self.state_label.setTextInteractionFlags(
            QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        self.rates_label = QtWidgets.QLabel("–")
        self.lines_label = QtWidgets.QLabel("–")
        self.problems_label = QtWidgets.QLabel("–")
        self.quirks_label = QtWidgets.QLabel("none")
        for label in (self.rates_label, self.problems_label, self.quirks_label):
            label.setWordWrap(True)
        form.addRow("State", self.state_label)
        form.addRow("Rates", self.rates_label)
        form.addRow("Lines", self.lines_label)
        form.addRow("Problems", self.problems_label)
        form.addRow("Clock", self.quirks_label)
        layout.addWidget(stream_box)

        self.replay_box = QtWidgets.QGroupBox("Replay")
        replay_layout = QtWidgets.QGridLayout(self.replay_box)
        self.play_button = QtWidgets.QPushButton("Pause")
        self.play_button.setToolTip("Play / pause the replay (Space)")
        self.play_button.clicked.connect(self.toggle_replay_paused)
        self.speed_combo = QtWidgets.QComboBox()
        for speed in SPEEDS:
            self.speed_combo.addItem(f"{speed:g}×", speed)
        self.speed_combo.setCurrentIndex(SPEEDS.index(1.0))
        self.speed_combo.activated.connect(
            lambda index: self._send(ReplayControl(speed=float(self.speed_combo.itemData(index)))))
        self.loop_checkbox = QtWidgets.QCheckBox("Loop")
        self.loop_checkbox.clicked.connect(lambda checked: self._send(ReplayControl(loop=checked)))
        self.seek_slider = QtWidgets.QSlider(QtCore.Qt.Orientation.Horizontal)
        self.seek_slider.setRange(0, SEEK_STEPS)
        self.seek_slider.sliderPressed.connect(self._on_seek_pressed)
        self.seek_slider.sliderReleased.connect(self._on_seek_released)
        # Clicks on the groove and arrow keys change the value without a drag.
        self.seek_slider.valueChanged.connect(self._on_seek_value_changed)
        self.position_label = QtWidgets.QLabel("0.0 / 0.0 s")
        replay_layout.addWidget(self.play_button, 0, 0)
        replay_layout.addWidget(self.speed_combo, 0, 1)
        replay_layout.addWidget(self.loop_checkbox, 0, 2)
        replay_layout.addWidget(self.seek_slider, 1, 0, 1, 2)
        replay_layout.addWidget(self.position_label, 1, 2)
        self.replay_box.setVisible(False)
        layout.addWidget(self.replay_box)
        layout.addStretch(1)

    # ---- listening address ----------------------------------------------------------------

    def address_text(self) -> str:
        return self.address_field.text()

    def copy_address(self) -> None:
        """Put the first address:port on the clipboard (the one most likely on the LAN)."""
        text = self.address_field.text().split(",")[0].strip()
        if text:
            QtGui.QGuiApplication.clipboard().setText(text)

    # ---- snapshot -> widgets --------------------------------------------------------------

    def update_health(self, health: StreamHealth) -> None:
        if health.port is not None:
            addresses = health.listen_addresses or ["127.0.0.1"]
            text = ", ".join(f"{address}:{health.port}" for address in addresses)
        else:
            text = ""
        if text != self.address_field.text():
            self.address_field.setText(text)
        color = STATE_COLORS.get(health.connection_state, "#333333")
        self._set_text(self.state_label,
                       f"<b style='color:{color}'>{connection_text(health)}</b>")
        rates = "  ".join(f"{tag} {rate:.0f} Hz" for tag, rate in sorted(health.rates_hz.items())
                          if rate > 0)
        self._set_text(self.rates_label, rates or "–")
        self._set_text(self.lines_label,
                       f"{health.lines_per_s:.0f} lines/s, {health.lines_total} total")
        self._set_text(self.problems_label,
                       f"{health.damaged} damaged, {health.unknown} unknown, "
                       f"{health.out_of_order} out of order, {health.too_long} too long")
        self._set_text(self.quirks_label, "; ".join(health.clock_quirks) or "none")

    def update_replay(self, replay: dict[str, Any] | None) -> None:
        """Follow the replay's state (every frame: only changed widgets are touched)."""
        self._replay = replay
        if self.replay_box.isHidden() != (replay is None):
            self.replay_box.setVisible(replay is not None)
        if replay is None:
            return
        paused = bool(replay.get("paused", False))
        if self.play_button.text() != ("Play" if paused else "Pause"):
            self.play_button.setText("Play" if paused else "Pause")
        speed = float(replay.get("speed", 1.0))
        index = self.speed_combo.findData(speed)
        if index < 0:
            self.speed_combo.addItem(f"{speed:g}×", speed)
            index = self.speed_combo.count() - 1
        if index != self.speed_combo.currentIndex():
            self.speed_combo.setCurrentIndex(index)
        if self.loop_checkbox.isChecked() != bool(replay.get("loop", False)):
            self.loop_checkbox.setChecked(bool(replay.get("loop", False)))
        position = float(replay.get("position_s", 0.0))
        duration = float(replay.get("duration_s", 0.0))
        if not self._seeking and duration > 0:
            self.seek_slider.blockSignals(True)
            self.seek_slider.setValue(int(round(SEEK_STEPS * min(position / duration, 1.0))))
            self.seek_slider.blockSignals(False)
        self._set_text(self.position_label, f"{position:.1f} / {duration:.1f} s")

    @property
    def replaying(self) -> bool:
        return self._replay is not None

    # ---- user intent -> commands ----------------------------------------------------------

    def toggle_replay_paused(self) -> None:
        if self._replay is None:
            return
        paused = not bool(self._replay.get("paused", False))
        self._replay = {**self._replay, "paused": paused}   # until the engine confirms
        self.play_button.setText("Play" if paused else "Pause")
        self._send(ReplayControl(paused=paused))

    def _on_seek_pressed(self) -> None:
        self._seeking = True

    def _on_seek_released(self) -> None:
        self._seeking = False
        self.seek_to_fraction(self.seek_slider.value() / SEEK_STEPS)

    def _on_seek_value_changed(self, value: int) -> None:
        if not self._seeking and not self.seek_slider.isSliderDown():
            self.seek_to_fraction(value / SEEK_STEPS)

    def seek_to_fraction(self, fraction: float) -> None:
        if self._replay is None:
            return
        duration = float(self._replay.get("duration_s", 0.0))
        self._send(ReplayControl(seek_s=max(0.0, min(fraction, 1.0)) * duration))

    @staticmethod
    def _set_text(label: QtWidgets.QLabel, text: str) -> None:
        if label.text() != text:
            label.setText(text)
