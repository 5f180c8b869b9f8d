"""Our estimates as CSV: what `orientation-lab filter` prints and what a recording keeps in
``estimates.csv`` (the same rows, so `filter` on a recorded ``raw.txt`` reproduces the file).

Columns: t_ms (the phone's aligned clock), qw qx qy qz (sensor -> ENU, w >= 0, 9 decimals),
acc_rejected, mag_rejected, at_rest (0/1). One row per distinct time that has a GYR, ACC or MAG
sample.
"""

from __future__ import annotations

from pathlib import Path
from typing import TextIO

from app.engine.runner import Rows

HEADER = "t_ms,qw,qx,qy,qz,acc_rejected,mag_rejected,at_rest"


def csv_lines(rows: Rows) -> list[str]:
    """The CSV lines (without LF) of the rows that have a sensor sample."""
    rows = rows.select(rows.has_sample)
    out = []
    for t, q, acc, mag, rest in zip(rows.t_ms.tolist(), rows.quat.tolist(),
                                    rows.acc_rejected.tolist(), rows.mag_rejected.tolist(),
                                    rows.at_rest.tolist()):
        out.append(f"{t},{q[0]:.9f},{q[1]:.9f},{q[2]:.9f},{q[3]:.9f},"
                   f"{int(acc)},{int(mag)},{int(rest)}")
    return out


def write_csv(rows: Rows, stream: TextIO) -> None:
    """Header and rows to an open text stream."""
    stream.write(HEADER + "\n")
    write_rows(rows, stream)


def write_rows(rows: Rows, stream: TextIO) -> int:
    """The CSV lines of `rows` (a piece of a run: call it piece after piece, after the
    header) to an open text stream; returns the number of lines."""
    lines = csv_lines(rows)
    if lines:
        stream.write("\n".join(lines) + "\n")
    return len(lines)


class EstimatesWriter:
    """Appends rows to ``estimates.csv`` as they are produced (the engine calls :meth:`write`
    at every publish). Write errors are not raised: they stop the file and are kept in
    :attr:`error` for the caller to report, so a full disk never stops the estimates."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.rows_written = 0
        self.error: str | None = None
        self._stream: TextIO | None = open(self.path, "w", encoding="ascii", newline="\n")
        self._stream.write(HEADER + "\n")

    def write(self, rows: Rows) -> None:
        if self._stream is None or not len(rows):
            return
        try:
            written = write_rows(rows, self._stream)
        except OSError as error:
            self.error = f"{self.path}: {error.strerror or error}"
            self._close_quietly()
            return
        self.rows_written += written

    def flush(self) -> None:
        if self._stream is not None:
            try:
                self._stream.flush()
            except OSError as error:
                self.error = f"{self.path}: {error.strerror or error}"
                self._close_quietly()

    def close(self) -> None:
        if self._stream is not None:
            self.flush()
            self._close_quietly()

    def _close_quietly(self) -> None:
        stream, self._stream = self._stream, None
        if stream is not None:
            try:
                stream.close()
            except OSError:
                pass
