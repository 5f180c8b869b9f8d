"""Command line: `orientation-lab` opens the window; subcommands run headless.

Headless commands (filter, evaluate, calibrate, simulate, send, serve) never import Qt. Any bad
argument or unreadable file gives a one-line error on stderr and exit status 2, no traceback.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path
from typing import Sequence

from app import __version__

EXIT_USAGE = 2


class UsageError(Exception):
    """A problem with the user's input: reported in one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, no usage dump
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


# ---- shared option handling --------------------------------------------------------------------

def _add_filter_options(p: argparse.ArgumentParser) -> None:
    import ekf
    p.add_argument("log", help="phone log (the Sensor Fusion app's text format, .txt or .txt.gz)")
    p.add_argument("--estimator", default="ekf",
                   help=f"estimator, or several separated by commas: {', '.join(ekf.ESTIMATORS)} (default ekf)")
    p.add_argument("--sensors", default="gyr,acc,mag",
                   help="sensors used by the filter, comma-separated subset of gyr,acc,mag (default all)")
    p.add_argument("--settings", metavar="FILE.json",
                   help="filter settings (JSON, e.g. written by `calibrate`)")


def _parse_sensors(text: str) -> tuple[str, ...]:
    parts = tuple(s.strip() for s in text.split(",") if s.strip())
    bad = [s for s in parts if s not in ("gyr", "acc", "mag")]
    if bad or not parts:
        raise UsageError(f"--sensors: expected a non-empty subset of gyr,acc,mag, got {text!r}")
    return parts


def _parse_estimators(text: str) -> list[str]:
    import ekf
    names = [s.strip() for s in text.split(",") if s.strip()]
    bad = [n for n in names if n not in ekf.ESTIMATORS]
    if bad or not names:
        raise UsageError(f"--estimator: unknown {', '.join(bad) or repr(text)}; choose from {', '.join(ekf.ESTIMATORS)}")
    return names


def _load_settings(path: str | None):
    import ekf
    if path is None:
        return None
    if path in ekf.PRESETS and not Path(path).exists():
        return ekf.PRESETS[path]   # a preset name: --settings course
    try:
        return ekf.EKFSettings.load(path)
    except FileNotFoundError:
        raise UsageError(f"settings file not found: {path}") from None
    except (OSError, ValueError, TypeError) as e:
        raise UsageError(f"bad settings file {path}: {e}") from None


def _read_log(path: str):
    from app.io.logfile import LogError, read_log
    try:
        log = read_log(path)
    except FileNotFoundError:
        raise UsageError(f"log file not found: {path}") from None
    except IsADirectoryError:
        raise UsageError(f"log path is a directory: {path}") from None
    except LogError as e:
        raise UsageError(str(e)) from None
    except OSError as e:
        raise UsageError(f"cannot read {path}: {e.strerror or e}") from None
    summary = log.stats.summary()
    if summary:
        print(summary if summary.startswith(Path(path).name) else f"{path}: {summary}", file=sys.stderr)
    return log


def _run(arrays, estimator: str, settings, sensors):
    import numpy as np
    import ekf
    rows = ~(np.isnan(arrays.gyr).all(axis=1) & np.isnan(arrays.acc).all(axis=1)
             & np.isnan(arrays.mag).all(axis=1))
    t_ms = arrays.t_ms[rows]
    result = ekf.filter_batch(t_ms / 1000.0, arrays.gyr[rows], arrays.acc[rows], arrays.mag[rows],
                              settings=settings, estimator=estimator, sensors=sensors)
    return t_ms, result


# ---- filter -------------------------------------------------------------------------------------

def cmd_filter(args: argparse.Namespace) -> int:
    sensors = _parse_sensors(args.sensors)
    estimators = _parse_estimators(args.estimator)
    if len(estimators) != 1:
        raise UsageError("filter: give exactly one --estimator")
    settings = _load_settings(args.settings)
    log = _read_log(args.log)
    t_ms, r = _run(log.to_arrays(), estimators[0], settings, sensors)
    out = open(args.output, "w", newline="") if args.output else sys.stdout
    try:
        w = csv.writer(out, lineterminator="\n")
        w.writerow(["t_ms", "qw", "qx", "qy", "qz", "acc_rejected", "mag_rejected", "at_rest"])
        for k in range(len(t_ms)):
            q = r.quat[k]
            w.writerow([int(t_ms[k]), f"{q[0]:.9f}", f"{q[1]:.9f}", f"{q[2]:.9f}", f"{q[3]:.9f}",
                        int(r.acc_rejected[k]), int(r.mag_rejected[k]), int(r.at_rest[k])])
    except OSError as e:
        raise UsageError(f"cannot write {args.output}: {e.strerror or e}") from None
    finally:
        if out is not sys.stdout:
            out.close()
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
    try:
        data = json.loads(Path(path).read_text())
        iv = data["score_intervals_ms"]
        if not all(len(x) == 2 for x in iv):
            raise ValueError("score_intervals_ms must be a list of [start, end] pairs")
    except FileNotFoundError:
        raise UsageError(f"intervals file not found: {path}") from None
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise UsageError(f"bad intervals file {path}: {e}") from None
    return iv, f"score intervals from {path}"


def evaluate_log(log, estimator: str, settings, sensors, intervals, skip_s: float):
    """RMSE (deg) of total/heading/inclination error against the log's ORI at ORI times.

    The estimate at an ORI time is the latest estimate at or before it (what a viewer would see).
    """
    import numpy as np
    import ekf
    arrays = log.to_arrays()
    t_est, r = _run(arrays, estimator, settings, sensors)
    has_ori = ~np.isnan(arrays.ori).any(axis=1)
    t_ref = arrays.t_ms[has_ori]
    q_ref = arrays.ori[has_ori]
    if len(t_ref) == 0:
        raise UsageError("evaluate: the log has no ORI lines to compare with")
    if len(t_est) == 0:
        raise UsageError("evaluate: the log has no GYR/ACC/MAG samples")
    idx = np.searchsorted(t_est, t_ref, side="right") - 1
    valid = idx >= 0
    q_est = np.full_like(q_ref, np.nan)
    q_est[valid] = r.quat[idx[valid]]
    mask = ekf.metrics.intervals_mask(t_ref, intervals)
    mask &= t_ref >= t_est[0] + skip_s * 1000.0
    return ekf.summarize(q_est, q_ref, mask)


def cmd_evaluate(args: argparse.Namespace) -> int:
    sensors = _parse_sensors(args.sensors)
    estimators = _parse_estimators(args.estimator)
    settings = _load_settings(args.settings)
    intervals, where = _intervals(args)
    log = _read_log(args.log)
    print(f"{args.log}: error against ORI, {where}" + (f", after the first {args.skip:g} s" if args.skip else ""))
    print(f"{'estimator':<16}{'samples':>9}{'total °':>10}{'heading °':>11}{'inclin. °':>11}")
    for name in estimators:
        s = evaluate_log(log, name, settings, sensors, intervals, args.skip)
        print(f"{name:<16}{s.samples:>9}{s.total_rmse_deg:>10.2f}{s.heading_rmse_deg:>11.2f}"
              f"{s.inclination_rmse_deg:>11.2f}")
    return 0


# ---- calibrate ----------------------------------------------------------------------------------

def cmd_calibrate(args: argparse.Namespace) -> int:
    import numpy as np
    import ekf
    from ekf import calibration
    log = _read_log(args.log)
    a = log.to_arrays()
    t_s = a.t_ms / 1000.0
    if np.isnan(a.acc).all():
        raise UsageError("calibrate: the log has no ACC lines")
    if args.whole:
        sel = np.ones(len(t_s), bool)
    else:
        segment = calibration.find_rest_segment(t_s, a.gyr, a.acc)
        if segment is None:
            raise UsageError("calibrate: found no still interval of at least 1 s (use --whole to take all)")
        start, end = segment
        sel = (t_s >= start) & (t_s <= end)
        print(f"still interval: {start - t_s[0]:.2f} s to {end - t_s[0]:.2f} s from the start of the log")
    cal = calibration.calibrate(a.acc[sel], a.gyr[sel], a.mag[sel])
    print(cal.format_table())
    if args.output:
        base = _load_settings(args.settings) or ekf.PRESETS["default"]
        settings = cal.to_settings(base)
        payload = {"settings": settings.to_dict(), "calibration": cal.to_dict(),
                   "source": str(args.log)}
        try:
            Path(args.output).write_text(json.dumps(payload, indent=2) + "\n")
        except OSError as e:
            raise UsageError(f"cannot write {args.output}: {e.strerror or e}") from None
        print(f"settings written to {args.output}")
    return 0


# ---- simulate -----------------------------------------------------------------------------------

def cmd_simulate(args: argparse.Namespace) -> int:
    from ekf.simulate import simulate
    from app.io.demo import write_session
    if args.duration <= 0:
        raise UsageError("--duration must be positive")
    if args.rate <= 0:
        raise UsageError("--rate must be positive")
    rates = {"gyr": args.rate, "acc": args.rate, "mag": args.mag_rate or args.rate / 2, "ori": args.rate}
    session = simulate(duration_s=args.duration, rates_hz=rates, seed=args.seed,
                       gyro_bias=tuple(args.gyro_bias))
    try:
        write_session(session, args.output)   # float32 text like the phone's; .gz compresses
    except OSError as e:
        raise UsageError(f"cannot write {args.output}: {e.strerror or e}") from None
    return 0


# ---- entry point --------------------------------------------------------------------------------

def _add_gui_arguments(p: argparse.ArgumentParser) -> None:
    """Options of the window (no command). Defined here so that parsing never imports Qt."""
    g = p.add_argument_group("window")
    g.add_argument("--host", default="0.0.0.0", help="address to listen on for the phone (default all)")
    g.add_argument("--port", type=int, default=3400, help="TCP port for the phone (default 3400)")
    g.add_argument("--demo", action="store_true", help="play the built-in demo session (still listening)")
    g.add_argument("--replay", metavar="LOG", help="play a phone log or recording")
    g.add_argument("--speed", type=float, default=1.0, help="replay speed (default 1)")
    g.add_argument("--loop", action="store_true", help="replay in a loop")
    g.add_argument("--settings", metavar="FILE.json", help="filter settings")
    g.add_argument("--screenshot", metavar="PNG", help="save the window to PNG (with --exit-after)")
    g.add_argument("--exit-after", type=float, metavar="S", help="quit after S seconds")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="orientation-lab",
                description="Orientation Lab: a quaternion EKF beside the phone's own estimate. "
                            "Without a command, opens the window listening for the phone.")
    p.add_argument("--version", action="version", version=f"orientation-lab {__version__}")
    _add_gui_arguments(p)
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    f = sub.add_parser("filter", help="run an estimator over a log and write its estimates as CSV")
    _add_filter_options(f)
    f.add_argument("-o", "--output", metavar="OUT.csv", help="output file (default: standard output)")
    f.set_defaults(func=cmd_filter)

    e = sub.add_parser("evaluate", help="RMSE of the estimate against the log's ORI")
    _add_filter_options(e)
    e.add_argument("--intervals", metavar="FILE.json",
                   help="JSON with score_intervals_ms (default: LOG's sibling .json if present)")
    e.add_argument("--skip", type=float, default=0.0, metavar="S",
                   help="ignore the first S seconds (convergence), default 0")
    e.set_defaults(func=cmd_evaluate)

    c = sub.add_parser("calibrate", help="noise statistics from rest data (task 2) and settings")
    c.add_argument("log")
    c.add_argument("-o", "--output", metavar="SETTINGS.json", help="write settings for the other commands")
    c.add_argument("--settings", metavar="FILE.json", help="base settings to complete (default preset otherwise)")
    c.add_argument("--whole", action="store_true", help="use the whole log instead of the longest still interval")
    c.set_defaults(func=cmd_calibrate)

    s = sub.add_parser("simulate", help="write a simulated phone log with ORI = the true orientation")
    s.add_argument("-o", "--output", required=True, metavar="LOG")
    s.add_argument("--duration", type=float, default=120.0, metavar="S")
    s.add_argument("--seed", type=int, default=0, metavar="N")
    s.add_argument("--rate", type=float, default=100.0, metavar="HZ", help="GYR/ACC/ORI rate (default 100)")
    s.add_argument("--mag-rate", type=float, default=None, metavar="HZ", help="MAG rate (default rate/2)")
    s.add_argument("--gyro-bias", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("BX", "BY", "BZ"),
                   help="gyroscope bias, rad/s")
    s.set_defaults(func=cmd_simulate)

    try:
        from app import cli_live
    except ImportError:
        cli_live = None
    if cli_live is not None:
        cli_live.add_subcommands(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if getattr(args, "func", None) is not None:
            return int(args.func(args) or 0)
        from app.ui.main import run_gui
        return int(run_gui(args) or 0)
    except UsageError as e:
        print(f"orientation-lab: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0
