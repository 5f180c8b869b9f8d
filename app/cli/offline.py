"""The offline commands: filter, evaluate, simulate (calibrate, calibrate-mag and tune are in
app.cli.calibration). Headless: they never import Qt.

filter and evaluate run the engine's runner (app.engine.offline), the same path as the live
engine, so a file gives the estimates its live replay gives.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ekf.simulate import simulate
from app.cli import options
from app.engine import config, estimates
from app.engine.offline import evaluate_log, filter_log
from app.stream.demo import write_session
from app.stream.logfile import LogData


def read_log(path: str, limits=None) -> LogData:
    """The log, with its one-line summary (damage by reason, clock quirks) on stderr."""
    log = config.open_log(path, limits or config.sensor_limits(""))
    summary = log.stats.summary()
    if summary:
        print(summary if summary.startswith(Path(path).name) else f"{path}: {summary}",
              file=sys.stderr)
    return log


# ---- filter -------------------------------------------------------------------------------------

def cmd_filter(args: argparse.Namespace) -> int:
    sensors = config.sensor_list(args.sensors)
    names = config.estimator_names(args.estimator)
    if len(names) != 1:
        raise config.ConfigError("filter: give exactly one --estimator")
    settings = config.load_settings(args.settings)
    rows = filter_log(read_log(args.log, args.limits), names[0], settings, sensors)
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

def intervals_of(args: argparse.Namespace) -> tuple[list | None, str]:
    path = args.intervals
    if path is None:
        sibling = Path(args.log).with_suffix(".json")
        if sibling.is_file():
            path = str(sibling)
    if path is None:
        return None, "whole log"
    return config.read_intervals(path), f"score intervals from {path}"


def cmd_evaluate(args: argparse.Namespace) -> int:
    sensors = config.sensor_list(args.sensors)
    names = config.estimator_names(args.estimator)
    settings = config.load_settings(args.settings)
    intervals, where = intervals_of(args)
    log = read_log(args.log, args.limits)
    skip = f", after the first {args.skip:g} s" if args.skip else ""
    print(f"{args.log}: error against ORI, {where}{skip}")
    print(f"{'estimator':<16}{'samples':>9}{'total °':>10}{'heading °':>11}{'inclin. °':>11}")
    for name in names:
        try:
            s = evaluate_log(log, name, settings, sensors, intervals, args.skip)
        except ValueError as error:
            raise config.ConfigError(f"evaluate: {error}") from None
        print(f"{name:<16}{s.samples:>9}{s.total_rmse_deg:>10.2f}{s.heading_rmse_deg:>11.2f}"
              f"{s.inclination_rmse_deg:>11.2f}")
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
    options.add_limits(parser)


def add_commands(sub) -> None:
    f = sub.add_parser("filter", help="run an estimator over a log and write its estimates as CSV")
    _log_filter_options(f, several=False)
    f.add_argument("-o", "--output", metavar="OUT.csv",
                   help="output file (default: standard output)")
    f.set_defaults(func=cmd_filter)

    e = sub.add_parser("evaluate", help="RMSE of the estimate against the log's ORI")
    _log_filter_options(e, several=True)
    options.add_intervals(e)
    options.add_skip(e)
    e.set_defaults(func=cmd_evaluate)

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
