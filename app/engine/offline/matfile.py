"""MATLAB MAT-files (level 5, what MATLAB's ``save -v7`` writes and ``load`` reads, as does
``scipy.io.loadmat``) written as a stream: structs of double matrices whose columns arrive piece
by piece, so an export never holds a whole session.

The format stores a matrix whole, column-major, one field after another, so the columns are
kept in a temporary file per field as they arrive (in the operating system's temporary folder)
and copied, compressed, into the MAT-file at the end: memory for one piece, temporary disk for
the uncompressed numbers. A variable of more than 2 GiB does not fit the format's sizes
(``ValueError`` before anything is written).
"""

from __future__ import annotations

import os
import struct
import tempfile
import time
import zlib
from pathlib import Path
from typing import BinaryIO

import numpy as np

MI_INT8, MI_INT32, MI_UINT32, MI_DOUBLE, MI_MATRIX, MI_COMPRESSED = 1, 5, 6, 9, 14, 15
MX_STRUCT, MX_DOUBLE = 2, 6
FIELD_NAME_BYTES = 32               # MATLAB's field name length (31 characters and a NUL)
MAX_VARIABLE_BYTES = 2**31 - 1      # a variable's bytes must fit a signed 32-bit size
_COPY_BYTES = 1 << 20


def _pad8(size: int) -> int:
    return (size + 7) // 8 * 8


def _element(kind: int, data: bytes) -> bytes:
    """A data element: the small form (tag and up to 4 bytes in 8 bytes) or tag + padded data."""
    if len(data) <= 4:
        return struct.pack("<HH", kind, len(data)) + data.ljust(4, b"\0")
    return struct.pack("<II", kind, len(data)) + data.ljust(_pad8(len(data)), b"\0")


def _matrix_head(mclass: int, dims: tuple[int, ...], name: bytes) -> bytes:
    """Array flags, dimensions and name of a matrix element (its tag not included)."""
    return (_element(MI_UINT32, struct.pack("<II", mclass, 0))
            + _element(MI_INT32, struct.pack(f"<{len(dims)}i", *dims))
            + (_element(MI_INT8, name) if name else struct.pack("<II", MI_INT8, 0)))


class MatStructs:
    """Structs of double matrices (``{"meas": {"t": (1,), "acc": (3,)}, ...}``: each field's
    column shape) whose columns are appended piece by piece (:meth:`append`), then written as a
    MAT-file (:meth:`write`): a field of column shape (r,) is an r×N matrix, (r, c) an r×c×N
    array. Use as a context manager (the temporary files are removed at its end)."""

    def __init__(self, structs: dict[str, dict[str, tuple[int, ...]]]) -> None:
        for fields in structs.values():
            if any(len(name) >= FIELD_NAME_BYTES for name in fields):
                raise ValueError(f"field names longer than {FIELD_NAME_BYTES - 1} characters")
        self.structs = structs
        self.columns = 0
        self._folder = tempfile.TemporaryDirectory(prefix="orientation-lab-mat-")
        self._files: dict[tuple[str, str], BinaryIO] = {}
        for name, fields in structs.items():
            for field in fields:
                self._files[name, field] = open(
                    Path(self._folder.name) / f"{name}.{field}", "w+b")

    def __enter__(self) -> MatStructs:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for stream in self._files.values():
            stream.close()
        self._folder.cleanup()

    def append(self, columns: dict[str, dict[str, np.ndarray]]) -> None:
        """The next n columns of every field: arrays (n, *column shape), as rows of a C array
        (an r×c column as its r×c matrix)."""
        counts = set()
        for name, fields in self.structs.items():
            for field, shape in fields.items():
                data = np.asarray(columns[name][field], np.float64).reshape(-1, *shape)
                if len(shape) == 2:
                    data = data.transpose(0, 2, 1)       # each column in MATLAB's order
                np.ascontiguousarray(data).tofile(self._files[name, field])
                counts.add(len(data))
        if len(counts) > 1:
            raise ValueError(f"fields of unequal lengths: {sorted(counts)}")
        self.columns += counts.pop() if counts else 0

    def sizes(self) -> dict[str, int]:
        """Each struct's bytes in the file (uncompressed), with the columns appended so far."""
        return struct_sizes(self.structs, self.columns)

    def write(self, out: BinaryIO) -> None:
        """The MAT-file: its header and every struct, each compressed (the columns appended so
        far)."""
        check_size(self.structs, self.columns)
        text = (f"MATLAB 5.0 MAT-file Platform: {os.name}, Created on: {time.asctime()}"
                .encode("ascii"))
        out.write(text[:116].ljust(116, b"\0") + b"\0" * 8 + struct.pack("<H", 0x0100)
                  + b"IM")
        for name, fields in self.structs.items():
            with tempfile.TemporaryFile(dir=self._folder.name) as packed:
                compressor = zlib.compressobj()
                size = self.sizes()[name]
                packed.write(compressor.compress(
                    struct.pack("<II", MI_MATRIX, size - 8) + _struct_head(name, fields)[8:]))
                for field, shape in fields.items():
                    for piece in self._field_pieces(name, field, shape):
                        packed.write(compressor.compress(piece))
                packed.write(compressor.flush())
                out.write(struct.pack("<II", MI_COMPRESSED, packed.tell()))
                packed.seek(0)
                while chunk := packed.read(_COPY_BYTES):
                    out.write(chunk)

    def _field_pieces(self, name: str, field: str, shape: tuple[int, ...]):
        """A field's matrix element in pieces: its head, then its numbers from the temporary
        file."""
        n = self.columns
        count = n * int(np.prod(shape))
        yield (struct.pack("<II", MI_MATRIX, _field_bytes(shape, n))
               + _matrix_head(MX_DOUBLE, _dims(shape, n), b"")
               + struct.pack("<II", MI_DOUBLE, 8 * count))
        stream = self._files[name, field]
        stream.flush()
        stream.seek(0)
        while chunk := stream.read(_COPY_BYTES):
            yield chunk


def _struct_head(name: str, fields: dict[str, tuple[int, ...]]) -> bytes:
    """A struct's tag (a placeholder size), flags, dims, name and field names."""
    names = b"".join(f.encode("ascii").ljust(FIELD_NAME_BYTES, b"\0") for f in fields)
    return (struct.pack("<II", MI_MATRIX, 0)
            + _matrix_head(MX_STRUCT, (1, 1), name.encode("ascii"))
            + _element(MI_INT32, struct.pack("<i", FIELD_NAME_BYTES))
            + _element(MI_INT8, names))


def _dims(shape: tuple[int, ...], n: int) -> tuple[int, ...]:
    return (*shape, n) if len(shape) > 1 else (shape[0], n)


def _field_bytes(shape: tuple[int, ...], n: int) -> int:
    """A field matrix's contents (without its tag)."""
    return len(_matrix_head(MX_DOUBLE, _dims(shape, n), b"")) + 8 + _pad8(
        8 * n * int(np.prod(shape)))


def struct_sizes(structs: dict[str, dict[str, tuple[int, ...]]], columns: int) -> dict[str, int]:
    """Each struct's bytes in a MAT-file (uncompressed) with `columns` columns."""
    return {name: len(_struct_head(name, fields)) + sum(
        8 + _field_bytes(shape, columns) for shape in fields.values())
        for name, fields in structs.items()}


def check_size(structs: dict[str, dict[str, tuple[int, ...]]], columns: int) -> None:
    """ValueError (a sentence) when a struct of `columns` columns would not fit the format."""
    for name, size in struct_sizes(structs, columns).items():
        if size > MAX_VARIABLE_BYTES:
            raise ValueError(f"{name} would take {size / 2**30:.1f} GiB and a MAT-file holds at "
                             "most 2 GiB a variable: export a shorter range, or CSV")
