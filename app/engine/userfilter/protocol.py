"""The wire between the engine and your filter's process: frames of a JSON header and raw arrays.

A frame is ``MAGIC`` (4 bytes), the header's length (uint32, little-endian), the header (a UTF-8
JSON object) and then the arrays the header lists under ``"arrays"`` as ``[name, dtype, shape]``,
each as its raw bytes in C order (dtypes ``<f8``, ``<i4``, ``|i1``, ``|u1``). A reader hands
bytes found between frames on as text: a child may write its frames into the same stream as its
prints (an Octave host writing to its stdout); the Python child keeps the two apart.

Requests (engine -> child), each answered by exactly one reply with the same ``op``, in order:

``start``    header: path, name, settings (:func:`settings_to_wire`), step_limit_s, load_limit_s;
             array ``source`` (the file's bytes, the ones the engine hashed). Reply: problem
             (None, or the file does not load / ``Filter()`` failed), missing, notes.
``rows``     header: id, epoch, innovations (false: nobody shows this block's innovations, a
             host may leave them out); arrays ``t`` (n,) seconds, ``given`` (n, 3) which of gyr,
             acc, mag each row gives your filter (1) or passes as None (0), ``values`` (n, 9) the
             three sensors' values. Reply: id, epoch, run (rows stepped), seconds (time in your
             step), elapsed (the block's time in the child), paused_at (the row where it paused,
             -1: not paused), last_out (the row whose output is the latest, -1: none in this
             block), problem, missing, notes; arrays
             ``q`` (n, 4) the latest output after each row (NaN: none yet), ``flags`` (n, 3) the
             latest output's acc_disturbed, mag_disturbed, standstill (-1: not reported), ``P``
             (4, 4) the latest output's covariance of q (absent: none), and the innovations
             returned in the block: ``inn_row`` (m,), ``inn_sensor`` (m,) (INNOVATION_SENSORS
             codes), ``inn_nu`` (m, 3) and ``inn_S`` (m, 3, 3) NaN-padded, ``inn_accepted`` (m,).
``reset``    header: epoch, settings (None: the same), fresh (also forget a problem): a new
             Filter object. Reply: problem, missing, notes.
``snapshot`` Reply: error (None: ok); array ``state``: the filter's state as opaque bytes.
``restore``  array ``state``. Reply: error, problem.

While it works through a long block the child sends ``progress`` frames (header: done) at least
every PROGRESS_S: a child that sends nothing while it owes a reply is in one call of your code.
"""

from __future__ import annotations

import json
import math
import struct
from typing import Any

import numpy as np

MAGIC = b"OLF1"
PROGRESS_S = 0.5
MAX_HEADER = 1 << 24
INNOVATION_SENSORS = ("acc", "mag", "gyr")
DTYPES = ("<f8", "<i4", "|i1", "|u1")
SETTINGS_ARRAYS = ("g0", "m0", "Rw", "Ra", "Rm", "gyr_bias")
PROBLEM_FIELDS = ("kind", "message", "details", "file", "line", "function", "t_s")

Arrays = dict[str, np.ndarray]


class ProtocolError(Exception):
    """A frame that is not one."""


def encode(header: dict[str, Any], arrays: Arrays | None = None) -> bytes:
    """One frame: the header (with the arrays' names, dtypes and shapes added) and the arrays."""
    arrays = arrays or {}
    listed, blobs = [], []
    for name, array in arrays.items():
        array = np.ascontiguousarray(array)
        dtype = array.dtype.str
        if dtype not in DTYPES:
            array = array.astype("<f8") if array.dtype.kind == "f" else array
            dtype = array.dtype.str
        if dtype not in DTYPES:
            raise ProtocolError(f"array {name!r}: dtype {dtype} is not one of {DTYPES}")
        listed.append([name, dtype, list(array.shape)])
        blobs.append(array.tobytes())
    text = json.dumps({**header, "arrays": listed}, allow_nan=True).encode("utf-8")
    return b"".join([MAGIC, struct.pack("<I", len(text)), text, *blobs])


def _array_sizes(listed: Any) -> list[tuple[str, np.dtype, tuple[int, ...], int]]:
    if not isinstance(listed, list):
        raise ProtocolError("the header's arrays are not a list")
    out = []
    for entry in listed:
        try:
            name, dtype, shape = entry
            dtype = np.dtype(dtype)
            shape = tuple(int(n) for n in shape)
        except (TypeError, ValueError) as error:
            raise ProtocolError(f"bad array entry {entry!r}: {error}") from None
        if dtype.str not in DTYPES or any(n < 0 for n in shape):
            raise ProtocolError(f"bad array entry {entry!r}")
        out.append((str(name), dtype, shape, dtype.itemsize * math.prod(shape)))
    return out


class FrameReader:
    """Bytes in any pieces -> frames ``("frame", header, arrays)`` and ``("text", bytes)``."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[tuple]:
        self._buffer += data
        out: list[tuple] = []
        buffer = self._buffer
        while buffer:
            if not buffer.startswith(MAGIC):
                found = buffer.find(MAGIC)
                # keep a tail that may be the start of a magic cut in two
                end = found if found >= 0 else max(0, len(buffer) - len(MAGIC) + 1)
                if end == 0:
                    break
                out.append(("text", bytes(buffer[:end])))
                del buffer[:end]
                continue
            if len(buffer) < 8:
                break
            (length,) = struct.unpack_from("<I", buffer, 4)
            if length > MAX_HEADER:
                raise ProtocolError(f"a header of {length} bytes")
            if len(buffer) < 8 + length:
                break
            try:
                header = json.loads(bytes(buffer[8:8 + length]).decode("utf-8"))
            except (UnicodeDecodeError, ValueError) as error:
                raise ProtocolError(f"a header that is not JSON: {error}") from None
            if not isinstance(header, dict):
                raise ProtocolError("a header that is not a JSON object")
            sizes = _array_sizes(header.pop("arrays", []))
            total = 8 + length + sum(size for *_, size in sizes)
            if len(buffer) < total:
                break
            arrays: Arrays = {}
            at = 8 + length
            for name, dtype, shape, size in sizes:
                arrays[name] = np.frombuffer(bytes(buffer[at:at + size]), dtype).reshape(shape)
                at += size
            del buffer[:total]
            out.append(("frame", header, arrays))
        return out

    def pending_text(self) -> bytes:
        """What is left that is not a frame (at the end of the stream)."""
        rest, self._buffer = bytes(self._buffer), bytearray()
        return b"" if rest.startswith(MAGIC) else rest


# ---- values ---------------------------------------------------------------------------------

def settings_to_wire(settings: dict[str, Any]) -> dict[str, Any]:
    """The ``settings`` a Filter gets (numpy arrays) as JSON values."""
    return {key: (value.tolist() if isinstance(value, np.ndarray) else value)
            for key, value in settings.items()}


def settings_from_wire(wire: dict[str, Any]) -> dict[str, Any]:
    """:func:`settings_to_wire` undone: the course's matrices and vectors as float arrays."""
    out = dict(wire)
    for key in SETTINGS_ARRAYS:
        if out.get(key) is not None:
            out[key] = np.array(out[key], dtype=float)
    return out


def problem_to_wire(problem: Any) -> dict[str, Any] | None:
    """A UserProblem as a JSON object (None: none)."""
    if problem is None:
        return None
    return {key: getattr(problem, key) for key in PROBLEM_FIELDS}
