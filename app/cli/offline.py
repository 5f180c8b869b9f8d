"""The offline commands: filter, evaluate, simulate, new-filter (calibrate, calibrate-mag and
tune are in app.cli.calibration). Headless: they never import Qt.

filter and evaluate run the engine's runner (app.engine.offline.filtering), the same path as
the live engine, so a file gives the estimates its live replay gives. Either takes the user's own
filter (``--estimator FILE.py``), which runs in a process of its own: what it prints goes to stderr
(stdout may be the CSV); a long run says how far it is; steps not written yet are listed; if it
fails (an error in its code, a call that does not return, its process ending), its file:line and
message are printed (``--traceback``: the whole traceback of its code) and the status is 1.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import ekf
from ekf.metrics import intervals_mask
from ekf.simulate import MAX_RATE_HZ, simulate
from app.cli import options
from app.engine import config
from app.engine.offline.filtering import (HEADER, LogScan, evaluate_log, evaluate_phone,
                                          filter_rows, scan_log, sibling_truth, write_rows)
from app.engine.offline.outputs import check_output, open_output
from app.engine.sessions.session import read_session, session_json_for
from app.engine.userfilter.filter import UserFilterEstimator, estimator_for
from app.engine.userfilter.matlab_template import write_matlab_template
from app.engine.userfilter.template import write_template
from app.stream.demo import write_session_to
from app.stream.lines import LogError
from app.stream.logfile import LogData, LogFile, LogStats


def open_log_noted(path: str, limits=None) -> LogData:
    """The whole log in memory (calibrate, tune), with its one-line summary (damage by reason,
    clock quirks) on stderr."""
    log = config.open_log(path, limits or config.sensor_limits(""))
    _print_summary(path, log.stats)
    return log


def _print_summary(path: str, stats: LogStats | None) -> None:
    summary = stats.summary() if stats is not None else ""
    if summary:
        print(summary if summary.startswith(Path(path).name) else f"{path}: {summary}",
              file=sys.stderr)


def scan(path: str, limits=None, ori: bool = False) -> tuple[LogFile, LogScan]:
    """The log to read chunk by chunk (filter, evaluate: memory does not grow with it) and
    what a first pass over it found, its summary on stderr."""
    log = config.log_file(path, limits or config.sensor_limits(""))
    with _log_errors():
        found = scan_log(log, ori=ori)
    _print_summary(path, found.stats)
    return log, found


@contextlib.contextmanager
def _log_errors():
    """A log that turns out unreadable while it is read (a damaged gzip stream, binary data, no
    line of the phone's format) is one line."""
    try:
        yield
    except LogError as error:
        raise config.ConfigError(str(error)) from None


def check_estimable(log: LogData | LogScan, sensors: tuple[str, ...]) -> None:
    """ConfigError (one line) when no estimate can be made from the log with these sensors:
    none of them in it, or no accelerometer (nothing gives down; the estimate would be the
    identity, or a turn from it)."""
    present = present_sensors(log)
    used = [name for name in present if name in sensors]
    tags = ", ".join(name.upper() for name in present) or "no GYR, ACC or MAG"
    if not used:
        raise config.ConfigError(f"{log.path}: no estimate can be made: the log holds {tags} "
                                 f"samples, none of --sensors {','.join(sensors)}")
    if "acc" not in present:
        raise config.ConfigError(f"{log.path}: no estimate can be made without accelerometer "
                                 f"samples (nothing gives down); the log holds {tags} only")


SENSOR_WORDS = {"gyr": "gyroscope", "acc": "accelerometer", "mag": "magnetometer"}
# what an estimator reads (a filter of the user's may read them all)
ESTIMATOR_SENSORS = {"accmag": ("acc", "mag")}


def present_sensors(log: LogData | LogScan) -> tuple[str, ...]:
    """The filter sensors the log holds samples of, in ("gyr", "acc", "mag") order."""
    if isinstance(log, LogScan):
        return tuple(name for name in SENSOR_WORDS if log.present[name])
    arrays = log.to_arrays()
    return tuple(name for name in SENSOR_WORDS
                 if bool(np.isfinite(getattr(arrays, name)[:, 0]).any()))


def warn_absent(log: LogData | LogScan, sensors: tuple[str, ...], names: list[str],
                present: tuple[str, ...] | None = None) -> tuple[str, ...]:
    """One line on stderr when the log lacks a sensor the estimators would use (a figure from
    such a log is that of the other sensors alone); the sensors it lacks."""
    present = present_sensors(log) if present is None else present
    used = {sensor for name in names
            for sensor in ESTIMATOR_SENSORS.get(str(name).lower(), tuple(SENSOR_WORDS))}
    absent = tuple(s for s in SENSOR_WORDS if s in sensors and s in used and s not in present)
    if absent:
        words = " or ".join(SENSOR_WORDS[s] for s in absent)
        left = ",".join(s for s in sensors if s in present) or "none"
        print(f"orientation-lab: warning: {Path(log.path).name} has no {words} samples: the "
              f"estimate runs without {'it' if len(absent) == 1 else 'them'} "
              f"(--sensors {left} says so and silences this)", file=sys.stderr)
    return absent


class FiniteCheck:
    """ConfigError (one line) when a built-in estimator's estimate stops being finite: its
    settings are within their declared ranges but beyond what the filter can compute. Fed the
    rows piece by piece (:meth:`check`); times count from the first row."""

    def __init__(self, name: str, settings: object) -> None:
        self.name = name
        self.settings = settings
        self.first_ms: int | None = None

    def check(self, quat: np.ndarray, t_ms: np.ndarray) -> None:
        if not len(t_ms):
            return
        if self.first_ms is None:
            self.first_ms = int(t_ms[0])
        bad = ~np.isfinite(quat).all(axis=1)
        if not bad.any():
            return
        base = ekf.PRESETS["default"]
        settings = self.settings
        changed = [f.name for f in dataclasses.fields(base) if settings is not None
                   and getattr(settings, f.name) != getattr(base, f.name)]
        which = (f"; changed from the default preset: {', '.join(changed[:4])}"
                 f"{' ...' if len(changed) > 4 else ''}" if changed else "")
        first = (int(t_ms[np.argmax(bad)]) - self.first_ms) / 1000.0
        raise config.ConfigError(f"the {self.name} estimate is not finite from {first:.2f} s "
                                 f"on: the settings are beyond what the filter can compute"
                                 f"{which}")


def settings_of(args: argparse.Namespace, names: list[str]) -> tuple[object, str]:
    """The settings `filter` and `evaluate` run with, and where they come from in words:
    --settings when given, else a recorded session's own, else the default preset. The course
    estimator is the course preset as it is (a note says so when --settings is given)."""
    if args.settings is not None:
        settings, which = config.load_settings(args.settings), f"--settings {args.settings}"
    else:
        found = session_json_for(config.resolve_log_path(args.log))
        recorded = read_session(found).settings if found is not None else None
        settings, which = recorded, (f"the session's recorded settings ({found})" if recorded
                                     else "the default preset")
    if "course" in names and args.settings is not None:
        print("orientation-lab: note: --estimator course is the course preset as it is; "
              "--settings applies to ekf", file=sys.stderr)
    return settings, which


# ---- your own filter ------------------------------------------------------------------------

PROGRESS_EVERY_S = 5.0


class _Progress:
    """on_progress of a user's filter on a long run: a line on stderr every PROGRESS_EVERY_S,
    how much of the log is read (the log is run chunk by chunk: a call's rows are a chunk's)."""

    def __init__(self, name: str, log: LogFile | None = None) -> None:
        self.name = name
        self.log = log
        self.started = self.said = time.monotonic()

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        share = self.log.fraction_read if self.log is not None else done / total
        if now - self.said >= PROGRESS_EVERY_S and share < 1.0:
            self.said = now
            print(f"{self.name}: {share:.0%} of the log ({now - self.started:.0f} s)",
                  file=sys.stderr, flush=True)


def user_filters(estimators: list, log: LogFile | None = None) -> list[UserFilterEstimator]:
    """The user's filters among estimators, each saying how far a long run over `log` is."""
    mine = [e for e in estimators if isinstance(e, UserFilterEstimator)]
    for estimator in mine:
        estimator.on_progress = _Progress(estimator.name, log)
    return mine


def close_all(estimators: list) -> None:
    """End the user's filters' processes (what they printed is on stderr once this returns)."""
    for estimator in estimators:
        if isinstance(estimator, UserFilterEstimator):
            estimator.close()


def report_user_filter(estimator: object, show_traceback: bool = False) -> bool:
    """What a user's filter left to say, on stderr; False when it failed (paused)."""
    if not isinstance(estimator, UserFilterEstimator):
        return True
    name = estimator.name
    missing = estimator.missing_steps()
    if missing:
        print(f"{name}: not written yet (skipped): {', '.join(missing)}", file=sys.stderr)
    for note in estimator.notes:
        print(f"{name}: {note}", file=sys.stderr)
    problem = estimator.problem
    if problem is None:
        return True
    print(f"orientation-lab: your filter stopped: {problem.message}", file=sys.stderr)
    if show_traceback:
        print(problem.details.rstrip(), file=sys.stderr)
    elif problem.details and problem.kind == "exception":
        print("(--traceback prints the whole traceback of your code)", file=sys.stderr)
    return False


def cmd_new_filter(args: argparse.Namespace) -> int:
    if args.matlab:
        return _new_matlab_filter(args.file)
    try:
        path = write_template(args.file)
    except FileExistsError:
        raise config.ConfigError(f"{args.file} exists already; not overwritten (choose another "
                                 "name)") from None
    except ValueError as error:
        raise config.ConfigError(str(error)) from None
    except OSError as error:
        raise config.ConfigError(f"cannot write {args.file}: {error.strerror or error}") \
            from None
    print(f"wrote {path}: run it with `orientation-lab --filter {path}` (the window) or "
          f"`orientation-lab evaluate LOG --estimator {path}`")
    return 0


def _new_matlab_filter(folder: str) -> int:
    try:
        path = write_matlab_template(folder)
    except FileExistsError as error:
        raise config.ConfigError(f"{error}; not overwritten (choose another folder)") from None
    except NotADirectoryError as error:
        raise config.ConfigError(str(error)) from None
    except OSError as error:
        raise config.ConfigError(f"cannot write {folder}: {error.strerror or error}") from None
    print(f"wrote the course's functions to {path}: run them with `orientation-lab --filter "
          f"{path}` (the window, in GNU Octave) or `orientation-lab evaluate LOG --estimator "
          f"{path}`; {path / 'README.md'} says what to write")
    return 0


def _check_smooth(args: argparse.Namespace, names: list[str]) -> None:
    """--smooth is the EKF's (the smoother needs its covariance)."""
    bad = [name for name in names if name not in ("ekf", "course")]
    if args.smooth and bad:
        raise config.ConfigError(f"--smooth needs the EKF (ekf or course), not {bad[0]!r}")


# ---- filter -------------------------------------------------------------------------------------

def cmd_filter(args: argparse.Namespace) -> int:
    return _filter(args)


def _filter(args: argparse.Namespace) -> int:
    sensors = config.sensor_list(args.sensors)
    names = config.estimator_names(args.estimator)
    if len(names) != 1:
        raise config.ConfigError("filter: give exactly one --estimator")
    settings, which = settings_of(args, names)
    _check_smooth(args, names)
    estimator = estimator_for(names[0], settings, sensors)   # before a long read
    try:
        return _filter_with(args, names, settings, which, sensors, estimator)
    finally:
        close_all([estimator])


def _filter_with(args: argparse.Namespace, names: list[str], settings, which: str,
                 sensors: tuple[str, ...], estimator) -> int:
    if args.output:
        check_output(args.output, args.log, args.settings if args.settings
                     and args.settings.endswith(".json") else None)
    log, found = scan(args.log, args.limits)
    user_filters([estimator], log)
    check_estimable(found, sensors)
    warn_absent(found, sensors, names)
    print(f"{args.log}: settings: {which}", file=sys.stderr)
    finite = None if isinstance(estimator, UserFilterEstimator) else FiniteCheck(
        names[0], settings or ekf.PRESETS["default"])
    # The rows are written as they come, to the output's temporary file (or, for stdout, a
    # spooled one): a file is not written when the run fails on the way.
    try:
        with (open_output(args.output, "w", encoding="ascii", newline="\n") if args.output
              else tempfile.SpooledTemporaryFile(1 << 23, "w+", encoding="ascii",
                                                 newline="\n")) as stream:
            stream.write(HEADER + "\n")
            with contextlib.redirect_stdout(sys.stderr), _log_errors():
                # what the user's code prints goes to stderr: not the CSV
                for rows in filter_rows(log, names[0] if args.smooth else estimator, settings,
                                        sensors, smooth=args.smooth):
                    if finite is not None:
                        finite.check(rows.quat, rows.t_ms)
                    write_rows(rows, stream)
            close_all([estimator])
            if not report_user_filter(estimator, args.traceback):
                raise _NothingWritten
            if not args.output:
                stream.seek(0)
                shutil.copyfileobj(stream, sys.stdout, 1 << 20)
    except _NothingWritten:
        print("orientation-lab: no estimates written", file=sys.stderr)
        return 1
    except ValueError as error:
        raise config.ConfigError(f"filter: {error}") from None
    except BrokenPipeError:
        # `filter LOG | head`: the reader had enough; say nothing, and keep Python's flush at
        # exit from failing on the closed pipe
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as error:
        raise config.ConfigError(f"cannot write {args.output or 'the estimates'}: "
                                 f"{error.strerror or error}") from None
    return 0


class _NothingWritten(Exception):
    """Your filter stopped: the estimates are not written."""


# ---- evaluate -----------------------------------------------------------------------------------

def intervals_of(args: argparse.Namespace) -> tuple[list | None, str]:
    path = args.intervals
    if path is None:
        sibling = Path(args.log).with_suffix(".json")
        if sibling.is_file():
            path = str(sibling)
    if path is None:
        return None, "whole log"
    return config.read_intervals(path), f"score intervals from {path}"


def _truth(args: argparse.Namespace) -> tuple[LogScan | None, str]:
    path = args.truth or sibling_truth(args.log)
    if path is None:
        return None, "the log's ORI"
    return scan(str(path), ori=True)[1], f"the truth in {path}"


def _row(name: str, s, width: int = 16) -> str:
    return (f"{name:<{width}}{s.samples:>9}{s.total_rmse_deg:>10.2f}{s.heading_rmse_deg:>11.2f}"
            f"{s.inclination_rmse_deg:>11.2f}")


def _reference_times(log: LogScan, truth: LogScan | None) -> np.ndarray:
    """The times [ms] of the reference orientations (the truth's, else the log's ORI) that
    are finite."""
    reference = truth if truth is not None else log
    if reference.ori_t_ms is None:
        return np.empty(0)
    return reference.ori_t_ms[np.isfinite(reference.ori_quat[:, 0])].astype(float)


def _references(log: LogScan, truth: LogScan | None, intervals: list | None,
                skip_s: float) -> int:
    """How many reference orientations lie in the intervals and after the skip (counted from
    the log's first GYR/ACC/MAG sample)."""
    t_ms = _reference_times(log, truth)
    if not len(t_ms):
        return 0
    first = float(log.first_sensor_ms) if log.first_sensor_ms is not None else t_ms[0]
    scored = intervals_mask(t_ms, intervals) & (t_ms >= first + skip_s * 1000.0)
    return int(scored.sum())


def _nothing_to_score(log: LogScan, truth: LogScan | None, where: str, skip: str) -> str:
    t_ms = _reference_times(log, truth)
    span = (f"its reference runs {(t_ms[-1] - t_ms[0]) / 1000.0:.1f} s, phone time "
            f"{int(t_ms[0])} to {int(t_ms[-1])} ms") if len(t_ms) else "no reference sample"
    return f"evaluate: no reference sample to score in the {where}{skip} ({span})"


def cmd_evaluate(args: argparse.Namespace) -> int:
    estimators: list = []
    try:
        return _evaluate(args, estimators)
    finally:
        close_all(estimators)


def _evaluate(args: argparse.Namespace, estimators: list) -> int:
    sensors = config.sensor_list(args.sensors)
    names = config.estimator_names(args.estimator)
    settings, which = settings_of(args, names)
    _check_smooth(args, names)
    intervals, where = intervals_of(args)
    for name in names:
        estimators.append(estimator_for(name, settings, sensors))
    log, found = scan(args.log, args.limits, ori=True)
    user_filters(estimators, log)
    check_estimable(found, sensors)
    warn_absent(found, sensors, names)
    truth, against = _truth(args)
    skip = f", after the first {args.skip:g} s" if args.skip else ""
    smooth = ", smoothed (forward EKF + backward RTS pass)" if args.smooth else ""
    print(f"{args.log}: error against {against} at its time stamps, {where}{skip}{smooth}; "
          f"settings: {which}")
    labels = [Path(name).name + (" smoothed" if args.smooth else "") for name in names]
    width = max([16] + [len(label) + 2 for label in labels])
    print(f"{'estimator':<{width}}{'samples':>9}{'total °':>10}{'heading °':>11}"
          f"{'inclin. °':>11}")
    status = 0
    try:
        for name, estimator, label in zip(names, estimators, labels):
            with contextlib.redirect_stdout(sys.stderr), _log_errors():
                s = evaluate_log(log, name if args.smooth else estimator, settings, sensors,
                                 intervals, args.skip, truth, smooth=args.smooth, scan=found)
            close_all([estimator])
            if not report_user_filter(estimator, args.traceback):
                print(f"{label:<{width}}{'stopped: see above':>20}", flush=True)
                status = 1
                continue
            if not s.samples and not _references(found, truth, intervals, args.skip):
                raise config.ConfigError(_nothing_to_score(found, truth, where, skip))
            builtin = not isinstance(estimator, UserFilterEstimator)
            if not s.samples or (builtin and not math.isfinite(s.total_rmse_deg)):
                raise config.ConfigError(
                    f"the {label} estimate is not finite where it is scored"
                    + (": the settings are beyond what the filter can compute" if builtin
                       else ""))
            print(_row(label, s, width), flush=True)
        if truth is not None:
            phone = evaluate_phone(found, truth, intervals, args.skip)
            if not phone.samples:
                raise config.ConfigError(_nothing_to_score(found, truth, where, skip))
            print(_row("phone (ORI)", phone, width))
    except ValueError as error:
        raise config.ConfigError(f"evaluate: {error}") from None
    return status


# ---- simulate -----------------------------------------------------------------------------------

def cmd_simulate(args: argparse.Namespace) -> int:
    if args.force:
        print("orientation-lab: note: --force is no longer needed: -o replaces an output file "
              "(it is accepted and ignored)", file=sys.stderr)
    check_output(args.output)
    rates = {"gyr": args.rate, "acc": args.rate, "mag": args.mag_rate or args.rate / 2,
             "ori": args.rate}
    for option, rate in (("--rate", args.rate), ("--mag-rate", rates["mag"])):
        if rate > MAX_RATE_HZ:
            raise config.ConfigError(f"simulate: {option} {rate:g} Hz: at most "
                                     f"{MAX_RATE_HZ:g} Hz (time stamps are whole milliseconds)")
        if rate * args.duration < 2:
            raise config.ConfigError(f"simulate: {option} {rate:g} Hz gives fewer than 2 samples "
                                     f"in {args.duration:g} s; give at least "
                                     f"{2 / args.duration:.3g} Hz or a longer --duration")
    try:
        session = simulate(duration_s=args.duration, rates_hz=rates, seed=args.seed,
                           gyro_bias=tuple(args.gyro_bias))
    except ValueError as error:
        raise config.ConfigError(f"simulate: {error}") from None
    with open_output(args.output, "wb") as stream:    # float32 text like the phone's
        write_session_to(session, stream, compress=str(args.output).endswith(".gz"))
    return 0


# ---- export -------------------------------------------------------------------------------------

def cmd_export(args: argparse.Namespace) -> int:
    from app.engine.offline.export import export_session
    separator = args.separator or ("semicolon" if args.decimal_comma else "comma")
    print(export_session(args.session, args.format, args.output, args.from_marker,
                         args.to_marker, args.from_s, args.to_s, separator,
                         args.decimal_comma))
    return 0


# ---- registration -------------------------------------------------------------------------------

def _log_filter_options(parser: argparse.ArgumentParser, several: bool) -> None:
    parser.add_argument("log", help="phone log (the Sensor Fusion app's text format, .txt or "
                                    ".txt.gz), or a recorded session folder")
    options.add_estimator(parser, several)
    options.add_sensors(parser)
    options.add_settings(parser)
    options.add_limits(parser)
    options.add_traceback(parser)
    options.add_octave(parser)
    options.add_smooth(parser)


def add_commands(sub) -> None:
    n = sub.add_parser("new-filter", help="write a template for your own filter (tu_qw, mu_g, "
                                          "mu_m, mu_normalizeQ as stubs), in Python or MATLAB",
                       description="Write FILE.py: the course's filterTemplate in Python, to run "
                                   "with --filter FILE.py or --estimator FILE.py; with --matlab, "
                                   "a folder DIR of the course's .m functions, run in GNU Octave "
                                   "with --filter DIR. An existing file is never overwritten.")
    n.add_argument("file", metavar="FILE.py|DIR")
    n.add_argument("--matlab", action="store_true",
                   help="write the course's MATLAB functions (tu_qw.m, mu_g.m, mu_m.m, "
                        "mu_normalizeQ.m, the outlier tests, the kit's helpers, a README) into "
                        "the folder DIR")
    n.set_defaults(func=cmd_new_filter)

    f = sub.add_parser("filter", help="run an estimator over a log and write its estimates as CSV")
    _log_filter_options(f, several=False)
    f.add_argument("-o", "--output", metavar="OUT.csv",
                   help="output file (default: standard output)")
    f.set_defaults(func=cmd_filter)

    e = sub.add_parser("evaluate", help="RMSE of the estimate against a truth file or the log's ORI")
    _log_filter_options(e, several=True)
    options.add_intervals(e)
    options.add_truth(e)
    options.add_skip(e)
    e.set_defaults(func=cmd_evaluate)

    x = sub.add_parser("export", help="export a session: CSV, the phone's text format, MATLAB .mat",
                       description="Replay a recorded session (or a phone's log) as the window "
                                   "does and write its measurements and estimates.")
    x.add_argument("session", help="a recorded session folder, its raw.txt or session.json, or "
                                   "a log saved on the phone")
    x.add_argument("--format", required=True, choices=("csv", "log", "mat"),
                   help="csv: measurements and estimates with a header of units; log: the "
                        "phone's text format (the course's MATLAB reader, `send`); mat: the "
                        "course kit's meas and xhat structs")
    x.add_argument("-o", "--output", required=True, metavar="OUT", help="the file to write")
    x.add_argument("--from-marker", metavar="A", help="start at marker A (number or label)")
    x.add_argument("--to-marker", metavar="B", help="end at marker B (number or label)")
    x.add_argument("--from", dest="from_s", type=options.NON_NEGATIVE, metavar="S",
                   help="start S seconds after the session's start")
    x.add_argument("--to", dest="to_s", type=options.NON_NEGATIVE, metavar="S",
                   help="end S seconds after the session's start")
    x.add_argument("--separator", default=None, choices=("comma", "semicolon", "tab"),
                   help="CSV field separator (default comma; semicolon with --decimal-comma)")
    x.add_argument("--decimal-comma", action="store_true",
                   help="CSV numbers with a decimal comma (needs --separator semicolon or tab)")
    x.set_defaults(func=cmd_export)

    s = sub.add_parser("simulate", help="write a simulated phone log with ORI = the true "
                                        "orientation")
    s.add_argument("-o", "--output", required=True, metavar="LOG")
    s.add_argument("--duration", type=options.POSITIVE, default=120.0, metavar="S")
    s.add_argument("--seed", type=options.SEED, default=0, metavar="N",
                   help="random seed, a whole number >= 0 (default 0)")
    s.add_argument("--rate", type=options.POSITIVE, default=100.0, metavar="HZ",
                   help="GYR/ACC/ORI rate, at most 1000 (default 100)")
    s.add_argument("--mag-rate", type=options.POSITIVE, default=None, metavar="HZ",
                   help="MAG rate, at most 1000 (default rate/2)")
    s.add_argument("--gyro-bias", type=options.FINITE, nargs=3, default=(0.0, 0.0, 0.0),
                   metavar=("BX", "BY", "BZ"), help="gyroscope bias, rad/s")
    s.add_argument("--force", action="store_true", help=argparse.SUPPRESS)
    s.set_defaults(func=cmd_simulate)
