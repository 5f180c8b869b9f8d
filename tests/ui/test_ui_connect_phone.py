"""File → Connect a phone… and the connection panel's other phone apps: the steps carry this
PC's addresses, phyphox's QR code as drawn decodes to what phyphox loads, the buttons switch
the window's source (through the engine's configuration checks)."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6 import QtCore, QtGui

from app.engine.snapshot import StreamHealth
from app.stream.phyphox_experiment import qr_payload
from app.ui.connection import ConnectionPanel, ConnectPhoneDialog, PhoneAppsBox

zxingcpp = pytest.importorskip("zxingcpp")


class Recorder:
    def __init__(self, answer: bool = True) -> None:
        self.calls: list[tuple[str, str]] = []
        self.answer = answer

    def __call__(self, app: str, where: str) -> bool:
        self.calls.append((app, where))
        return self.answer


def _gray(pixmap: QtGui.QPixmap) -> np.ndarray:
    image = pixmap.toImage().convertToFormat(QtGui.QImage.Format.Format_Grayscale8)
    width, height = image.width(), image.height()
    data = np.frombuffer(image.constBits(), np.uint8, image.bytesPerLine() * height)
    return data.reshape(height, image.bytesPerLine())[:, :width].copy()


def test_the_dialog_shows_each_apps_steps_with_this_pcs_address(qtbot):
    connect = Recorder()
    dialog = ConnectPhoneDialog(connect, addresses=["192.168.1.23", "10.0.0.7"])
    qtbot.addWidget(dialog)
    texts = [dialog.tabs.tabText(i) for i in range(dialog.tabs.count())]
    assert texts == ["Sensor Fusion (Android)", "phyphox (iPhone, Android)",
                     "Sensor Logger (iPhone, Android)"]
    words = {i: " ".join(label.text() for label in dialog.tabs.widget(i).findChildren(
        type(dialog.error))) for i in range(3)}
    assert "192.168.1.23" in words[0] and "3400" in words[0]
    assert "http://192.168.1.23:8000/" in words[2] and "http://10.0.0.7:8000/" in words[2]
    assert "Allow remote access" in words[1] and "Scan QR code" in words[1]


def test_the_qr_code_on_screen_decodes_to_our_experiment(qtbot):
    dialog = ConnectPhoneDialog(Recorder(), addresses=["127.0.0.1"])
    qtbot.addWidget(dialog)
    found = zxingcpp.read_barcodes(_gray(dialog.qr_label.pixmap()))
    assert len(found) == 1 and found[0].bytes == qr_payload()


def test_the_dialog_connects_phyphox_and_says_a_bad_address(qtbot):
    connect = Recorder()
    dialog = ConnectPhoneDialog(connect, addresses=["127.0.0.1"])
    qtbot.addWidget(dialog)
    dialog.phyphox_field.setText("https://192.168.1.5")
    dialog.phyphox_button.click()
    assert connect.calls == [] and "plain http" in dialog.error.text()
    dialog.phyphox_field.setText("192.168.1.5:8080")
    dialog.phyphox_button.click()
    assert connect.calls == [("phyphox", "http://192.168.1.5:8080")]
    assert dialog.result() == dialog.DialogCode.Accepted
    dialog.sensor_logger_button.click()
    dialog.sensor_fusion_button.click()
    assert connect.calls[1:] == [("sensor-logger", "8000"), ("sensor-fusion", "3400")]


def test_the_panel_box_switches_apps(qtbot):
    connect = Recorder()
    opened = []
    box = PhoneAppsBox(connect, lambda: opened.append(True))
    qtbot.addWidget(box)
    box.phyphox_field.setText("not a host:99999")
    box.phyphox_button.click()
    assert connect.calls == [] and box.error.text()
    box.phyphox_field.setText("http://10.1.2.3:8081")
    qtbot.keyClick(box.phyphox_field, QtCore.Qt.Key.Key_Return)
    box.sensor_logger_port.setValue(8123)
    box.sensor_logger_button.click()
    box.steps_button.click()
    assert connect.calls == [("phyphox", "http://10.1.2.3:8081"), ("sensor-logger", "8123")]
    assert opened == [True] and box.error.text() == ""


def test_the_panel_shows_what_to_type_and_how(qtbot):
    panel = ConnectionPanel(lambda command: None, PhoneAppsBox(Recorder(), lambda: None))
    qtbot.addWidget(panel)
    panel.update_health(StreamHealth(port=8000, listen_addresses=["192.168.1.23"],
                                     connect_to=["http://192.168.1.23:8000/"],
                                     connect_hint="listening on port 8000 for Sensor Logger"))
    assert panel.address_text() == "http://192.168.1.23:8000/"
    assert panel.hint_label.text() == "listening on port 8000 for Sensor Logger"
    panel.update_health(StreamHealth(port=3400, listen_addresses=["192.168.1.23"]))
    assert panel.address_text() == "192.168.1.23:3400" and panel.hint_label.text() == ""


def test_the_window_switches_to_phyphox(qtbot, settings_file, fake_engine):
    from app.engine.live.worker import Engine
    from app.stream.phyphox import PhyphoxSource
    from app.ui.main_window import MainWindow

    built = []

    def factory(app: str, where: str) -> Engine:
        built.append((app, where))
        return Engine(PhyphoxSource(where, timeout_s=0.3, retry_max_s=0.2), comparisons=False)

    window = MainWindow(fake_engine, settings=QtCore.QSettings(
        str(settings_file), QtCore.QSettings.Format.IniFormat), use_gl=False,
        phone_factory=factory)
    qtbot.addWidget(window)
    try:
        assert window.connect_action.text() == "&Connect a phone…"
        window.connect_action.trigger()
        dialog = window.connect_dialog
        dialog.phyphox_field.setText("127.0.0.1:9")
        dialog.phyphox_button.click()
        assert built == [("phyphox", "http://127.0.0.1:9")]
        assert fake_engine.stop_calls == 1 and window.engine.source.kind == "phyphox"
        assert "polling phyphox at http://127.0.0.1:9" in window.statusBar().currentMessage()
    finally:
        window.shutdown()
