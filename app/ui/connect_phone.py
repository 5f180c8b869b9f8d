"""Connecting any phone: File → Connect a phone… (per app the steps with this PC's addresses,
and for phyphox the QR code that loads our experiment) and the connection panel's box that
switches the source to phyphox, Sensor Logger or the Sensor Fusion app.

Draws and forwards intent only: `connect(app, where)` asks the window for an engine on the
new source ("sensor-fusion" with a port, "phyphox" with the address phyphox shows,
"sensor-logger" with a port); the address is checked by the engine's configuration first.
"""

from __future__ import annotations

from typing import Callable

from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.config import ConfigError, phyphox_url
from app.stream.phyphox_experiment import qr_code
from app.stream.sensor_logger import DEFAULT_PORT as SENSOR_LOGGER_PORT
from app.stream.tcp_server import DEFAULT_PORT as SENSOR_FUSION_PORT
from app.stream.tcp_server import lan_ipv4_addresses

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
        self.sensor_fusion_button = QtWidgets.QPushButton(f"Listen for it on port {port}")
        self.sensor_fusion_button.clicked.connect(
            lambda: self._go("sensor-fusion", str(port)))
        box.addWidget(self.sensor_fusion_button, 0, QtCore.Qt.AlignmentFlag.AlignLeft)
        box.addStretch(1)
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
        self.sensor_logger_button = QtWidgets.QPushButton(f"Listen on port {port}")
        self.sensor_logger_button.clicked.connect(
            lambda: self._go("sensor-logger", str(port)))
        box.addWidget(self.sensor_logger_button, 0, QtCore.Qt.AlignmentFlag.AlignLeft)
        box.addStretch(1)
        return tab

    # -- actions --------------------------------------------------------------------------------

    def _phyphox(self) -> None:
        text = self.phyphox_field.text().strip()
        try:
            url = phyphox_url(text)
        except ConfigError as error:
            self.error.setText(str(error).replace("--phyphox: ", ""))
            return
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
        try:
            url = phyphox_url(self.phyphox_field.text())
        except ConfigError as error:
            self.error.setText(str(error).replace("--phyphox: ", ""))
            return
        self._go("phyphox", url)

    def _go(self, app: str, where: str) -> None:
        self.error.setText("")
        self._connect(app, where)
