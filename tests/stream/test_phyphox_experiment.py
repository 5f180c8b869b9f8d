"""Our phyphox experiment and its QR code: the file follows phyphox's file format
(phyphox-docs docs/file-format/), and the QR code decodes (zxing-cpp, an independent decoder)
to what phyphox loads from an offline QR code (docs/transferring-experiments.md: "phyphox",
the zip's CRC32 big endian, index 0 of 1 codes, the zip)."""

from __future__ import annotations

import io
import struct
import xml.etree.ElementTree as ElementTree
import zipfile
import zlib

import numpy as np
import pytest

from app.cli import main
from app.stream.phyphox_experiment import (FILE_NAME, experiment_xml, experiment_zip, qr_code,
                                           qr_payload, read_qr_payload)

zxingcpp = pytest.importorskip("zxingcpp")

#: Elements and attributes of the format that the experiment may use (file-format index.md,
#: input.md, views/basics.md), with the sensor types and rate strategies input.md lists.
ALLOWED = {"phyphox": {"version", "locale"}, "title": set(), "category": set(),
           "description": set(), "data-containers": set(), "container": {"size"},
           "input": set(), "sensor": {"type", "rate", "rateStrategy"},
           "output": {"component"}, "views": set(), "view": {"label"}, "info": {"label"}}
SENSOR_TYPES = {"accelerometer", "linear_acceleration", "gravity", "magnetic_field",
                "gyroscope", "humidity", "light", "pressure", "proximity", "temperature",
                "attitude", "custom"}
COMPONENTS = {"x", "y", "z", "t", "abs", "accuracy"}


def _decode(code) -> bytes:
    modules = np.array(list(code.matrix_iter(scale=4, border=4)), dtype=np.uint8)
    image = np.where(modules == 1, 0, 255).astype(np.uint8)
    found = zxingcpp.read_barcodes(image)
    assert len(found) == 1 and found[0].valid
    return found[0].bytes


def test_the_file_follows_the_format():
    root = ElementTree.fromstring(experiment_xml())
    assert root.tag == "phyphox" and tuple(map(int, root.get("version").split("."))) >= (1, 14)
    for element in root.iter():
        assert element.tag in ALLOWED, element.tag
        assert set(element.attrib) <= ALLOWED[element.tag], (element.tag, element.attrib)
    containers = [c.text for c in root.iter("container")]
    assert len(containers) == len(set(containers))
    types = []
    for sensor in root.iter("sensor"):
        types.append(sensor.get("type"))
        assert sensor.get("type") in SENSOR_TYPES
        assert float(sensor.get("rate")) == 0.0            # as fast as possible
        assert sensor.get("rateStrategy") == "request"     # every reading, none dropped
        components = {o.get("component") for o in sensor.iter("output")}
        assert components <= COMPONENTS and "t" in components
        assert {o.text for o in sensor.iter("output")} <= set(containers)
    assert types == ["accelerometer", "gyroscope", "magnetic_field", "attitude"]
    attitude = root.find("input/sensor[@type='attitude']")
    assert [o.get("component") for o in attitude.iter("output")] == ["t", "abs", "x", "y", "z"]


def test_the_qr_code_decodes_to_what_phyphox_loads():
    payload = _decode(qr_code())
    assert payload == qr_payload()
    assert payload[:7] == b"phyphox"
    crc, index, count = struct.unpack(">IBB", payload[7:13])
    assert (index, count) == (0, 1) and crc == zlib.crc32(payload[13:])
    with zipfile.ZipFile(io.BytesIO(payload[13:])) as archive:
        assert archive.namelist() == [FILE_NAME]
        assert archive.read(FILE_NAME).decode("utf-8") == experiment_xml()
    assert read_qr_payload(payload) == experiment_xml()
    assert experiment_zip() == experiment_zip()          # the same code every time


def test_a_damaged_payload_is_refused():
    payload = bytearray(qr_payload())
    payload[-5] ^= 0xFF
    with pytest.raises(ValueError, match="CRC32"):
        read_qr_payload(bytes(payload))
    with pytest.raises(ValueError, match="phyphox"):
        read_qr_payload(b"https://example.org")


def test_command_writes_the_file_and_the_code(tmp_path, capsys):
    out = tmp_path / "lab.phyphox"
    png = tmp_path / "lab.png"
    assert main(["phyphox-experiment", "-o", str(out), "--qr", str(png)]) == 0
    assert out.read_text(encoding="utf-8") == experiment_xml()
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["phyphox-experiment", "-o", str(tmp_path / "x.phyphox"), "--qr",
                 str(tmp_path / "x.gif")]) == 2
    assert "--qr: a .png or .svg file" in capsys.readouterr().err
    assert not (tmp_path / "x.phyphox").exists()
