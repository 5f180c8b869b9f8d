"""The offline commands: filter, evaluate, calibrate, simulate. Headless: they never import Qt.

filter and evaluate run the engine's runner (app.engine.offline), the same path as the live
engine, so a file gives the estimates its live replay gives.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import ekf
from ekf import calibration
from ekf.simulate import simulate
from app.cli import options
from app.engine import config, estimates
from app.engine.offline import evaluate_log, evaluate_phone, filter_log, sibling_truth
from app.stream.demo import write_session
from app.stream.logfile import LogData


def read_log(path: str) -> LogData:
    """The log, with its one-line summary (damage, clock quirks) on stderr."""
    log = config.open_log(path)
    summary = log.stats.summary()
    if summary:
        print(summary if summary.startswith(Path(path).name) else f"{path}: {summary}",
              file=sys.stderr)
    return log


def _check_smooth(args: argparse.Namespace, names: list[str]) -> None:
    """--smooth is the EKF's (the smoother needs its covariance)."""
    bad = [name for name in names if name not in ("ekf", "course")]
    if args.smooth and bad:
        raise config.ConfigError(f"--smooth needs the EKF (ekf or course), not {bad[0]!r}")


# ---- filter -------------------------------------------------------------------------------------

def cmd_filter(args: argparse.Namespace) -> int:
    sensors = config.sensor_list(args.sensors)
    names = config.estimator_names(args.estimator)
    if len(names) != 1:
        raise config.ConfigError("filter: give exactly one --estimator")
    settings = config.load_settings(args.settings)
    _check_smooth(args, names)
    try:
        rows = filter_log(read_log(args.log), names[0], settings, sensors, smooth=args.smooth)
    except ValueError as error:
        raise config.ConfigError(f"filter: {error}") from None
    try:
        if args.output:
            with open(args.output, "w", encoding="ascii", newline="\n") as stream:
                estimates.write_csv(rows, stream)
        else:
            estimates.write_csv(rows, sys.stdout)
    except OSError as error:
        raise config.ConfigError(f"cannot write {args.output}: {error.strerror or error}") \
            from None
    return 0


# ---- evaluate -----------------------------------------------------------------------------------

def _intervals(args: argparse.Namespace) -> tuple[list | None, str]:
    path = args.intervals
    if path is None:
        sibling = Path(args.log).with_suffix(".json")
        if sibling.is_file():
            path = str(sibling)
    if path is None:
        return None, "whole log"
    return config.read_intervals(path), f"score intervals from {path}"


def _truth(args: argparse.Namespace) -> tuple[LogData | None, str]:
    path = args.truth or sibling_truth(args.log)
    if path is None:
        return None, "the log's ORI"
    return read_log(str(path)), f"the truth in {path}"


def _row(name: str, s) -> str:
    return (f"{name:<16}{s.samples:>9}{s.total_rmse_deg:>10.2f}{s.heading_rmse_deg:>11.2f}"
            f"{s.inclination_rmse_deg:>11.2f}")


def cmd_evaluate(args: argparse.Namespace) -> int:
    sensors = config.sensor_list(args.sensors)
    names = config.estimator_names(args.estimator)
    settings = config.load_settings(args.settings)
    _check_smooth(args, names)
    intervals, where = _intervals(args)
    log = read_log(args.log)
    truth, against = _truth(args)
    skip = f", after the first {args.skip:g} s" if args.skip else ""
    smooth = ", smoothed (forward EKF + backward RTS pass)" if args.smooth else ""
    print(f"{args.log}: error against {against} at its time stamps, {where}{skip}{smooth}")
    print(f"{'estimator':<16}{'samples':>9}{'total °':>10}{'heading °':>11}{'inclin. °':>11}")
    try:
        for name in names:
            s = evaluate_log(log, name, settings, sensors, intervals, args.skip, truth,
                             smooth=args.smooth)
            print(_row(name + (" smoothed" if args.smooth else ""), s))
        if truth is not None:
            print(_row("phone (ORI)", evaluate_phone(log, truth, intervals, args.skip)))
    except ValueError as error:
        raise config.ConfigError(f"evaluate: {error}") from None
    return 0


# ---- calibrate ----------------------------------------------------------------------------------

def cmd_calibrate(args: argparse.Namespace) -> int:
    arrays = read_log(args.log).to_arrays()
    t_s = arrays.t_ms / 1000.0
    if np.isnan(arrays.acc).all():
        raise config.ConfigError("calibrate: the log has no ACC lines")
    if args.whole:
        chosen = np.ones(len(t_s), bool)
    else:
        segment = calibration.find_rest_segment(t_s, arrays.gyr, arrays.acc)
        if segment is None:
            raise config.ConfigError("calibrate: found no still interval of at least 1 s "
                                     "(use --whole to take all)")
        start, end = segment
        chosen = (t_s >= start) & (t_s <= end)
        print(f"still interval: {start - t_s[0]:.2f} s to {end - t_s[0]:.2f} s from the start "
              "of the log")
    result = calibration.calibrate(arrays.acc[chosen], arrays.gyr[chosen], arrays.mag[chosen])
    print(result.format_table())
    if args.output:
        base = config.load_settings(args.settings) or ekf.PRESETS["default"]
        payload = {"settings": result.to_settings(base).to_dict(),
                   "calibration": result.to_dict(), "source": str(args.log)}
        try:
            Path(args.output).write_text(json.dumps(payload, indent=2) + "\n")
        except OSError as error:
            raise config.ConfigError(f"cannot write {args.output}: {error.strerror or error}") \
                from None
        print(f"settings written to {args.output}")
    return 0


# ---- simulate -----------------------------------------------------------------------------------

def cmd_simulate(args: argparse.Namespace) -> int:
    rates = {"gyr": args.rate, "acc": args.rate, "mag": args.mag_rate or args.rate / 2,
             "ori": args.rate}
    session = simulate(duration_s=args.duration, rates_hz=rates, seed=args.seed,
                       gyro_bias=tuple(args.gyro_bias))
    try:
        write_session(session, args.output)   # float32 text like the phone's; .gz compresses
    except OSError as error:
        raise config.ConfigError(f"cannot write {args.output}: {error.strerror or error}") \
            from None
    return 0


# ---- registration -------------------------------------------------------------------------------

def _log_filter_options(parser: argparse.ArgumentParser, several: bool) -> None:
    parser.add_argument("log", help="phone log (the Sensor Fusion app's text format, .txt or "
                                    ".txt.gz), or a recorded session folder")
    options.add_estimator(parser, several)
    options.add_sensors(parser)
    options.add_settings(parser)
    options.add_smooth(parser)


def add_commands(sub) -> None:
    f = sub.add_parser("filter", help="run an estimator over a log and write its estimates as CSV")
    _log_filter_options(f, several=False)
    f.add_argument("-o", "--output", metavar="OUT.csv",
                   help="output file (default: standard output)")
    f.set_defaults(func=cmd_filter)

    e = sub.add_parser("evaluate", help="RMSE of the estimate against a truth file or the log's ORI")
    _log_filter_options(e, several=True)
    e.add_argument("--intervals", metavar="FILE.json",
                   help="JSON with score_intervals_ms (default: LOG's sibling .json if present)")
    options.add_truth(e)
    e.add_argument("--skip", type=options.NON_NEGATIVE, default=0.0, metavar="S",
                   help="ignore the first S seconds (convergence), default 0")
    e.set_defaults(func=cmd_evaluate)

    c = sub.add_parser("calibrate", help="noise statistics from rest data (task 2) and settings")
    c.add_argument("log")
    c.add_argument("-o", "--output", metavar="SETTINGS.json",
                   help="write settings for the other commands")
    options.add_settings(c, "base settings to complete (default preset otherwise)")
    c.add_argument("--whole", action="store_true",
                   help="use the whole log instead of the longest still interval")
    c.set_defaults(func=cmd_calibrate)

    s = sub.add_parser("simulate", help="write a simulated phone log with ORI = the true "
                                        "orientation")
    s.add_argument("-o", "--output", required=True, metavar="LOG")
    s.add_argument("--duration", type=options.POSITIVE, default=120.0, metavar="S")
    s.add_argument("--seed", type=int, default=0, metavar="N")
    s.add_argument("--rate", type=options.POSITIVE, default=100.0, metavar="HZ",
                   help="GYR/ACC/ORI rate (default 100)")
    s.add_argument("--mag-rate", type=options.POSITIVE, default=None, metavar="HZ",
                   help="MAG rate (default rate/2)")
    s.add_argument("--gyro-bias", type=float, nargs=3, default=(0.0, 0.0, 0.0),
                   metavar=("BX", "BY", "BZ"), help="gyroscope bias, rad/s")
    s.set_defaults(func=cmd_simulate)
