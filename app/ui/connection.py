"""Connection panel: where the phone should connect, what arrives and who may connect.

Shows StreamHealth from the snapshot (addresses, port, state, rates, counters with the damaged
lines by reason, the connections closed, clock quirks, the recording); the replay's controls
are in the transport bar (app/ui/transport.py). While the phone streams, a
new device that connects waits: the panel asks "a new device at ADDRESS wants to stream:
accept?" (Accept / Ignore send AcceptConnection / IgnoreConnection). "Allow only" restricts who
may connect (SetAllowedNetworks; the same check as --allow). "Forward to" hands a copy of every
line from the phone to another server, such as the course kit's StreamSensorDataReader in MATLAB
(SetForward; the same as --forward), and shows what was sent and dropped.

Connecting any phone: File → Connect a phone… (ConnectPhoneDialog: per app the steps with this
PC's addresses, and for phyphox the QR code that loads our experiment) and the panel's box that
switches the source to phyphox, Sensor Logger or the Sensor Fusion app (PhoneAppsBox). Both
draw and forward intent only: `connect(app, where)` asks the window for an engine on the new
source ("sensor-fusion" with a port, "phyphox" with the address phyphox shows, "sensor-logger"
with a port); the address is checked by the engine's configuration first.
"""

from __future__ import annotations

from typing import Callable

from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.commands import (AcceptConnection, IgnoreConnection, SetAllowedNetworks,
                                 SetForward)
from app.engine.config import ConfigError, allowed_networks, forward_target, phyphox_url
from app.engine.snapshot import StreamHealth, lag_text
from app.stream.tcp_server import lan_ipv4_addresses
from app.stream.phyphox_experiment import qr_code
from app.stream.protocol import reasons_text
from app.stream.sensor_logger import DEFAULT_PORT as SENSOR_LOGGER_PORT
from app.stream.tcp_server import DEFAULT_PORT as SENSOR_FUSION_PORT

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


def phyphox_url_or_say(text: str, error: QtWidgets.QLabel) -> str | None:
    """The address typed for phyphox in its normal form, or None with the problem in `error`."""
    try:
        return phyphox_url(text)
    except ConfigError as problem:
        error.setText(str(problem).replace("--phyphox: ", ""))
        return None


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


# ---- connecting another phone app ----------------------------------------------------------

Connect = Callable[[str, str], bool]
ERROR_STYLE = "color: #b3261e"


def qr_pixmap(scale: int = 4) -> QtGui.QPixmap:
    """The phyphox QR code (app.stream.phyphox_experiment) as a pixmap, dark on white."""
    buffer = QtCore.QBuffer()
    buffer.open(QtCore.QIODevice.OpenModeFlag.WriteOnly)
    stream = _QtWriter(buffer)
    qr_code().save(stream, kind="png", scale=scale, border=4)
    pixmap = QtGui.QPixmap()
    pixmap.loadFromData(bytes(buffer.data()), "PNG")
    return pixmap


class _QtWriter:
    """A file-like writer into a QBuffer (segno writes to any object with write())."""

    def __init__(self, buffer: QtCore.QBuffer) -> None:
        self.buffer = buffer

    def write(self, data: bytes) -> int:
        self.buffer.write(bytes(data))
        return len(data)


def _steps(items: list[str]) -> QtWidgets.QLabel:
    label = QtWidgets.QLabel("<ol>" + "".join(f"<li>{item}</li>" for item in items) + "</ol>")
    label.setWordWrap(True)
    label.setTextFormat(QtCore.Qt.TextFormat.RichText)
    label.setTextInteractionFlags(QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
    label.setAlignment(QtCore.Qt.AlignmentFlag.AlignTop)
    return label


def _addresses(addresses: list[str], template: str) -> str:
    return " or ".join(f"<b>{template.format(address=a)}</b>" for a in addresses)


class ConnectPhoneDialog(QtWidgets.QDialog):
    """Per app (a tab each) the steps to connect the phone, with this PC's addresses; phyphox's
    tab shows the QR code that loads our experiment. Its buttons call `connect`."""

    def __init__(self, connect: Connect, parent: QtWidgets.QWidget | None = None,
                 addresses: list[str] | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle("Connect a phone")
        self.setObjectName("connect_phone_dialog")
        self._connect = connect
        self.addresses = addresses if addresses is not None else lan_ipv4_addresses()
        layout = QtWidgets.QVBoxLayout(self)
        intro = QtWidgets.QLabel("The phone and this PC must be on the same network (the same "
                                 "Wi-Fi). Pick the app the phone has:")
        intro.setWordWrap(True)
        layout.addWidget(intro)
        self.tabs = QtWidgets.QTabWidget()
        self.tabs.addTab(self._sensor_fusion_tab(), "Sensor Fusion (Android)")
        self.tabs.addTab(self._phyphox_tab(), "phyphox (iPhone, Android)")
        self.tabs.addTab(self._sensor_logger_tab(), "Sensor Logger (iPhone, Android)")
        layout.addWidget(self.tabs, 1)
        self.error = QtWidgets.QLabel("")
        self.error.setStyleSheet(ERROR_STYLE)
        self.error.setWordWrap(True)
        layout.addWidget(self.error)
        buttons = QtWidgets.QDialogButtonBox(QtWidgets.QDialogButtonBox.StandardButton.Close)
        buttons.rejected.connect(self.reject)
        layout.addWidget(buttons)

    # -- tabs -----------------------------------------------------------------------------------

    def _sensor_fusion_tab(self) -> QtWidgets.QWidget:
        tab = QtWidgets.QWidget()
        box = QtWidgets.QVBoxLayout(tab)
        port = SENSOR_FUSION_PORT
        box.addWidget(_steps([
            "Open the Sensor Fusion app and its <i>Stream</i> settings.",
            f"Type this PC's address {_addresses(self.addresses, '{address}')} and port "
            f"<b>{port}</b>.",
            "Turn on the sensors you want (accelerometer, gyroscope, magnetometer, "
            "orientation) and start streaming."]))
        self.sensor_fusion_button = self._listen_button(box, f"Listen for it on port {port}",
                                                        "sensor-fusion", port)
        return tab

    def _phyphox_tab(self) -> QtWidgets.QWidget:
        tab = QtWidgets.QWidget()
        row = QtWidgets.QHBoxLayout(tab)
        self.qr_label = QtWidgets.QLabel()
        self.qr_label.setObjectName("phyphox_qr")
        self.qr_label.setPixmap(qr_pixmap())
        self.qr_label.setToolTip("Orientation Lab's phyphox experiment: accelerometer (with g), "
                                 "gyroscope, magnetometer and attitude, as fast as the phone "
                                 "gives them")
        row.addWidget(self.qr_label, 0, QtCore.Qt.AlignmentFlag.AlignTop)
        column = QtWidgets.QVBoxLayout()
        column.addWidget(_steps([
            "Install phyphox (free, App Store or Google Play).",
            "In phyphox tap <b>+</b>, then <i>Scan QR code</i>, and scan this code: it loads "
            "the experiment <i>Orientation Lab</i> (or load the file written by "
            "<code>orientation-lab phyphox-experiment</code>).",
            "Open the experiment; in its menu tap <i>Allow remote access</i>. phyphox shows an "
            "address like <b>http://192.168.1.5:8080</b>.",
            "Type that address here and press Connect: Orientation Lab starts the measurement "
            "and polls the phone."]))
        form = QtWidgets.QHBoxLayout()
        self.phyphox_field = QtWidgets.QLineEdit()
        self.phyphox_field.setPlaceholderText("http://192.168.1.5:8080")
        self.phyphox_field.returnPressed.connect(self._phyphox)
        self.phyphox_button = QtWidgets.QPushButton("Connect")
        self.phyphox_button.clicked.connect(self._phyphox)
        form.addWidget(self.phyphox_field, 1)
        form.addWidget(self.phyphox_button)
        column.addLayout(form)
        column.addStretch(1)
        row.addLayout(column, 1)
        return tab

    def _sensor_logger_tab(self) -> QtWidgets.QWidget:
        tab = QtWidgets.QWidget()
        box = QtWidgets.QVBoxLayout(tab)
        port = SENSOR_LOGGER_PORT
        urls = _addresses(self.addresses, "http://{address}:" + str(port) + "/")
        box.addWidget(_steps([
            "Install Sensor Logger (free, App Store or Google Play).",
            "In its settings turn on <i>HTTP Push</i> and type the push URL " + urls + ".",
            "Turn on the sensors <i>Accelerometer</i>, <i>Gravity</i>, <i>Gyroscope</i>, "
            "<i>Magnetometer</i> and <i>Orientation</i> (on Android also <i>Total "
            "Acceleration</i>). <i>Standardise Units &amp; Frames</i> may be on or off.",
            "Press Listen here, tap <i>Tap to Test Pushing</i> in Sensor Logger, then start a "
            "recording."]))
        self.sensor_logger_button = self._listen_button(box, f"Listen on port {port}",
                                                        "sensor-logger", port)
        return tab

    def _listen_button(self, box: QtWidgets.QVBoxLayout, text: str, app: str,
                       port: int) -> QtWidgets.QPushButton:
        """The tab's last widget: a button that listens for `app` on `port`."""
        button = QtWidgets.QPushButton(text)
        button.clicked.connect(lambda: self._go(app, str(port)))
        box.addWidget(button, 0, QtCore.Qt.AlignmentFlag.AlignLeft)
        box.addStretch(1)
        return button

    # -- actions --------------------------------------------------------------------------------

    def _phyphox(self) -> None:
        url = phyphox_url_or_say(self.phyphox_field.text(), self.error)
        if url is not None:
            self._go("phyphox", url)

    def _go(self, app: str, where: str) -> None:
        self.error.setText("")
        if self._connect(app, where):
            self.accept()


class PhoneAppsBox(QtWidgets.QGroupBox):
    """The connection panel's way to another phone app: phyphox's address, Sensor Logger's
    port, the Sensor Fusion app, and the steps (Connect a phone…)."""

    def __init__(self, connect: Connect, open_dialog: Callable[[], None],
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__("Other phone apps", parent)
        self._connect = connect
        grid = QtWidgets.QGridLayout(self)
        self.phyphox_field = QtWidgets.QLineEdit()
        self.phyphox_field.setPlaceholderText("address phyphox shows, http://…:8080")
        self.phyphox_field.setToolTip("phyphox (iPhone, Android): the address it shows under "
                                      "Allow remote access")
        self.phyphox_field.returnPressed.connect(self.connect_phyphox)
        self.phyphox_button = QtWidgets.QPushButton("phyphox")
        self.phyphox_button.setToolTip("Poll phyphox at this address")
        self.phyphox_button.clicked.connect(self.connect_phyphox)
        self.sensor_logger_port = QtWidgets.QSpinBox()
        self.sensor_logger_port.setRange(1, 65535)
        self.sensor_logger_port.setValue(SENSOR_LOGGER_PORT)
        self.sensor_logger_button = QtWidgets.QPushButton("Sensor Logger")
        self.sensor_logger_button.setToolTip("Take Sensor Logger's HTTP Push on this port; the "
                                             "URL to type into it is shown above")
        self.sensor_logger_button.clicked.connect(
            lambda: self._go("sensor-logger", str(self.sensor_logger_port.value())))
        self.sensor_fusion_button = QtWidgets.QPushButton("Sensor Fusion")
        self.sensor_fusion_button.setToolTip(f"Listen for the Sensor Fusion app on port "
                                             f"{SENSOR_FUSION_PORT}")
        self.sensor_fusion_button.clicked.connect(
            lambda: self._go("sensor-fusion", str(SENSOR_FUSION_PORT)))
        self.steps_button = QtWidgets.QPushButton("Steps and QR code…")
        self.steps_button.clicked.connect(open_dialog)
        self.error = QtWidgets.QLabel("")
        self.error.setStyleSheet(ERROR_STYLE)
        self.error.setWordWrap(True)
        grid.addWidget(self.phyphox_field, 0, 0)
        grid.addWidget(self.phyphox_button, 0, 1)
        grid.addWidget(self.sensor_logger_port, 1, 0)
        grid.addWidget(self.sensor_logger_button, 1, 1)
        grid.addWidget(self.sensor_fusion_button, 2, 1)
        grid.addWidget(self.steps_button, 2, 0)
        grid.addWidget(self.error, 3, 0, 1, 2)
        grid.setColumnStretch(0, 1)

    def connect_phyphox(self) -> None:
        url = phyphox_url_or_say(self.phyphox_field.text(), self.error)
        if url is not None:
            self._go("phyphox", url)

    def _go(self, app: str, where: str) -> None:
        self.error.setText("")
        self._connect(app, where)
