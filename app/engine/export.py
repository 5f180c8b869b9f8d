"""Exports of a session (or a phone's log): CSV, the phone's own text format, MATLAB .mat.

The estimates come from the replay's own processing (:class:`~app.engine.pipeline.Pipeline`)
with the session's set-up and recorded timeline, so an export holds what replaying the
session shows. The window's File → Export and ``orientation-lab export`` both call
:func:`export_session`.

* **CSV**: one row per distinct time: t [s] since the start, acc [m/s²], gyr [rad/s],
  mag [µT] (x, y, z), the phone's quaternion (w x y z) and ours, our yaw/pitch/roll and the
  phone's [deg] (z-y-x), and the flags acc_rejected, mag_rejected, at_rest (0/1). A header row
  names every column with its unit; an empty field: no such sample at that time. Separator
  ``,`` ``;`` or TAB; with a decimal comma (``;`` then, by default).
* **log**: the raw lines verbatim (only known-tag lines, no header): the course's MATLAB reader
  and ``orientation-lab send`` read it unchanged.
* **mat**: the course kit's structs as ``filterTemplate`` returns them, ``meas`` (t 1×N, acc,
  gyr, mag 3×N, orient 4×N; NaN where a sensor has no sample) and ``xhat`` (t 1×N, x 4×N our
  quaternion, P 4×4×N its covariance), written with ``scipy.io.savemat`` (the optional extra
  ``orientation-lab[mat]``).

A range: the whole session, between two markers (by number or label), or from/to times in
seconds (the window's visible range). The log export keeps the lines whose own time (by the
replay's timing) falls in the range.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import ekf
from app.engine.config import ConfigError, open_replay
from app.engine.outputs import atomic_output, check_output
from app.engine.configuration import Config, Setup, recorded_setup
from app.engine.pipeline import Pipeline
from app.engine.runner import SENSORS, EstimatorRunner
from app.engine.session import Marker, SessionInfo, read_session, session_json_for
from app.stream.sources import LogFileSource
from app.stream.tags import WIDTHS

FORMATS = ("csv", "log", "mat")
SEPARATORS = {"comma": ",", "semicolon": ";", "tab": "\t", ",": ",", ";": ";", "\t": "\t"}
MAT_HINT = ("the MATLAB export needs scipy: pip install scipy (or pip install "
            "'orientation-lab[mat]'; make run and make test install it)")
_CSV_COLUMNS = (
    [("t", "s")] + [(f"{s}_{a}", u) for s, u in (("acc", "m/s^2"), ("gyr", "rad/s"),
                                                 ("mag", "uT")) for a in "xyz"]
    + [(f"phone_q{c}", "-") for c in "wxyz"] + [(f"q{c}", "-") for c in "wxyz"]
    + [(n, "deg") for n in ("yaw", "pitch", "roll")]
    + [(f"phone_{n}", "deg") for n in ("yaw", "pitch", "roll")]
    + [(n, "0/1") for n in ("acc_rejected", "mag_rejected", "at_rest")])


@dataclass
class SessionData:
    """A session computed once for exports: per distinct time (N rows, in time order) t_ms on
    the phone's aligned clock, t_s since the start, gyr/acc/mag (N, 3) and ori (N, 4) (NaN: no
    sample), our quat (N, 4), flags (N, 3) acc_rejected, mag_rejected, at_rest, cov (N, 4, 4)
    of q (with_cov) or None; the raw lines and their timing; the markers."""

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
    source: LogFileSource
    markers: list[Marker] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.t_ms)


def session_setup(session: SessionInfo | None, estimator: str = "ekf",
                  settings: ekf.EKFSettings | None = None) -> Setup:
    """The set-up a replay of this session starts with: its recorded configuration over time
    (app.engine.configuration; the comparisons, which exports do not hold, off)."""
    setup = recorded_setup(session, Config(estimator, SENSORS, settings or ekf.PRESETS["default"]))
    return dataclasses.replace(setup, comparisons=False,
                               timeline=tuple(c for c in setup.timeline
                                              if c.kind != "comparisons"))


def load_session(path: str | Path, with_cov: bool = False,
                 setup: Setup | None = None) -> SessionData:
    """Replay a session (folder, raw.txt, session.json) or a phone's log once, as fast as the
    kernels go, and keep what the exports need; setup: the configuration over time to replay
    it with (None: the recorded one; the window passes the one it replays). ConfigError for
    anything else."""
    source = open_replay(path)
    raw = source.path
    json_path = session_json_for(raw)
    try:
        session = read_session(json_path) if json_path else None
    except ValueError as error:
        raise ConfigError(str(error)) from None
    runner = EstimatorRunner(collect_plot=False, collect_cov=with_cov)
    ordered: list[tuple[np.ndarray, ...]] = []
    rows, covs = [], []

    def collect(*_args) -> None:
        if with_cov:
            covs.append(runner.take_covariances())
        rows.append(runner.take_rows())

    pipeline = Pipeline(runner, on_cut=collect,
                        on_ordered=lambda t, tag, values: ordered.append((t, tag, values)))
    setup = setup if setup is not None else session_setup(session)
    setup = dataclasses.replace(setup, comparisons=False, timeline=tuple(
        c for c in setup.timeline if c.kind != "comparisons"))
    pipeline.begin(pipeline.initial_checkpoint(setup), setup.timeline)
    step = 1 << 16
    for first in range(0, source.line_count, step):
        pipeline.feed_bytes(source.lines_between(first, min(first + step,
                                                            source.line_count)))
    pipeline.end_of_stream(partial_line_damaged=False)
    collect()
    return _session_data(raw, source, session, ordered, rows, covs if with_cov else None)


def _session_data(path: Path, source: LogFileSource, session: SessionInfo | None,
                  ordered: list, rows: list, covs: list | None) -> SessionData:
    from app.engine.runner import Rows
    if not ordered:
        raise ConfigError(f"{path}: no GYR, ACC, MAG or ORI samples to export")
    t = np.concatenate([o[0] for o in ordered])
    tag = np.concatenate([o[1] for o in ordered])
    values = np.concatenate([o[2] for o in ordered])
    group = np.concatenate(([0], np.cumsum(t[1:] != t[:-1])))
    count = int(group[-1]) + 1
    columns = []
    for code, width in enumerate(WIDTHS):
        column = np.full((count, width), np.nan)
        chosen = tag == code
        column[group[chosen]] = values[chosen, :width]      # the last of a time wins
        columns.append(column)
    estimates = Rows.concatenate(rows)
    times = t[np.concatenate(([0], np.flatnonzero(t[1:] != t[:-1]) + 1))]
    if len(estimates) == count and np.array_equal(estimates.t_ms, times):
        index = np.arange(count)
    else:       # a session cut at a shared time: the latest row at or before each time
        index = np.clip(np.searchsorted(estimates.t_ms, times, side="right") - 1, 0, None)
    cov = None
    if covs is not None:
        cov = np.concatenate(covs)[index] if covs else np.full((count, 4, 4), np.nan)
    flags = np.column_stack([estimates.acc_rejected, estimates.mag_rejected,
                             estimates.at_rest])[index].astype(np.float64)
    return SessionData(path, times, (times - times[0]) / 1000.0, *columns[:3], columns[3],
                       estimates.quat[index], flags, cov, source,
                       session.markers if session else [])


# ---- ranges ------------------------------------------------------------------------------------

def find_marker(markers: list[Marker], name: str) -> Marker:
    """A marker by number ("2") or label ("turn"); ConfigError naming the choices."""
    for marker in markers:
        if str(marker.id) == str(name).strip() or marker.label == name:
            return marker
    choices = ", ".join(m.title for m in markers) or "none"
    raise ConfigError(f"no marker {name!r} in the session (markers: {choices})")


def time_range(data: SessionData, from_marker: str | None = None, to_marker: str | None = None,
               from_s: float | None = None, to_s: float | None = None) -> tuple[float, float]:
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
        raise ConfigError(f"the range ends ({end:.3f} s) before it starts ({start:.3f} s)")
    if len(data) and not ((data.t_s >= start - 1e-9) & (data.t_s <= end + 1e-9)).any():
        raise ConfigError(f"no samples from {start:.3f} s to {end:.3f} s: the session runs "
                          f"from {float(data.t_s[0]):.3f} s to {float(data.t_s[-1]):.3f} s")
    return start, end


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


def write_csv(data: SessionData, out: Path, start: float, end: float, separator: str = ",",
              decimal_comma: bool = False) -> int:
    """Rows of the range as CSV; returns the row count."""
    if decimal_comma and separator == ",":
        raise ConfigError("a decimal comma needs another separator: semicolon or tab")
    chosen = (data.t_s >= start - 1e-9) & (data.t_s <= end + 1e-9)
    table = csv_table(data, chosen)
    row_format = separator.join(["%.3f"] + ["%.9g"] * (len(_CSV_COLUMNS) - 4) + ["%d"] * 3)
    flags_ok = np.nan_to_num(table[:, -3:]).astype(int)
    lines = [row_format % (*row[:-3], *flag) for row, flag in zip(table.tolist(),
                                                                    flags_ok.tolist())]
    text = "\n".join(lines)
    text = text.replace("nan", "")
    if decimal_comma:
        text = text.replace(".", ",")
    with atomic_output(out, "w", encoding="ascii", newline="\n") as stream:
        stream.write(csv_header(separator) + "\n")
        if lines:
            stream.write(text + "\n")
    return len(lines)


def write_log(data: SessionData, out: Path, start: float, end: float) -> int:
    """The raw lines whose own time falls in the range, verbatim; returns the line count."""
    source = data.source
    pace = source.pace
    offset = float(data.t_s[0]) if len(data) else 0.0
    first = int(np.searchsorted(pace, start - offset - 1e-9, side="left"))
    last = int(np.searchsorted(pace, end - offset + 1e-9, side="right"))
    with atomic_output(out, "wb") as stream:
        stream.write(source.lines_between(first, last))
    return max(0, last - first)


def write_mat(data: SessionData, out: Path, start: float, end: float) -> int:
    """meas and xhat structs (filterTemplate's) to a .mat file; returns the column count."""
    try:
        from scipy.io import savemat
    except ImportError:
        raise ConfigError(MAT_HINT) from None
    chosen = (data.t_s >= start - 1e-9) & (data.t_s <= end + 1e-9)
    t = data.t_s[chosen][None, :]
    cov = data.cov[chosen] if data.cov is not None else np.full((int(chosen.sum()), 4, 4),
                                                                 np.nan)
    meas = {"t": t, "acc": data.acc[chosen].T, "gyr": data.gyr[chosen].T,
            "mag": data.mag[chosen].T, "orient": data.ori[chosen].T}
    xhat = {"t": t, "x": data.quat[chosen].T, "P": np.transpose(cov, (1, 2, 0))}
    with atomic_output(out, "wb") as stream:
        savemat(stream, {"meas": meas, "xhat": xhat}, oned_as="row", do_compression=True)
    return int(chosen.sum())


def export_session(path: str | Path, fmt: str, out: str | Path,
                   from_marker: str | None = None, to_marker: str | None = None,
                   from_s: float | None = None, to_s: float | None = None,
                   separator: str = ",", decimal_comma: bool = False,
                   data: SessionData | None = None, setup: Setup | None = None) -> str:
    """Export a session; returns one line saying what was written. ConfigError for bad
    arguments (a one-line message). setup: the configuration over time its estimates are
    computed with (None: the recorded one; the window passes the one it replays)."""
    if fmt not in FORMATS:
        raise ConfigError(f"--format: expected one of {', '.join(FORMATS)}, got {fmt!r}")
    if fmt == "mat":
        try:
            import scipy.io  # noqa: F401
        except ImportError:
            raise ConfigError(MAT_HINT) from None
    sep = SEPARATORS.get(separator)
    if sep is None:
        raise ConfigError(f"--separator: expected comma, semicolon or tab, got {separator!r}")
    out = check_output(out, path)
    if out.is_dir():
        raise ConfigError(f"{out}: is a folder; give a file name to write")
    data = data if data is not None and (fmt != "mat" or data.cov is not None) \
        else load_session(path, with_cov=fmt == "mat", setup=setup)
    start, end = time_range(data, from_marker, to_marker, from_s, to_s)
    try:
        if fmt == "csv":
            count = write_csv(data, out, start, end, sep, decimal_comma)
            what = f"{count} rows"
        elif fmt == "log":
            what = f"{write_log(data, out, start, end)} lines"
        else:
            what = f"{write_mat(data, out, start, end)} samples (meas, xhat)"
    except OSError as error:
        raise ConfigError(f"cannot write {out}: {error.strerror or error}") from None
    return f"{out}: {what} from {start:.1f} s to {end:.1f} s"
