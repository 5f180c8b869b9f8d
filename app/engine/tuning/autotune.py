"""Auto-tune: search the filter settings that minimise the RMSE against a reference (the log's
ORI: the phone's own estimate, or ground truth where the log carries it) over a chosen range,
and check the result on another range or log ("tune on this range, check on that range").

Each candidate is one re-run of the log (:func:`app.engine.offline.refilter.refilter`, the compiled
batch path) up to the end of the range; the search is ``scipy.optimize.minimize``'s
Nelder-Mead with bounds, on the parameters' ranges mapped to [0, 1] (logarithmically for
positive quantities such as covariances), started from the base settings. A covariance matrix is
tuned as a scale: the parameter is the mean of its diagonal, and the whole matrix is scaled.

:class:`TuningJob` runs a search in a thread (the kernels release the GIL, so a window stays
responsive) with a progress callback and Cancel; a cancelled search returns the best found so
far. Qt-free.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

import ekf
from ekf._optional import MissingLibrary, require
from ekf.metrics import ErrorSummary
from ekf.settings import search_ranges
from app.engine.processing.configuration import Setup
from app.engine.errors import ConfigError
from app.engine.offline.refilter import refilter
from app.stream.logfile import LogData
from app.engine.processing.runner import SENSORS

# (low, high) searched for a setting, log scale, from its declaration (ekf.settings'
# `search`); values outside them are never tried.
RANGES: dict[str, tuple[float, float]] = {
    name: (r.low, r.high) for name, r in search_ranges().items()}
DEFAULT_PARAMETERS = ("gyr_noise_cov", "acc_noise_cov", "mag_noise_cov", "acc_lowpass_s")
OBJECTIVES = ("total", "heading", "inclination")
# The sensor a setting belongs to, by its name: on a log without that sensor the setting has no
# effect, and a search leaves it alone (no_gyro_random_walk is the one for a log without a
# gyroscope, and belongs to none).
SETTING_SENSORS = (("gyr", ("gyr_", "gyro_", "rest_rate_")), ("acc", ("acc_",)),
                   ("mag", ("mag_",)))


def setting_sensor(name: str) -> str | None:
    """"gyr", "acc" or "mag" for a setting of that sensor (gyr_noise_cov: "gyr"), else None."""
    for sensor, prefixes in SETTING_SENSORS:
        if name.startswith(prefixes):
            return sensor
    return None


def sensors_in(log: LogData) -> frozenset[str]:
    """The filter sensors the log holds samples of."""
    codes = np.unique(log.tag)
    return frozenset(name for code, name in enumerate(SENSORS) if code in codes)


def split_by_sensor(parameters: Sequence["Parameter"], present: Iterable[str]
                    ) -> tuple[list["Parameter"], list["Parameter"]]:
    """(the parameters to search, those of a sensor not in `present`: left alone)."""
    present = set(present)
    kept, dropped = [], []
    for parameter in parameters:
        sensor = setting_sensor(parameter.name)
        (dropped if sensor is not None and sensor not in present else kept).append(parameter)
    return kept, dropped


@dataclass(frozen=True)
class Parameter:
    """A setting searched between low and high (log scale when both are positive)."""

    name: str
    low: float
    high: float

    @property
    def log(self) -> bool:
        return self.low > 0

    def value(self, settings: ekf.EKFSettings) -> float:
        v = getattr(settings, self.name)
        return float(np.mean(np.diag(np.asarray(v, float)))) if _is_matrix(v) else float(v)

    def apply(self, settings: ekf.EKFSettings, value: float) -> ekf.EKFSettings:
        current = getattr(settings, self.name)
        if _is_matrix(current):
            matrix = np.asarray(current, float)
            scale = float(np.mean(np.diag(matrix)))
            new = (matrix * (value / scale)).tolist() if scale > 0 else _diag(value)
            return settings.with_changes(**{self.name: new})
        return settings.with_changes(**{self.name: float(value)})

    def to_unit(self, value: float) -> float:
        value = min(max(value, self.low), self.high)
        if self.log:
            return math.log(value / self.low) / math.log(self.high / self.low)
        return (value - self.low) / (self.high - self.low)

    def from_unit(self, u: float) -> float:
        u = min(max(float(u), 0.0), 1.0)
        if self.log:
            return self.low * (self.high / self.low) ** u
        return self.low + u * (self.high - self.low)


def _is_matrix(value: Any) -> bool:
    return isinstance(value, (list, tuple)) and bool(value) and isinstance(value[0], (list,
                                                                                     tuple))


def _diag(value: float) -> list[list[float]]:
    return (np.eye(3) * value).tolist()


def parse_parameters(text: str | Sequence[str] | None,
                     base: ekf.EKFSettings) -> list[Parameter]:
    """"a,b=lo:hi,c" -> Parameters (the declared search ranges, RANGES, else a decade either
    side of the base value). ConfigError for unknown, non-numeric or unbounded settings."""
    items = (list(DEFAULT_PARAMETERS) if not text else
             [p.strip() for p in text.split(",") if p.strip()] if isinstance(text, str)
             else list(text))
    known = {f.name: f for f in fields(ekf.EKFSettings)}
    out = []
    for item in items:
        name, _, bounds = item.partition("=")
        name = name.strip()
        if name not in known:
            raise ConfigError(f"--params: unknown setting {name!r}")
        value = getattr(base, name)
        if isinstance(value, (bool, str)) or value is None or (
                isinstance(value, (list, tuple)) and not _is_matrix(value)):
            raise ConfigError(f"--params: {name} is not a number or a covariance")
        if name == "acc_lowpass_s" and not bounds and float(value) == 0 and not text:
            continue         # the plain course model has no low-pass to tune
        out.append(Parameter(name, *_bounds(name, bounds, base)))
    if not out:
        raise ConfigError("--params: nothing to tune")
    return out


def _bounds(name: str, text: str, base: ekf.EKFSettings) -> tuple[float, float]:
    if text:
        try:
            low, high = (float(x) for x in text.split(":"))
        except ValueError:
            raise ConfigError(f"--params: {name}={text}: expected LOW:HIGH") from None
    elif name in RANGES:
        low, high = RANGES[name]
    else:
        value = Parameter(name, 1.0, 1.0).value(base)
        if not (value > 0 and math.isfinite(value)):
            raise ConfigError(f"--params: give a range for {name} (e.g. {name}=0.1:10)")
        low, high = value / 10.0, value * 10.0
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise ConfigError(f"--params: {name}: bad range {low:g}:{high:g}")
    for end in (low, high):        # both ends are values the setting's declaration allows
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                Parameter(name, low, high).apply(base, end)
        except ValueError as error:
            raise ConfigError(f"--params {name}={low:g}:{high:g}: {end:g} is not allowed "
                              f"({error})") from None
    return low, high


@dataclass
class Target:
    """Where a search is scored: a prepared log, its score intervals (None: all of it), the
    convergence time ignored at its start, a label for reports and, from the window, the
    configuration over time the log is replayed with (setup; a candidate overrides its
    settings, as a settings edit does; None: the estimator and sensors given to evaluate)."""

    log: LogData
    intervals_ms: list | None = None
    skip_s: float = 0.0
    label: str = ""
    setup: Setup | None = None

    @property
    def end_ms(self) -> float | None:
        return max(end for _, end in self.intervals_ms) if self.intervals_ms else None

    def evaluate(self, settings: ekf.EKFSettings, estimator: str = "ekf",
                 sensors: Iterable[str] = SENSORS) -> ErrorSummary:
        setup = None if self.setup is None else self.setup.overridden("settings", settings)
        result = refilter(self.log.until(self.end_ms), settings, estimator, sensors,
                          self.intervals_ms, self.skip_s, setup=setup)
        if result.errors is None:
            raise ConfigError(f"{self.label or 'the log'}: no ORI reference to tune against")
        return result.summary


@dataclass
class TuneResult:
    """What a search did: base and best settings, the parameters (with their values before and
    after), before/after figures on the tuning range and on the check range (None without
    one), evaluations, wall time, whether it was cancelled, an over-fitting warning (None: the
    check agrees) and the history of the best objective per evaluation."""

    base: ekf.EKFSettings
    best: ekf.EKFSettings
    parameters: list[Parameter]
    tune_before: ErrorSummary
    tune_after: ErrorSummary
    check_before: ErrorSummary | None
    check_after: ErrorSummary | None
    evaluations: int
    elapsed_s: float
    cancelled: bool
    objective: str = "total"
    overfit_warning: str | None = None
    history: list[float] = field(default_factory=list)
    tune_label: str = ""
    check_label: str = ""

    def parameter_rows(self) -> list[tuple[str, float, float, float, float]]:
        """(name, low, high, before, after) per parameter."""
        return [(p.name, p.low, p.high, p.value(self.base), p.value(self.best))
                for p in self.parameters]

    def format_report(self) -> str:
        lines = [f"{'parameter':<24}{'range':>22}{'before':>12}{'after':>12}"]
        for name, low, high, before, after in self.parameter_rows():
            lines.append(f"{name:<24}{f'{low:.3g} .. {high:.3g}':>22}{before:>12.4g}"
                         f"{after:>12.4g}")
        lines.append("")
        rows = _figure_rows(self)
        width = max([30] + [len(label) + 2 for label, _ in rows])
        lines.append(f"{'RMSE vs ORI (deg)':<{width}}{'total':>9}{'heading':>9}{'inclin.':>9}")
        for label, s in rows:
            lines.append(f"{label:<{width}}{s.total_rmse_deg:>9.3f}{s.heading_rmse_deg:>9.3f}"
                         f"{s.inclination_rmse_deg:>9.3f}")
        state = " (cancelled: best so far)" if self.cancelled else ""
        lines.append(f"{self.evaluations} evaluations in {self.elapsed_s:.1f} s{state}")
        if self.overfit_warning:
            lines.append(f"warning: {self.overfit_warning}")
        lines += [f"warning: {text}" for text in self.bound_warnings()]
        return "\n".join(lines)

    def bound_warnings(self) -> list[str]:
        """A parameter whose best value lies on its search range's edge (within 1 % of the
        range, on a log scale where the range spans more than a decade): the best may be
        beyond it."""
        out = []
        for name, low, high, _, after in self.parameter_rows():
            if not (math.isfinite(after) and high > low):
                continue
            if low > 0 and high / low > 10:
                where = (math.log(after / low) / math.log(high / low)) if after > 0 else 0.0
            else:
                where = (after - low) / (high - low)
            if where <= 0.01 or where >= 0.99:
                edge = low if where <= 0.01 else high
                out.append(f"{name} ended at its search bound {edge:.3g}: the best may lie "
                           f"beyond it (widen it with --params {name}=LO:HI)")
        return out

    def to_dict(self) -> dict[str, Any]:
        def summary(s: ErrorSummary | None) -> dict[str, float] | None:
            return None if s is None else {
                "total_rmse_deg": s.total_rmse_deg, "heading_rmse_deg": s.heading_rmse_deg,
                "inclination_rmse_deg": s.inclination_rmse_deg, "samples": s.samples}
        return {"parameters": [dict(zip(("name", "low", "high", "before", "after"), row))
                               for row in self.parameter_rows()],
                "objective": self.objective, "tune_range": self.tune_label,
                "check_range": self.check_label,
                "tune_before": summary(self.tune_before), "tune_after": summary(self.tune_after),
                "check_before": summary(self.check_before),
                "check_after": summary(self.check_after),
                "evaluations": self.evaluations, "elapsed_s": self.elapsed_s,
                "cancelled": self.cancelled, "overfit_warning": self.overfit_warning}


def _figure_rows(result: TuneResult) -> list[tuple[str, ErrorSummary]]:
    rows = [(f"tune  {result.tune_label} before", result.tune_before),
            (f"tune  {result.tune_label} after", result.tune_after)]
    if result.check_before is not None:
        rows += [(f"check {result.check_label} before", result.check_before),
                 (f"check {result.check_label} after", result.check_after)]
    return rows


def _objective_value(summary: ErrorSummary, objective: str) -> float:
    value = getattr(summary, f"{objective}_rmse_deg")
    return float(value) if math.isfinite(value) else 1e6


def overfit_warning(tune_before: ErrorSummary, tune_after: ErrorSummary,
                    check_before: ErrorSummary | None, check_after: ErrorSummary | None,
                    objective: str = "total") -> str | None:
    """A one-line warning when the improvement does not carry over to the check range."""
    if check_before is None or check_after is None:
        return ("no check range: the figures are those of the range tuned on; check the "
                "settings on another range or log before trusting them")
    tb, ta = (_objective_value(s, objective) for s in (tune_before, tune_after))
    cb, ca = (_objective_value(s, objective) for s in (check_before, check_after))
    if ca > cb * 1.02:
        return (f"over-fitted: better where tuned ({tb:.2f} -> {ta:.2f} deg) but worse on the "
                f"check range ({cb:.2f} -> {ca:.2f} deg); keep the old settings")
    gain_tune = (tb - ta) / tb if tb > 0 else 0.0
    gain_check = (cb - ca) / cb if cb > 0 else 0.0
    if gain_tune > 0.05 and gain_check < 0.5 * gain_tune:
        return (f"the check range improves much less ({100 * gain_check:.0f} %) than the range "
                f"tuned on ({100 * gain_tune:.0f} %): partly over-fitted")
    return None


class _Cancelled(Exception):
    pass


@dataclass
class Progress:
    """evaluations done of at most max_evaluations; best objective so far [deg]; the latest
    candidate's values by parameter name."""

    evaluations: int
    max_evaluations: int
    best_deg: float
    latest: dict[str, float]

    @property
    def fraction(self) -> float:
        return min(1.0, self.evaluations / max(self.max_evaluations, 1))


class _Search:
    """The objective of one search, keeping the best candidate and reporting progress."""

    def __init__(self, target: Target, base: ekf.EKFSettings, parameters: list[Parameter],
                 estimator: str, sensors: tuple[str, ...], objective: str, max_evals: int,
                 progress: Callable[[Progress], Any] | None,
                 cancelled: Callable[[], bool] | None) -> None:
        self.target, self.base, self.parameters = target, base, parameters
        self.estimator, self.sensors, self.objective = estimator, sensors, objective
        self.max_evals, self.progress, self.cancelled = max_evals, progress, cancelled
        self.evaluations = 0
        self.best_value = math.inf
        self.best_settings = base
        self.best_summary: ErrorSummary | None = None
        self.history: list[float] = []

    def settings_at(self, u: np.ndarray) -> ekf.EKFSettings:
        settings = self.base
        for p, x in zip(self.parameters, u):
            settings = p.apply(settings, p.from_unit(x))
        return settings

    def __call__(self, u: np.ndarray) -> float:
        if self.cancelled is not None and self.cancelled():
            raise _Cancelled
        if self.evaluations >= self.max_evals:
            raise _Cancelled       # the budget: scipy's maxfev may overshoot by a few
        settings = self.settings_at(u)
        summary = self.target.evaluate(settings, self.estimator, self.sensors)
        value = _objective_value(summary, self.objective)
        self.evaluations += 1
        if value < self.best_value:
            self.best_value, self.best_settings, self.best_summary = value, settings, summary
        self.history.append(self.best_value)
        if self.progress is not None:
            self.progress(Progress(self.evaluations, self.max_evals, self.best_value,
                                   {p.name: p.from_unit(x) for p, x in zip(self.parameters, u)}))
        return value


def tune(target: Target, base: ekf.EKFSettings | None = None,
         parameters: Sequence[Parameter] | str | None = None, check: Target | None = None,
         max_evals: int = 60, objective: str = "total", estimator: str = "ekf",
         sensors: Iterable[str] = SENSORS, progress: Callable[[Progress], Any] | None = None,
         cancelled: Callable[[], bool] | None = None) -> TuneResult:
    """Search `parameters` (Parameters, or parse_parameters' text; None: DEFAULT_PARAMETERS)
    from `base` (None: the default preset) minimising the `objective` RMSE ("total",
    "heading", "inclination") on `target`, at most `max_evals` re-runs; then score base and
    best on `check`. `cancelled()` true stops the search (best so far kept)."""
    optimize = require("scipy.optimize", "the auto-tune")
    base = base if base is not None else ekf.PRESETS["default"]
    if objective not in OBJECTIVES:
        raise ConfigError(f"objective must be one of {', '.join(OBJECTIVES)}")
    params = (parse_parameters(parameters, base) if parameters is None or
              isinstance(parameters, str) else list(parameters))
    started = time.perf_counter()
    search = _Search(target, base, params, estimator, tuple(sensors), objective,
                     max(int(max_evals), 1), progress, cancelled)
    x0 = np.array([p.to_unit(p.value(base)) for p in params])
    stopped = False
    try:
        search(x0)                                  # the base itself is the first candidate
        simplex = np.vstack([x0] + [np.clip(x0 + step, 0, 1) for step in
                                    _simplex_steps(x0)])
        optimize.minimize(search, x0, method="Nelder-Mead", bounds=[(0.0, 1.0)] * len(params),
                          options={"maxfev": search.max_evals, "initial_simplex": simplex,
                                   "xatol": 1e-3, "fatol": 1e-3})
    except _Cancelled:
        stopped = search.evaluations < search.max_evals
    tune_before = target.evaluate(base, estimator, sensors)
    tune_after = search.best_summary or tune_before
    check_before = check_after = None
    if check is not None:
        check_before = check.evaluate(base, estimator, sensors)
        check_after = check.evaluate(search.best_settings, estimator, sensors)
    return TuneResult(base, search.best_settings, params, tune_before, tune_after, check_before,
                      check_after, search.evaluations, time.perf_counter() - started, stopped,
                      objective, overfit_warning(tune_before, tune_after, check_before,
                                                 check_after, objective),
                      search.history, target.label, check.label if check else "")


def _simplex_steps(x0: np.ndarray) -> list[np.ndarray]:
    """One step of 0.2 (a fifth of the range) along each axis, inwards near a bound."""
    steps = []
    for k in range(len(x0)):
        step = np.zeros(len(x0))
        step[k] = 0.2 if x0[k] <= 0.8 else -0.2
        steps.append(step)
    return steps


class TuningJob:
    """A search in a background thread. on_progress(Progress) and on_done(TuneResult | None,
    error | None) are called from that thread. :meth:`cancel` stops it at the next
    evaluation (the best so far is the result)."""

    def __init__(self, target: Target, base: ekf.EKFSettings | None = None,
                 parameters: Sequence[Parameter] | str | None = None,
                 check: Target | None = None, max_evals: int = 60, objective: str = "total",
                 estimator: str = "ekf", sensors: Iterable[str] = SENSORS,
                 on_progress: Callable[[Progress], Any] | None = None,
                 on_done: Callable[[TuneResult | None, BaseException | None], Any] | None
                 = None) -> None:
        self._kwargs = dict(target=target, base=base, parameters=parameters, check=check,
                            max_evals=max_evals, objective=objective, estimator=estimator,
                            sensors=tuple(sensors))
        self.on_progress, self.on_done = on_progress, on_done
        self._cancel = threading.Event()
        self.result: TuneResult | None = None
        self.error: BaseException | None = None
        self.latest: Progress | None = None
        self._thread = threading.Thread(target=self._run, name="tuning", daemon=True)

    def start(self) -> "TuningJob":
        self._thread.start()
        return self

    def cancel(self) -> None:
        self._cancel.set()

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    def wait(self, timeout: float | None = None) -> bool:
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def _progress(self, progress: Progress) -> None:
        self.latest = progress
        if self.on_progress is not None:
            self.on_progress(progress)

    def _run(self) -> None:
        try:
            self.result = tune(**self._kwargs, progress=self._progress,
                               cancelled=self._cancel.is_set)
        except (Exception, MissingLibrary) as error:   # reported to the caller, never lost
            self.error = error
        if self.on_done is not None:
            self.on_done(self.result, self.error)
