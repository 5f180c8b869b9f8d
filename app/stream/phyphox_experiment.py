"""Orientation Lab's phyphox experiment: the .phyphox file, and the QR code that loads it.

The experiment (phyphox file format, phyphox-docs ``docs/file-format/``) records the four
sensors the filters and the comparison need, each as fast as the phone gives them
(``rate="0"``, ``rateStrategy="request"``): ``accelerometer`` (acceleration with g, m/s^2), ``gyroscope`` (rad/s),
``magnetic_field`` (uT) and ``attitude`` (the phone's own orientation, a quaternion with w in
the ``abs`` output), each with its time buffer.

The QR code holds the experiment itself (phyphox-docs ``docs/transferring-experiments.md``,
"Offline QR-Codes"): the bytes ``phyphox``, the CRC32 of the zip that follows (big endian),
this code's index and the number of codes (0 and 1), then a zip holding the .phyphox file.
The phone needs no connection to this PC to load it. docs/decisions/phyphox-qr.md says why.
"""

from __future__ import annotations

import io
import struct
import zipfile
import zlib
from dataclasses import dataclass
from xml.sax.saxutils import escape

import segno

#: The experiment's file name inside the zip and when written by `phyphox-experiment`.
FILE_NAME = "orientation-lab.phyphox"
TITLE = "Orientation Lab"
#: File format 1.14 (phyphox 1.1.10) brought ``rateStrategy``; "request" hands over every
#: reading as the system gives it, none grouped or dropped (attitude came with 1.9).
FORMAT_VERSION = "1.14"
QR_MAGIC = b"phyphox"
#: A data container of size 0 grows without limit, like the raw-sensor experiments phyphox
#: ships: what the phone measured while this PC did not fetch it is still there.
BUFFER_SIZE = 0


@dataclass(frozen=True)
class ExperimentSensor:
    """One <sensor> of the experiment: phyphox's type, the Sensor Fusion tag it becomes, and
    its buffers (time first, then the values in the order of the tag's line)."""

    type: str
    tag: str
    outputs: tuple[tuple[str, str], ...]     # (component, buffer), time first

    @property
    def buffers(self) -> tuple[str, ...]:
        return tuple(buffer for _, buffer in self.outputs)


SENSORS: tuple[ExperimentSensor, ...] = (
    ExperimentSensor("accelerometer", "ACC",
                     (("t", "acc_time"), ("x", "accX"), ("y", "accY"), ("z", "accZ"))),
    ExperimentSensor("gyroscope", "GYR",
                     (("t", "gyr_time"), ("x", "gyrX"), ("y", "gyrY"), ("z", "gyrZ"))),
    ExperimentSensor("magnetic_field", "MAG",
                     (("t", "mag_time"), ("x", "magX"), ("y", "magY"), ("z", "magZ"))),
    ExperimentSensor("attitude", "ORI",
                     (("t", "att_time"), ("abs", "attW"), ("x", "attX"), ("y", "attY"),
                      ("z", "attZ"))),
)

DESCRIPTION = ("Raw sensors and the phone's orientation for Orientation Lab on a PC.")
INSTRUCTION = ("Menu: Allow remote access. Type the address phyphox shows into Orientation "
               "Lab (File, Connect a phone); it starts the measurement.")


def _attribute(text: str) -> str:
    return escape(text, {'"': "&quot;"})


def experiment_xml(sensors: tuple[ExperimentSensor, ...] = SENSORS) -> str:
    """The .phyphox file (XML, UTF-8 text)."""
    lines = [f'<phyphox version="{FORMAT_VERSION}" locale="en">',
             f"<title>{TITLE}</title>",
             "<category>Orientation Lab</category>",
             f"<description>{escape(DESCRIPTION)}</description>",
             "<data-containers>"]
    for sensor in sensors:
        lines += [f'<container size="{BUFFER_SIZE}">{buffer}</container>'
                  for buffer in sensor.buffers]
    lines += ["</data-containers>", "<input>"]
    for sensor in sensors:
        lines.append(f'<sensor type="{sensor.type}" rate="0" rateStrategy="request">')
        lines += [f'<output component="{component}">{buffer}</output>'
                  for component, buffer in sensor.outputs]
        lines.append("</sensor>")
    lines += ["</input>", "<views>", '<view label="Orientation Lab">',
              f'<info label="{_attribute(INSTRUCTION)}"/>', "</view>", "</views>"]
    lines += ["</phyphox>", ""]
    return "\n".join(lines)


def experiment_zip(xml: str | None = None) -> bytes:
    """The experiment in a zip (one deflated member, a fixed date: the same bytes every
    time, so the QR code does not change from one run to the next)."""
    data = (xml if xml is not None else experiment_xml()).encode("utf-8")
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        info = zipfile.ZipInfo(FILE_NAME, date_time=(2024, 1, 1, 0, 0, 0))
        info.compress_type = zipfile.ZIP_DEFLATED
        archive.writestr(info, data, compress_type=zipfile.ZIP_DEFLATED, compresslevel=9)
    return buffer.getvalue()


def qr_payload(zip_bytes: bytes | None = None) -> bytes:
    """The bytes of the one offline QR code: ``phyphox``, CRC32 (big endian) of the zip, index
    0, count 1, the zip."""
    data = zip_bytes if zip_bytes is not None else experiment_zip()
    return QR_MAGIC + struct.pack(">I", zlib.crc32(data) & 0xFFFFFFFF) + bytes([0, 1]) + data


def read_qr_payload(payload: bytes) -> str:
    """The .phyphox text a QR payload carries, checked as phyphox checks it (magic, one code,
    CRC32, a zip with one .phyphox file); ValueError naming what is wrong."""
    if len(payload) < 13 or not payload.startswith(QR_MAGIC):
        raise ValueError("not a phyphox experiment QR code (no 'phyphox' header)")
    crc, index, count = struct.unpack(">IBB", payload[7:13])
    data = payload[13:]
    if (index, count) != (0, 1):
        raise ValueError(f"code {index + 1} of {count}: expected a single code")
    if zlib.crc32(data) & 0xFFFFFFFF != crc:
        raise ValueError("CRC32 does not match the data")
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        names = [name for name in archive.namelist() if name.endswith(".phyphox")]
        if len(names) != 1:
            raise ValueError(f"expected one .phyphox file in the zip, found {len(names)}")
        return archive.read(names[0]).decode("utf-8")


def qr_code(payload: bytes | None = None) -> segno.QRCode:
    """The QR code (byte mode, one segment, error correction M) of :func:`qr_payload`."""
    return segno.make_qr(payload if payload is not None else qr_payload(), mode="byte",
                         error="m", boost_error=False)
