"""Exports of a session (or a phone's log): CSV, the phone's own text format, MATLAB .mat.

The estimates come from the replay's own processing
(:class:`~app.engine.processing.pipeline.Pipeline`) with the session's configuration over time
(:mod:`app.engine.processing.configuration`: the recorded one, or the one the window replays), so an
export holds what replaying the session shows. The window's File → Export and ``orientation-lab
export`` both call :func:`export_session`.

An export reads the log twice as a stream, never whole: a first pass (parser and orderer only)
finds the session's times, so a range is checked before anything is written; the second replays
it block by block (:func:`session_pieces`) and writes each block's rows as they come. Memory
does not grow with the session (the MATLAB file keeps its columns in temporary files until it
is written, :mod:`app.engine.offline.matfile`).

* **CSV**: one row per distinct time: t [s] since the start, acc [m/s²], gyr [rad/s],
  mag [µT] (x, y, z), the phone's quaternion (w x y z) and ours, our yaw/pitch/roll and the
  phone's [deg] (z-y-x), and the flags acc_rejected, mag_rejected, at_rest (0/1). A header row
  names every column with its unit; an empty field: no such sample at that time. Separator
  ``,`` ``;`` or TAB; with a decimal comma (``;`` then, by default).
* **log**: the raw lines verbatim (only known-tag lines, no header): the course's MATLAB reader
  and ``orientation-lab send`` read it unchanged.
* **mat**: the course kit's structs as ``filterTemplate`` returns them, ``meas`` (t 1×N, acc,
  gyr, mag 3×N, orient 4×N; NaN where a sensor has no sample) and ``xhat`` (t 1×N, x 4×N our
  quaternion, P 4×4×N its covariance), a MATLAB 5 file (``load`` in MATLAB and Octave,
  ``scipy.io.loadmat``) written by :mod:`app.engine.offline.matfile`. A variable holds at most 2 GiB
  (xhat: about 12 million rows, ten hours of a phone's four sensors).

A range: the whole session, between two markers (by number or label), or from/to times in
seconds (the window's visible range). The log export keeps the lines whose own time (by the
replay's timing) falls in the range.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import ekf
from app.engine import config
from app.engine.config import ConfigError
from app.engine.offline.matfile import MatStructs, check_size
from app.engine.offline.outputs import check_output, open_output
from app.engine.processing.configuration import Config, Setup, recorded_setup
from app.engine.processing.pipeline import Pipeline
from app.engine.processing.runner import SENSORS, EstimatorRunner, Rows
from app.engine.sessions.session import Marker, SessionInfo, read_session, session_json_for
from app.stream.lines import CHUNK_BYTES, LogError, Pacer, line_blocks, line_starts
from app.stream.protocol import WIDTHS

FORMATS = ("csv", "log", "mat")
SEPARATORS = {"comma": ",", "semicolon": ";", "tab": "\t", ",": ",", ";": ";", "\t": "\t"}
MAT_STRUCTS = {"meas": {"t": (1,), "acc": (3,), "gyr": (3,), "mag": (3,), "orient": (4,)},
               "xhat": {"t": (1,), "x": (4,), "P": (4, 4)}}
_CSV_COLUMNS = (
    [("t", "s")] + [(f"{s}_{a}", u) for s, u in (("acc", "m/s^2"), ("gyr", "rad/s"),
                                                 ("mag", "uT")) for a in "xyz"]
    + [(f"phone_q{c}", "-") for c in "wxyz"] + [(f"q{c}", "-") for c in "wxyz"]
    + [(n, "deg") for n in ("yaw", "pitch", "roll")]
    + [(f"phone_{n}", "deg") for n in ("yaw", "pitch", "roll")]
    + [(n, "0/1") for n in ("acc_rejected", "mag_rejected", "at_rest")])


@dataclass
class SessionData:
    """A session computed for exports, whole (:func:`load_session`) or a piece of it
    (:func:`session_pieces`): per distinct time (N rows, in time order) t_ms on the phone's
    aligned clock, t_s since the session's start, gyr/acc/mag (N, 3) and ori (N, 4) (NaN: no
    sample), our quat (N, 4), flags (N, 3) acc_rejected, mag_rejected, at_rest, cov (N, 4, 4)
    of q (with_cov) or None; the markers."""

    path: Path
    t_ms: np.ndarray
    t_s: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    ori: np.ndarray
    quat: np.ndarray
    flags: np.ndarray
    cov: np.ndarray | None
    markers: list[Marker] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.t_ms)

    def select(self, chosen: np.ndarray) -> SessionData:
        """The rows where `chosen` is true."""
        return SessionData(self.path, *(getattr(self, name)[chosen] for name in (
            "t_ms", "t_s", "gyr", "acc", "mag", "ori", "quat", "flags")),
            None if self.cov is None else self.cov[chosen], self.markers)


@dataclass
class SessionSpan:
    """A session's distinct times, t_s (N,) in seconds since its start, and its markers: what
    :func:`time_range` needs, from a pass without the estimators."""

    t_s: np.ndarray
    markers: list[Marker] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.t_s)


@dataclass
class OpenedSession:
    """A session's log (checked as a replay checks it), its session.json (None: a phone's log)
    and whether a torn last line is left out (a recording's raw.txt, as the replay does)."""

    raw: Path
    session: SessionInfo | None
    drop_torn: bool

    @property
    def markers(self) -> list[Marker]:
        return self.session.markers if self.session else []

    def blocks(self, block_bytes: int = CHUNK_BYTES) -> Iterator[bytes]:
        """The log's lines in blocks (:func:`~app.stream.lines.line_blocks`)."""
        try:
            yield from line_blocks(self.raw, block_bytes, self.drop_torn)
        except LogError as error:
            raise ConfigError(f"{error}; {config.REPLAY_EXPECTED}") from None


def session_setup(session: SessionInfo | None, estimator: str = "ekf",
                  settings: ekf.EKFSettings | None = None) -> Setup:
    """The set-up a replay of this session starts with: its recorded configuration over time
    (app.engine.processing.configuration; the comparisons, which exports do not hold, off)."""
    setup = recorded_setup(session, Config(estimator, SENSORS, settings or ekf.PRESETS["default"]))
    return _without_comparisons(setup)


def _without_comparisons(setup: Setup) -> Setup:
    return dataclasses.replace(setup, comparisons=False,
                               timeline=tuple(c for c in setup.timeline
                                              if c.kind != "comparisons"))


def open_session(path: str | Path) -> OpenedSession:
    """A session folder, its raw.txt or session.json, or a phone's log, to export; ConfigError
    (one line) for anything else."""
    raw = config.replay_log(path)
    json_path = session_json_for(raw)
    try:
        session = read_session(json_path) if json_path else None
    except ValueError as error:
        raise ConfigError(str(error)) from None
    return OpenedSession(raw, session, raw.with_name("session.json").is_file())


def _pipeline(opened: OpenedSession, with_cov: bool, setup: Setup | None = None,
              **callbacks: Any) -> Pipeline:
    """The replay's processing at the session's start, with its configuration over time
    (setup; None: the recorded one); callbacks: the Pipeline's on_cut, on_ordered."""
    pipeline = Pipeline(EstimatorRunner(collect_plot=False, collect_cov=with_cov), **callbacks)
    setup = session_setup(opened.session) if setup is None else _without_comparisons(setup)
    pipeline.begin(pipeline.initial_checkpoint(setup), setup.timeline)
    return pipeline


def session_span(opened: OpenedSession, block_bytes: int = CHUNK_BYTES) -> SessionSpan:
    """The session's distinct times (the replay's parser and orderer, no estimator)."""
    pipeline = _pipeline(opened, with_cov=False)
    parser, orderer = pipeline.parser, pipeline.orderer
    runs: list[np.ndarray] = []
    last: list[int] = []

    def take(t: np.ndarray) -> None:
        if len(t):
            new = np.ones(len(t), bool)
            new[1:] = t[1:] != t[:-1]
            new[0] = not last or t[0] != last[0]
            runs.append(t[new])
            last[:] = [int(t[-1])]

    for block in opened.blocks(block_bytes):
        parsed = parser.feed_arrays(block)
        if len(parsed.t_ms):
            take(orderer.push_arrays(parsed.t_ms, parsed.tag, parsed.values).t_ms)
    parsed = parser.finish_arrays()
    if len(parsed.t_ms):
        take(orderer.push_arrays(parsed.t_ms, parsed.tag, parsed.values).t_ms)
    take(orderer.flush_arrays().t_ms)
    times = np.concatenate(runs) if runs else np.empty(0, np.int64)
    return SessionSpan((times - times[0]) / 1000.0 if len(times) else np.empty(0),
                       opened.markers)


def session_pieces(opened: OpenedSession, with_cov: bool = False,
                   block_bytes: int = CHUNK_BYTES,
                   setup: Setup | None = None) -> Iterator[SessionData]:
    """Replay the session once, as fast as the kernels go, block by block, and hand on what
    the exports need, piece by piece (each piece whole distinct times, in order); setup: the
    configuration over time to replay it with (None: the recorded one; the window passes the
    one it replays)."""
    joiner = _Joiner(opened.raw, opened.markers, with_cov)

    def taken(rows: Rows | None = None) -> None:
        runner.take_errors()                      # the window's error plots: not exported
        covs = runner.take_covariances() if with_cov else None
        joiner.add_rows(runner.take_rows() if rows is None else rows, covs)

    pipeline = _pipeline(opened, with_cov, setup, on_ordered=joiner.ordered,
                         on_cut=lambda rows, _piece: taken(rows))     # a session that ended
    runner = pipeline.runner
    for block in opened.blocks(block_bytes):
        pipeline.feed_bytes(block)
        taken()
        yield from joiner.pieces(final=False)
    pipeline.end_of_stream(partial_line_damaged=False)
    taken()
    yield from joiner.pieces(final=True)


def load_session(path: str | Path, with_cov: bool = False,
                 setup: Setup | None = None) -> SessionData:
    """Replay a session (folder, raw.txt, session.json) or a phone's log once and keep what
    the exports need, whole; setup as for :func:`session_pieces`. ConfigError for anything
    else."""
    opened = open_session(path)
    pieces = list(session_pieces(opened, with_cov, setup=setup))
    if not pieces:
        raise ConfigError(f"{opened.raw}: no GYR, ACC, MAG or ORI samples to export")
    return SessionData(opened.raw, *(np.concatenate([getattr(p, name) for p in pieces])
                                     for name in ("t_ms", "t_s", "gyr", "acc", "mag", "ori",
                                                  "quat", "flags")),
                       np.concatenate([p.cov for p in pieces]) if with_cov else None,
                       opened.markers)


class _Joiner:
    """The ordered samples as the pipeline hands them to the estimators and the runner's rows,
    joined per distinct time: a time's row is the latest committed at that time (two when a
    session ends and the next starts at the same time), its readings the last sample of each
    tag at it."""

    def __init__(self, path: Path, markers: list[Marker], with_cov: bool) -> None:
        self.path = path
        self.markers = markers
        self.with_cov = with_cov
        self.t0: np.int64 | None = None
        self._samples: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._rows: list[Rows] = []
        self._covs: list[np.ndarray] = []

    def ordered(self, t_ms: np.ndarray, tag: np.ndarray, values: np.ndarray) -> None:
        self._samples.append((t_ms, tag, values))

    def add_rows(self, rows: Rows, covs: np.ndarray | None) -> None:
        if len(rows):
            self._rows.append(rows)
            if covs is not None:
                self._covs.append(covs)

    def pieces(self, final: bool) -> Iterator[SessionData]:
        """The distinct times complete so far (all of them when `final`): the latest time waits
        for more samples and rows of it."""
        if not self._samples:
            return
        t, tag, values = (np.concatenate(column) for column in zip(*self._samples))
        rows = Rows.concatenate(self._rows)
        covs = np.concatenate(self._covs) if self._covs else np.empty((0, 4, 4))
        firsts = np.concatenate(([0], np.flatnonzero(t[1:] != t[:-1]) + 1))
        count = len(firsts) if final else len(firsts) - 1
        if not count:
            return
        cut = len(t) if count == len(firsts) else int(firsts[count])
        row_cut = len(rows)
        if not final:
            while row_cut and rows.t_ms[row_cut - 1] == t[-1]:
                row_cut -= 1
        self._samples = [(t[cut:], tag[cut:], values[cut:])] if cut < len(t) else []
        self._rows = [rows.select(np.arange(len(rows)) >= row_cut)] if row_cut < len(rows) \
            else []
        self._covs = [covs[row_cut:]] if self.with_cov and row_cut < len(covs) else []
        yield self._piece(t[:cut], tag[:cut], values[:cut], firsts[:count],
                          rows.select(np.arange(len(rows)) < row_cut), covs[:row_cut])

    def _piece(self, t: np.ndarray, tag: np.ndarray, values: np.ndarray, firsts: np.ndarray,
               rows: Rows, covs: np.ndarray) -> SessionData:
        times = t[firsts]
        if self.t0 is None:
            self.t0 = times[0]
        group = np.zeros(len(t), np.int64)
        group[firsts[1:]] = 1
        group = np.cumsum(group)
        columns = []
        for code, width in enumerate(WIDTHS):
            column = np.full((len(times), width), np.nan)
            chosen = tag == code
            column[group[chosen]] = values[chosen, :width]      # the last of a time wins
            columns.append(column)
        row_t = rows.t_ms
        ends = np.concatenate((np.flatnonzero(row_t[1:] != row_t[:-1]), [len(row_t) - 1])) \
            if len(row_t) else np.empty(0, np.int64)
        if len(ends) == len(times) and np.array_equal(row_t[ends], times):
            index = ends
        else:       # not expected: the latest row at or before each time
            index = np.clip(np.searchsorted(row_t, times, side="right") - 1, 0, None)
        if not len(row_t):
            rows = Rows(times, np.full((len(times), 4), np.nan), np.full((len(times), 4), np.nan),
                        *(np.zeros(len(times), bool) for _ in range(4)))
            covs = np.full((len(times), 4, 4), np.nan)
            index = np.arange(len(times))
        cov = None
        if self.with_cov:
            cov = covs[index] if len(covs) else np.full((len(times), 4, 4), np.nan)
        flags = np.column_stack([rows.acc_rejected, rows.mag_rejected,
                                 rows.at_rest])[index].astype(np.float64)
        return SessionData(self.path, times, (times - self.t0) / 1000.0, *columns[:3],
                           columns[3], rows.quat[index], flags, cov, self.markers)


# ---- ranges ------------------------------------------------------------------------------------

def find_marker(markers: list[Marker], name: str) -> Marker:
    """A marker by number ("2") or label ("turn"); ConfigError naming the choices."""
    for marker in markers:
        if str(marker.id) == str(name).strip() or marker.label == name:
            return marker
    choices = ", ".join(m.title for m in markers) or "none"
    raise ConfigError(f"no marker {name!r} in the session (markers: {choices})")


def time_range(data: SessionData | SessionSpan, from_marker: str | None = None,
               to_marker: str | None = None, from_s: float | None = None,
               to_s: float | None = None) -> tuple[float, float]:
    """The range [start, end] in seconds since the start (the whole session by default)."""
    start = 0.0 if len(data) == 0 else float(data.t_s[0])
    end = float(data.t_s[-1]) if len(data) else 0.0
    if from_marker is not None:
        marker = find_marker(data.markers, from_marker)
        start = marker.t_s if marker.t_s is not None else start
    if to_marker is not None:
        marker = find_marker(data.markers, to_marker)
        end = marker.t_s if marker.t_s is not None else end
    if from_s is not None:
        start = float(from_s)
    if to_s is not None:
        end = float(to_s)
    if end < start:
        raise ConfigError(f"the range ends ({_seconds(end)}) before it starts "
                          f"({_seconds(start)})")
    if len(data) and not ((data.t_s >= start - 1e-9) & (data.t_s <= end + 1e-9)).any():
        raise ConfigError(f"no samples from {_seconds(start)} to {_seconds(end)}: the session "
                          f"runs from {_seconds(float(data.t_s[0]))} to "
                          f"{_seconds(float(data.t_s[-1]))}")
    return start, end


def _seconds(value: float) -> str:
    """"12.345 s"; a time far beyond any session in three significant digits ("1e+308 s")."""
    return f"{value:.3f} s" if abs(value) < 1e7 else f"{value:.3g} s"


# ---- writers -----------------------------------------------------------------------------------

def csv_header(separator: str = ",") -> str:
    return separator.join(f"{name} [{unit}]" for name, unit in _CSV_COLUMNS)


def csv_table(data: SessionData, chosen: np.ndarray) -> np.ndarray:
    """(n, 27) the CSV's numbers (NaN: an empty field)."""
    euler = np.degrees(ekf.quaternion.to_euler(data.quat[chosen]))
    ori = data.ori[chosen]
    phone_euler = np.full((len(ori), 3), np.nan)
    has_ori = ~np.isnan(ori).any(axis=1)
    if has_ori.any():
        phone_euler[has_ori] = np.degrees(ekf.quaternion.to_euler(ori[has_ori]))
    return np.column_stack([data.t_s[chosen], data.acc[chosen], data.gyr[chosen],
                            data.mag[chosen], ori, data.quat[chosen], euler, phone_euler,
                            data.flags[chosen]])


def _in_range(data: SessionData, start: float, end: float) -> np.ndarray:
    return (data.t_s >= start - 1e-9) & (data.t_s <= end + 1e-9)


def csv_text(data: SessionData, start: float, end: float, separator: str = ",",
             decimal_comma: bool = False) -> tuple[str, int]:
    """The CSV lines of the rows of a piece in the range (each ending in LF) and their
    count."""
    table = csv_table(data, _in_range(data, start, end))
    if not len(table):
        return "", 0
    row_format = separator.join(["%.3f"] + ["%.9g"] * (len(_CSV_COLUMNS) - 4) + ["%d"] * 3)
    flags_ok = np.nan_to_num(table[:, -3:]).astype(int)
    text = "\n".join(row_format % (*row[:-3], *flag) for row, flag in zip(table.tolist(),
                                                                          flags_ok.tolist()))
    text = text.replace("nan", "")
    if decimal_comma:
        text = text.replace(".", ",")
    return text + "\n", len(table)


def write_csv(pieces: Iterator[SessionData], out: Path, start: float, end: float,
              separator: str = ",", decimal_comma: bool = False) -> int:
    """Rows of the range as CSV, piece by piece; returns the row count."""
    count = 0
    with open_output(out, "w", encoding="ascii", newline="\n") as stream:
        stream.write(csv_header(separator) + "\n")
        for data in pieces:
            text, rows = csv_text(data, start, end, separator, decimal_comma)
            stream.write(text)
            count += rows
    return count


def write_log(opened: OpenedSession, out: Path, start: float, end: float) -> int:
    """The raw lines whose own time (their pacing from the log's start) falls in the range,
    verbatim, block by block; returns the line count."""
    pacer = Pacer()
    count = 0
    with open_output(out, "wb") as stream:
        for block in opened.blocks():
            starts = line_starts(block)
            pace = pacer.times(block, starts)
            chosen = np.flatnonzero((pace >= start - 1e-9) & (pace <= end + 1e-9))
            if len(chosen):         # the pace never goes back: a run of lines
                stream.write(block[starts[chosen[0]]:starts[chosen[-1] + 1]])
                count += len(chosen)
    return count


def write_mat(pieces: Iterator[SessionData], out: Path, start: float, end: float) -> int:
    """meas and xhat structs (filterTemplate's) to a .mat file; returns the column count."""
    with MatStructs(MAT_STRUCTS) as mat:
        for data in pieces:
            part = data.select(_in_range(data, start, end))
            cov = part.cov if part.cov is not None else np.full((len(part), 4, 4), np.nan)
            mat.append({"meas": {"t": part.t_s, "acc": part.acc, "gyr": part.gyr,
                                 "mag": part.mag, "orient": part.ori},
                        "xhat": {"t": part.t_s, "x": part.quat, "P": cov}})
        with open_output(out, "wb") as stream:
            mat.write(stream)
        return mat.columns


def export_session(path: str | Path, fmt: str, out: str | Path,
                   from_marker: str | None = None, to_marker: str | None = None,
                   from_s: float | None = None, to_s: float | None = None,
                   separator: str = ",", decimal_comma: bool = False,
                   setup: Setup | None = None) -> str:
    """Export a session; returns one line saying what was written. ConfigError for bad
    arguments (a one-line message). setup: the configuration over time its estimates are
    computed with (None: the recorded one; the window passes the one it replays)."""
    if fmt not in FORMATS:
        raise ConfigError(f"--format: expected one of {', '.join(FORMATS)}, got {fmt!r}")
    sep = SEPARATORS.get(separator)
    if sep is None:
        raise ConfigError(f"--separator: expected comma, semicolon or tab, got {separator!r}")
    if fmt == "csv" and decimal_comma and sep == ",":
        raise ConfigError("a decimal comma needs another separator: semicolon or tab")
    out = check_output(out, path)
    opened = open_session(path)
    span = session_span(opened)
    if not len(span):
        raise ConfigError(f"{opened.raw}: no GYR, ACC, MAG or ORI samples to export")
    start, end = time_range(span, from_marker, to_marker, from_s, to_s)
    try:
        if fmt == "csv":
            count = write_csv(session_pieces(opened, setup=setup), out, start, end, sep,
                              decimal_comma)
            what = f"{count} rows"
        elif fmt == "log":
            what = f"{write_log(opened, out, start, end)} lines"
        else:
            columns = int(((span.t_s >= start - 1e-9) & (span.t_s <= end + 1e-9)).sum())
            try:
                check_size(MAT_STRUCTS, columns)
            except ValueError as error:
                raise ConfigError(f"cannot export {columns} samples to MATLAB: {error}") \
                    from None
            count = write_mat(session_pieces(opened, with_cov=True, setup=setup), out, start, end)
            what = f"{count} samples (meas, xhat)"
    except OSError as error:
        raise ConfigError(f"cannot write {out}: {error.strerror or error}") from None
    last = float(span.t_s[-1]) if len(span) else end
    return f"{out}: {what} from {start:.1f} s to {min(end, last):.1f} s"
