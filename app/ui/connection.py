"""Connection panel: where the phone should connect, what arrives, who may connect, and replay
controls.

Shows StreamHealth from the snapshot (addresses, port, state, rates, counters with the damaged
lines by reason, the connections closed, clock quirks, the recording) and, while replaying,
play/pause, speed, loop and a seek slider that send ReplayControl. While the phone streams, a
new device that connects waits: the panel asks "a new device at ADDRESS wants to stream:
accept?" (Accept / Ignore send AcceptConnection / IgnoreConnection). "Allow only" restricts who
may connect (SetAllowedNetworks; the same check as --allow).
"""

from __future__ import annotations

from typing import Any, Callable

from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.commands import (AcceptConnection, IgnoreConnection, ReplayControl,
                                 SetAllowedNetworks)
from app.engine.config import ConfigError, allowed_networks
from app.engine.snapshot import StreamHealth, lag_text
from app.stream.protocol import reasons_text

SEEK_STEPS = 1000
SPEEDS = (0.25, 0.5, 1.0, 2.0, 5.0, 10.0)
STATE_COLORS = {"waiting": "#b07d00", "connected": "#1e8c3a", "disconnected": "#b3261e",
                "replaying": "#1f5fbf", "finished": "#555555"}


def waiting_text(peer: str) -> str:
    """The question for a device waiting to stream ("192.168.1.42:51234" -> its address)."""
    address = peer.rsplit(":", 1)[0] if ":" in peer else peer
    return f"A new device at {address} wants to stream: accept?"


def problems_text(health: StreamHealth) -> str:
    damaged = f"{health.damaged} damaged"
    if health.damaged_reasons:
        damaged += f" ({reasons_text(health.damaged_reasons)})"
    text = (f"{damaged}, {health.unknown} unknown, {health.out_of_order} out of order, "
            f"{health.too_long} too long")
    if health.connections_closed:
        text += f"; connections closed: {reasons_text(health.connections_closed)}"
    return text


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
        layout.addWidget(self._build_waiting_box())
        layout.addWidget(self._build_allow_box())

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
        self.recording_label = QtWidgets.QLabel("")
        self.recording_label.setWordWrap(True)
        form.addRow("Recording", self.recording_label)
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

    def _build_waiting_box(self) -> QtWidgets.QGroupBox:
        self.waiting_box = QtWidgets.QGroupBox("New device")
        box = QtWidgets.QHBoxLayout(self.waiting_box)
        self.waiting_label = QtWidgets.QLabel("")
        self.waiting_label.setWordWrap(True)
        self.accept_button = QtWidgets.QPushButton("Accept")
        self.accept_button.setToolTip("Let this device take over the stream (the current one "
                                      "is disconnected)")
        self.ignore_button = QtWidgets.QPushButton("Ignore")
        self.ignore_button.setToolTip("Close this device's connection; the phone keeps "
                                      "streaming")
        self.accept_button.clicked.connect(self.accept_waiting)
        self.ignore_button.clicked.connect(self.ignore_waiting)
        box.addWidget(self.waiting_label, 1)
        box.addWidget(self.accept_button)
        box.addWidget(self.ignore_button)
        self.waiting_box.setVisible(False)
        self._waiting_peer: str | None = None
        return self.waiting_box

    def _build_allow_box(self) -> QtWidgets.QGroupBox:
        box = QtWidgets.QGroupBox("Allow only")
        layout = QtWidgets.QGridLayout(box)
        self.allow_field = QtWidgets.QLineEdit()
        self.allow_field.setPlaceholderText("anyone (e.g. 192.168.1.42, 192.168.1.0/24)")
        self.allow_field.setToolTip("Addresses or networks that may connect, separated by "
                                    "commas; empty: anyone. Others are closed and counted.")
        self.allow_field.returnPressed.connect(self.apply_allow)
        self.allow_button = QtWidgets.QPushButton("Apply")
        self.allow_button.clicked.connect(self.apply_allow)
        self.allow_error = QtWidgets.QLabel("")
        self.allow_error.setStyleSheet("color: #b3261e")
        self.allow_error.setWordWrap(True)
        layout.addWidget(self.allow_field, 0, 0)
        layout.addWidget(self.allow_button, 0, 1)
        layout.addWidget(self.allow_error, 1, 0, 1, 2)
        self._allowed_shown: list[str] | None = None
        return box

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
        self._set_text(self.problems_label, problems_text(health))
        clock = list(health.clock_quirks)
        if health.reorder_window_ms > 100:
            clock.append(lag_text(health))
        self._set_text(self.quirks_label, "; ".join(clock) or "none")
        self._set_text(self.recording_label, health.recording or "off")
        self._update_waiting(health.waiting_peers)
        if health.allowed != self._allowed_shown and not self.allow_field.hasFocus():
            self._allowed_shown = list(health.allowed)
            self.allow_field.setText(", ".join(health.allowed))

    def _update_waiting(self, peers: list[str]) -> None:
        peer = peers[0] if peers else None
        if peer != self._waiting_peer:
            self._waiting_peer = peer
            if peer is not None:
                more = f" ({len(peers) - 1} more waiting)" if len(peers) > 1 else ""
                self.waiting_label.setText(waiting_text(peer) + more)
                self.waiting_label.setToolTip(peer)
        if self.waiting_box.isHidden() != (peer is None):
            self.waiting_box.setVisible(peer is not None)

    # ---- who may stream -------------------------------------------------------------------

    def accept_waiting(self) -> None:
        if self._waiting_peer is not None:
            self._send(AcceptConnection(self._waiting_peer))

    def ignore_waiting(self) -> None:
        if self._waiting_peer is not None:
            self._send(IgnoreConnection(self._waiting_peer))

    def apply_allow(self) -> None:
        """The allow field -> SetAllowedNetworks, or the problem shown under it."""
        try:
            networks = allowed_networks(self.allow_field.text())
        except ConfigError as error:
            self.allow_error.setText(str(error).replace("--allow: ", ""))
            return
        self.allow_error.setText("")
        self._allowed_shown = None           # show what the server applies
        self._send(SetAllowedNetworks(networks))

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
