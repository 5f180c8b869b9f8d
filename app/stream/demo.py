"""The built-in demo session: a simulated recording in the phone's own log format.

`write_demo_session` turns `ekf.simulate.simulate` into phone lines (PROTOCOL.md, values as the
phone's float32 Java text, ORI = the true orientation) and gzips them reproducibly. The committed
file `app/resources/demo_session.txt.gz` is its output with the defaults; a test keeps the two equal.
Regenerate it with ``python -m app.stream.demo``.
"""

from __future__ import annotations

import contextlib
import gzip
import sys
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import BinaryIO

import numpy as np

from app.stream.protocol import Sample, format_line
from ekf.simulate import SENSOR_TAGS, SimulatedSession, simulate

DEMO_SESSION_PATH = Path(__file__).resolve().parents[1] / "resources" / "demo_session.txt.gz"
"""Where the committed demo session lives (app/resources/, inside the package: a wheel has it)."""

DEMO_RATES_HZ: dict[str, float] = {"gyr": 100.0, "acc": 100.0, "mag": 50.0, "ori": 100.0}
DEMO_GYRO_BIAS = (0.003, -0.002, 0.004)
"""A small gyroscope bias [rad/s], so plain gyro integration visibly drifts (about 28° over
the demo) while the filters hold."""


def session_lines(session: SimulatedSession, chunk: int = 1 << 16) -> Iterator[str]:
    """A simulated session's phone lines (without LF), in time order, ties GYR, ACC, MAG, ORI.

    Values are rounded to float32 first, as the phone sends them, and handed to the formatter as
    the float64 of the float32's shortest digits (what parsing the phone's text gives), so the
    text has the phone's digits (``9.784376``, not ``9.78437614440918``). Made `chunk` lines
    at a time, so a long session never has all its lines in memory at once.
    """
    t_ms, sensor, row = session.merged_order()
    values32 = [session.series(tag).values.astype(np.float32) for tag in SENSOR_TAGS]
    for start in range(0, len(t_ms), chunk):
        times = t_ms[start:start + chunk].tolist()
        sensors = sensor[start:start + chunk]
        rows = row[start:start + chunk]
        texts, firsts = [], []
        for code, values in enumerate(values32):
            mine = rows[sensors == code]
            first = int(mine[0]) if len(mine) else 0
            last = int(mine[-1]) + 1 if len(mine) else 0
            texts.append([[float(str(v)) for v in vector] for vector in values[first:last]])
            firsts.append(first)
        for t, s, r in zip(times, sensors.tolist(), rows.tolist()):
            yield format_line(Sample(t, SENSOR_TAGS[s], tuple(texts[s][r - firsts[s]])))


def write_session_to(session: SimulatedSession, stream: BinaryIO, compress: bool = False) -> None:
    """Write a simulated session's phone lines (LF line ends, only known tags, no header: the
    course's MATLAB reader accepts it) to a binary stream, gzipped reproducibly when
    `compress` (no time stamp or name in the header, so equal sessions give identical bytes)."""
    target = (gzip.GzipFile(filename="", mode="wb", fileobj=stream, mtime=0, compresslevel=9)
              if compress else contextlib.nullcontext(stream))
    with target as out:
        batch: list[str] = []
        for line in session_lines(session):
            batch.append(line)
            if len(batch) == 4096:
                out.write(("\n".join(batch) + "\n").encode("ascii"))
                batch.clear()
        if batch:
            out.write(("\n".join(batch) + "\n").encode("ascii"))


def write_session(session: SimulatedSession, path: str | Path) -> Path:
    """Write a simulated session as a phone log (see :func:`write_session_to`), gzipped when
    the path ends in ``.gz``; its folder is made when missing. Returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as stream:
        write_session_to(session, stream, compress=path.suffix == ".gz")
    return path


def demo_session(seed: int = 7, duration_s: float = 90.0,
                 rates_hz: Mapping[str, float] | None = None,
                 gyro_bias: Sequence[float] = DEMO_GYRO_BIAS) -> SimulatedSession:
    """The demo's simulated session (the standard script: rests, fast and slow turns about every
    axis, two linear-acceleration bursts, a magnetic disturbance), with its ground truth."""
    return simulate(duration_s=duration_s, rates_hz=dict(rates_hz or DEMO_RATES_HZ), seed=seed,
                    gyro_bias=gyro_bias, script="standard")


def demo_session_lines(seed: int = 7, duration_s: float = 90.0,
                       rates_hz: Mapping[str, float] | None = None,
                       gyro_bias: Sequence[float] = DEMO_GYRO_BIAS) -> list[str]:
    """The demo's phone lines (without LF); see :func:`session_lines`."""
    return list(session_lines(demo_session(seed, duration_s, rates_hz, gyro_bias)))


def write_demo_session(path: str | Path, seed: int = 7, duration_s: float = 90.0,
                       rates_hz: Mapping[str, float] | None = None,
                       gyro_bias: Sequence[float] = DEMO_GYRO_BIAS) -> Path:
    """Write the demo session as phone text to `path` (gzipped, reproducibly, when it ends in
    ``.gz``, as app/resources/demo_session.txt.gz does). Returns the path written."""
    return write_session(demo_session(seed, duration_s, rates_hz, gyro_bias), path)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m app.stream.demo [PATH]``: (re)write the demo session (default: DEMO_SESSION_PATH)."""
    args = list(sys.argv[1:] if argv is None else argv)
    target = Path(args[0]) if args else DEMO_SESSION_PATH
    written = write_demo_session(target)
    print(f"wrote {written} ({written.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
