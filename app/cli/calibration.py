"""The calibration commands: calibrate (task 2 at rest), calibrate-mag (hard and soft iron) and
tune (search settings against the log's reference). Headless: Qt is imported only for --plots,
inside the function that draws (app.ui.figures), and its absence is a one-line error.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import ekf
from ekf.calibration import CalibrationResult
from app.cli import options
from app.cli.offline import FiniteCheck, intervals_of, open_log_noted, warn_absent
from app.engine import config
from app.engine.tuning import autotune, profiles
from app.engine.tuning.calibration import RestCalibration, mag_from_log, rest_from_log
from app.engine.offline.outputs import check_output, write_output
from app.engine.offline.refilter import refilter
from app.stream.logfile import LogData


def _write_json(path: str, payload: dict[str, Any], *inputs: str | None) -> None:
    """The settings file, written only when `--settings` would accept what it holds."""
    check_output(path, *inputs)
    text = json.dumps(profiles.jsonable(payload), indent=2) + "\n"
    try:
        ekf.EKFSettings.from_file_value(json.loads(text))
    except ValueError as error:
        raise config.ConfigError(f"not written to {path}: the settings would be refused: "
                                 f"{error}") from None
    write_output(path, text)
    print(f"settings written to {path}")


def _figures():
    """app.ui.figures, or a one-line ConfigError when Qt cannot be imported."""
    try:
        from app.ui import figures
    except ImportError as error:
        raise config.ConfigError(f"--plots needs Qt (PySide6, pyqtgraph): {error}") from None
    return figures


def _plots_folder(path: str | None) -> None:
    """--plots names a folder that exists or can be made, and that takes files: checked before
    the analysis runs, so a wrong path is one line and costs no waiting."""
    if path is None:
        return
    folder = Path(path)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / ".orientation-lab-probe"
        probe.write_bytes(b"")
        probe.unlink()
    except FileExistsError:
        raise config.ConfigError(f"--plots {path}: not a folder (a file of that name exists)") \
            from None
    except OSError as error:
        raise config.ConfigError(f"--plots {path}: cannot write there: "
                                 f"{error.strerror or error}") from None


def _save_figures(save, *data: Any, folder: str) -> None:
    try:
        written = save(*data, folder)
    except OSError as error:
        raise config.ConfigError(f"--plots {folder}: cannot write the figures: "
                                 f"{error.strerror or error}") from None
    for path in written:
        print(f"wrote {path}")


def _keep_in_profile(name: str, **parts: Any) -> None:
    store = profiles.ProfileStore()
    try:
        profile = store.load(name)
    except config.ConfigError:
        profile = profiles.Profile(name)
    for key, value in parts.items():
        setattr(profile, key, value)
    print(f"profile {profile.name!r} saved to {store.save(profile)}")
    for text in profile.warnings(profile.to_settings()):
        print(f"warning: {text}")


# ---- calibrate ------------------------------------------------------------------------------------

def _print_rest(rest: RestCalibration, t0: float) -> None:
    if rest.interval_s is not None:
        start, end = rest.interval_s
        print(f"{rest.how}: {start - t0:.2f} s to {end - t0:.2f} s from the start of the log")
    print(rest.analysis.result.format_table())
    print()
    print(rest.analysis.format_report())
    if rest.allan is not None:
        print()
        print(rest.allan.format_table())


def _measured(make: Callable[[], ekf.EKFSettings]) -> ekf.EKFSettings:
    """The settings made from measured values, or a one-line ConfigError when the filter would
    refuse them (a value outside its setting's declaration)."""
    try:
        return make()
    except ValueError as error:
        raise config.ConfigError(f"nothing written: the measured values are no settings the "
                                 f"filter accepts: {error}") from None


def _refuse_constant(result: CalibrationResult) -> None:
    """ConfigError (one line) when a sensor axis holds one value over the whole interval: it
    has no noise to measure, so its statistics (and a covariance from them) mean nothing."""
    constant = result.constant_axes()
    if constant:
        names = ", ".join(f"{sensor} {axis}" for sensor, axis, _ in constant)
        sensor, axis, value = constant[0]
        raise config.ConfigError(
            f"calibrate: {names} {'is' if len(constant) == 1 else 'are'} constant over the "
            f"interval ({sensor} {axis} = {value:g} in every sample): a reading that never "
            "changes has no noise to measure (a stuck axis, or data not from a sensor)")


def cmd_calibrate(args: argparse.Namespace) -> int:
    _plots_folder(args.plots)
    if args.output:
        check_output(args.output, args.log)
    log = open_log_noted(args.log, args.limits)
    start, end = args.range if args.range else (None, None)
    with warnings.catch_warnings(record=True) as caught:     # kept until the data is checked
        warnings.simplefilter("always")
        rest = rest_from_log(log, start, None if end == float("inf") else end, whole=args.whole)
    result = rest.analysis.result
    _refuse_constant(result)
    for warning in caught:
        warnings.warn_explicit(warning.message, warning.category, warning.filename,
                               warning.lineno)
    _print_rest(rest, float(log.to_arrays().t_s[0]))
    calibration = {"rest": result.to_dict(), "analysis": rest.analysis.to_dict(),
                   "allan": rest.allan.to_dict() if rest.allan else None}
    if args.output:
        base = config.load_settings(args.settings) or ekf.PRESETS["default"]
        settings = _measured(lambda: result.to_settings(base))
        _write_json(args.output, {"settings": settings.to_dict(),
                                  "calibration": calibration, "source": str(args.log)},
                    args.log)
    if args.profile:
        _keep_in_profile(args.profile, rest=result.to_dict(),
                         allan=rest.allan.to_dict() if rest.allan else None)
    if args.plots:
        _save_figures(_figures().save_rest_figures, rest.analysis, rest.allan,
                      folder=args.plots)
    return 0


# ---- calibrate-mag --------------------------------------------------------------------------------

def cmd_calibrate_mag(args: argparse.Namespace) -> int:
    _plots_folder(args.plots)
    if args.output:
        check_output(args.output, args.log)
    log = open_log_noted(args.log, args.limits)
    start, end = args.range if args.range else (None, None)
    result, raw = mag_from_log(log, start, None if end == float("inf") else end)
    print(result.format_report())
    if args.output:
        base = config.load_settings(args.settings) or ekf.PRESETS["default"]
        settings = _measured(lambda: base.with_changes(**result.settings_changes()))
        _write_json(args.output, {"settings": settings.to_dict(),
                                  "calibration": {"mag": result.to_dict()},
                                  "source": str(args.log)}, args.log)
    if args.profile:
        _keep_in_profile(args.profile, mag=result.to_dict())
    if args.plots:
        _save_figures(_figures().save_mag_figures, result, raw, folder=args.plots)
    return 0


# ---- tune -----------------------------------------------------------------------------------------

def _range_ms(prepared: LogData, span: tuple[float, float],
              flag: str = "--range") -> list[list[float]]:
    """A START:END range in seconds as phone-time ms; ConfigError when it starts at or after
    the log's end."""
    if span[0] >= prepared.duration_s:
        end = "" if span[1] == float("inf") else f"{span[1]:g}"
        raise config.ConfigError(f"tune: {flag} {span[0]:g}:{end} starts after the log's end "
                                 f"({prepared.duration_s:.1f} s)")
    start = prepared.start_ms
    hi = min(span[1], prepared.duration_s)
    return [[start + span[0] * 1000.0, start + hi * 1000.0]]


def _targets(args: argparse.Namespace, prepared: LogData) -> tuple[autotune.Target,
                                                                          autotune.Target | None]:
    """The tuning range and the check range: given, or the log's halves."""
    if args.range:
        tune_ms, tune_label = _range_ms(prepared, args.range), "range %g:%g s" % args.range
    else:
        tune_ms, tune_label = intervals_of(args)
    check_prepared, check_label = prepared, ""
    if args.check_log:
        check_prepared, check_label = open_log_noted(args.check_log, args.limits), \
            Path(args.check_log).name
    if args.check_intervals:
        check_ms = config.read_intervals(args.check_intervals)
        check_label = check_label or f"intervals {Path(args.check_intervals).name}"
    elif args.check_range:
        check_ms = _range_ms(check_prepared, args.check_range, "--check-range")
        check_label = check_label or "range %g:%g s" % args.check_range
    elif args.check_log:
        check_ms = None
    elif tune_ms is None and not args.no_check:     # nothing chosen: tune on one half
        half = prepared.duration_s / 2.0
        tune_ms, tune_label = _range_ms(prepared, (0.0, half)), "first half"
        check_ms, check_label = _range_ms(prepared, (half, prepared.duration_s)), "second half"
    else:
        return autotune.Target(prepared, tune_ms, args.skip, tune_label), None
    return (autotune.Target(prepared, tune_ms, args.skip, tune_label),
            autotune.Target(check_prepared, check_ms, args.skip, check_label))


def _check_computable(prepared: LogData, result: autotune.TuneResult, estimator: str,
                      sensors: tuple[str, ...]) -> None:
    """ConfigError (one line) when the best settings found give an estimate that is not finite
    somewhere in the log: `filter` would refuse them, so they are neither written nor kept."""
    rows = refilter(prepared, result.best, estimator, sensors).rows
    rows = rows.select(rows.has_sample)
    try:
        FiniteCheck(estimator, result.best).check(rows.quat, rows.t_ms)
    except config.ConfigError as error:
        ranges = ", ".join(f"{p.name}={p.low:g}:{p.high:g}" for p in result.parameters)
        raise config.ConfigError(f"tune: nothing written: {error} (searched {ranges}; narrow "
                                 "--params)") from None


def cmd_tune(args: argparse.Namespace) -> int:
    sensors = config.sensor_list(args.sensors)
    names = config.estimator_names(args.estimator)
    if len(names) != 1 or names[0] not in ("ekf", "course"):
        raise config.ConfigError("tune: give one EKF --estimator (ekf or course)")
    base = config.load_settings(args.settings) or ekf.PRESETS["default"]
    parameters = autotune.parse_parameters(args.params, base)
    if args.output:                                  # before the search, not after it
        check_output(args.output, args.log, args.check_log)
    log = open_log_noted(args.log, args.limits)
    prepared = log
    if len(prepared.ori_times) == 0:
        raise config.ConfigError(f"tune: {args.log} has no ORI lines to tune against")
    absent = warn_absent(log, sensors, names, tuple(autotune.sensors_in(prepared)))
    parameters, left_alone = autotune.split_by_sensor(
        parameters, [s for s in sensors if s not in absent])
    if left_alone:
        names_left = ", ".join(p.name for p in left_alone)
        if not parameters:
            raise config.ConfigError(f"tune: nothing to tune: the filter runs without the "
                                     f"sensor of {names_left}")
        print(f"orientation-lab: not tuning {names_left}: the filter runs without "
              f"{'its sensor' if len(left_alone) == 1 else 'their sensors'}", file=sys.stderr)
    target, check = _targets(args, prepared)
    for where, chosen in (("the tuning range", target), ("the check range", check)):
        if chosen is not None and not chosen.evaluate(base, names[0], sensors).samples:
            raise config.ConfigError(f"tune: no ORI reference sample to score in {where} "
                                     f"({chosen.label or 'whole log'}"
                                     f"{f', after --skip {args.skip:g} s' if args.skip else ''})")
    print(f"tuning {', '.join(p.name for p in parameters)} on {args.log} "
          f"({target.label or 'whole log'}), at most {args.max_evals} runs ...", flush=True)
    try:
        result = autotune.tune(target, base, parameters, check, args.max_evals, args.objective,
                             names[0], sensors)
    except ValueError as error:
        raise config.ConfigError(f"tune: {error}") from None
    print(result.format_report())
    _check_computable(prepared, result, names[0], sensors)
    payload = {"settings": result.best.to_dict(), "tuning": result.to_dict(),
               "source": str(args.log)}
    if args.output:
        _write_json(args.output, payload, args.log, getattr(args, "check_log", None))
    if args.profile:
        _keep_in_profile(args.profile, settings=result.best.to_dict(), tuning=result.to_dict())
    return 0


# ---- registration ---------------------------------------------------------------------------------

def add_commands(sub) -> None:
    c = sub.add_parser("calibrate", help="noise statistics from rest data (task 2) and settings")
    c.add_argument("log")
    options.add_output(c)
    options.add_settings(c, "base settings to complete (default preset otherwise)")
    c.add_argument("--whole", action="store_true",
                   help="use the whole log instead of the longest still interval")
    options.add_range(c, "--range", "use this stretch instead of the longest still interval")
    options.add_profile(c)
    options.add_plots(c)
    options.add_limits(c)
    c.set_defaults(func=cmd_calibrate)

    m = sub.add_parser("calibrate-mag", help="magnetometer hard- and soft-iron fit (turn the "
                                             "phone in every direction while recording)")
    m.add_argument("log")
    options.add_output(m, "the base settings with the magnetometer correction")
    options.add_settings(m, "base settings to add the correction to (default preset otherwise)")
    options.add_range(m, "--range", "use only this stretch")
    options.add_profile(m)
    options.add_plots(m)
    options.add_limits(m)
    m.set_defaults(func=cmd_calibrate_mag)

    _add_tune(sub)


def _add_tune(sub) -> None:
    t = sub.add_parser("tune", help="search settings minimising the RMSE against the log's ORI "
                                    "(tune on one range, check on another)")
    t.add_argument("log")
    options.add_output(t, "the tuned settings and what the search did")
    options.add_settings(t, "settings to start from (default preset otherwise)")
    options.add_estimator(t)
    options.add_octave(t)
    options.add_sensors(t)
    t.add_argument("--params", metavar="A,B=LO:HI,...",
                   help="settings to tune, optionally with a range (default "
                        f"{','.join(autotune.DEFAULT_PARAMETERS)})")
    options.add_intervals(t, help_text="tune on these score_intervals_ms (default: LOG's sibling "
                                       ".json; neither: the first half of the log)")
    options.add_range(t, "--range", "tune on this stretch")
    options.add_intervals(t, "--check-intervals", "check on these score_intervals_ms")
    options.add_range(t, "--check-range", "check on this stretch")
    t.add_argument("--check-log", metavar="LOG",
                   help="check on another log (its --check-intervals/--check-range, or all)")
    t.add_argument("--no-check", action="store_true",
                   help="no check range (the figures are then only those tuned on)")
    options.add_skip(t)
    t.add_argument("--max-evals", type=int, default=60, metavar="N",
                   help="at most N runs of the filter (default 60)")
    t.add_argument("--objective", choices=autotune.OBJECTIVES, default="total",
                   help="the RMSE minimised (default total)")
    options.add_profile(t)
    options.add_limits(t)
    t.set_defaults(func=cmd_tune)
