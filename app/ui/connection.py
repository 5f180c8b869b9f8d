"""Connection panel: where the phone should connect, what arrives and who may connect.

Shows StreamHealth from the snapshot (addresses, port, state, rates, counters with the damaged
lines by reason, the connections closed, clock quirks, the recording); the replay's controls
are in the transport bar (app/ui/transport.py). While the phone streams, a
new device that connects waits: the panel asks "a new device at ADDRESS wants to stream:
accept?" (Accept / Ignore send AcceptConnection / IgnoreConnection). "Allow only" restricts who
may connect (SetAllowedNetworks; the same check as --allow). "Forward to" hands a copy of every
line from the phone to another server, such as the course kit's StreamSensorDataReader in MATLAB
(SetForward; the same as --forward), and shows what was sent and dropped.
"""

from __future__ import annotations

from typing import Callable

from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.commands import (AcceptConnection, IgnoreConnection, SetAllowedNetworks,
                                 SetForward)
from app.engine.config import ConfigError, allowed_networks, forward_target
from app.engine.snapshot import StreamHealth, lag_text
from app.stream.protocol import reasons_text

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
    """Stream health and who may connect. `send(command)` forwards connection commands."""

    def __init__(self, send: Callable[[object], None],
                 phone_apps: QtWidgets.QWidget | None = None,
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self._send = send
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)

        listen_box = QtWidgets.QGroupBox("Phone connects to")
        listen_grid = QtWidgets.QGridLayout(listen_box)
        self.address_field = QtWidgets.QLineEdit()
        self.address_field.setReadOnly(True)
        self.address_field.setPlaceholderText("not listening")
        self.address_field.setToolTip("Type one of these into the phone's app (the Sensor "
                                      "Fusion app: address and port; Sensor Logger: its push "
                                      "URL)")
        self.copy_button = QtWidgets.QPushButton("Copy")
        self.copy_button.clicked.connect(self.copy_address)
        self.hint_label = QtWidgets.QLabel("")
        self.hint_label.setWordWrap(True)
        self.hint_label.setStyleSheet("color: #555555")
        listen_grid.addWidget(self.address_field, 0, 0)
        listen_grid.addWidget(self.copy_button, 0, 1)
        listen_grid.addWidget(self.hint_label, 1, 0, 1, 2)
        listen_grid.setColumnStretch(0, 1)
        layout.addWidget(listen_box)
        if phone_apps is not None:
            layout.addWidget(phone_apps)
        layout.addWidget(self._build_waiting_box())
        layout.addWidget(self._build_allow_box())
        layout.addWidget(self._build_forward_box())

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

    def _build_forward_box(self) -> QtWidgets.QGroupBox:
        box = QtWidgets.QGroupBox("Forward to (MATLAB kit)")
        box.setToolTip("Every line from the phone is also sent, verbatim and in order, to this "
                       "server, e.g. the course kit's StreamSensorDataReader in MATLAB; a slow "
                       "or absent receiver never slows the phone (its lines are dropped and "
                       "counted)")
        layout = QtWidgets.QGridLayout(box)
        self.forward_field = QtWidgets.QLineEdit()
        self.forward_field.setPlaceholderText("off (e.g. 127.0.0.1:3400)")
        self.forward_field.returnPressed.connect(self.toggle_forward)
        self.forward_button = QtWidgets.QPushButton("Forward")
        self.forward_button.clicked.connect(self.toggle_forward)
        self.forward_status = QtWidgets.QLabel("off")
        self.forward_status.setWordWrap(True)
        layout.addWidget(self.forward_field, 0, 0)
        layout.addWidget(self.forward_button, 0, 1)
        layout.addWidget(self.forward_status, 1, 0, 1, 2)
        self._forwarding: str | None = None
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
        if health.connect_to:
            text = ", ".join(health.connect_to)
        elif health.port is not None:
            addresses = health.listen_addresses or ["127.0.0.1"]
            text = ", ".join(f"{address}:{health.port}" for address in addresses)
        else:
            text = ""
        self._set_text(self.hint_label, health.connect_hint)
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
        self._update_forward(health)
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

    @staticmethod
    def _set_text(label: QtWidgets.QLabel, text: str) -> None:
        if label.text() != text:
            label.setText(text)

    # ---- forward to MATLAB ----------------------------------------------------------------

    def toggle_forward(self) -> None:
        """Forward: start forwarding to the field's HOST:PORT (a bad one is said under the
        field); Stop: stop it."""
        if self._forwarding is not None and self.sender() is self.forward_button:
            self._send(SetForward(None))
            return
        text = self.forward_field.text().strip()
        if not text:
            self._send(SetForward(None))
            return
        try:
            host, port = forward_target(text)
        except ConfigError as error:
            self._set_text(self.forward_status, "<span style='color:#b3261e'>"
                           f"{str(error).replace('--forward: ', '')}</span>")
            return
        self._send(SetForward(f"{host}:{port}"))

    def _update_forward(self, health: StreamHealth) -> None:
        status = health.forward
        target = status.target if status is not None and status.state != "stopped" else None
        if target != self._forwarding:
            self._forwarding = target
            self.forward_button.setText("Stop" if target else "Forward")
            if target and not self.forward_field.hasFocus():
                self.forward_field.setText(target)
        if status is None or status.state == "stopped":
            if self._forwarding is None and "color:#b3261e" not in self.forward_status.text():
                self._set_text(self.forward_status, "off")
            return
        text = status.summary().removeprefix(f"forward {status.target} ")
        if health.connection_state not in ("connected", "waiting", "disconnected"):
            text += " (forwards the live phone stream only)"
        if status.last_error and status.state != "connected":
            text += f"; {status.last_error}"
        self._set_text(self.forward_status, text)
