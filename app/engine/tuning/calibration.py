"""Calibration from a log or from live samples: the one path of `calibrate`, `calibrate-mag` and
the calibration workspace (Qt-free).

* :func:`rest_from_log` picks the rest stretch of a log (the longest still interval, a chosen
  time range, or all of it) and analyses it: task-2 statistics with normality, autocorrelation
  and warnings (:func:`ekf.noise.analyse_rest`) and the gyroscope's Allan deviation. The
  workspace does the same in steps: a :class:`RestSource` (a log's samples, or live ones
  collected, with where the phone was still and where it moved), then
  :func:`analyse_still` or :func:`analyse_stretch` of the stretch the user drags.
* :func:`mag_from_log` fits the magnetometer's hard and soft iron to a log's readings.
* :class:`SampleCollector` gathers the live plot chunks' samples (acc, gyr, mag with their
  times) for a duration of phone time, for the workspace's Start button.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ekf import calibration, magcal
from ekf.calibration import REPORT_ORDER
from ekf._optional import MissingLibrary
from ekf.allan import AllanResult, allan_deviation
from ekf.noise import RestAnalysis, analyse_rest, merged_axis, runs_of
from app.engine.errors import ConfigError
from app.stream.logfile import LogData

@dataclass
class RestCalibration:
    """A rest stretch analysed: the analysis (statistics, normality, autocorrelation,
    warnings), the Allan deviation (None with too few gyro samples), the interval used
    (seconds, the log's time axis; None: everything given) and how it was chosen."""

    analysis: RestAnalysis
    allan: AllanResult | None
    interval_s: tuple[float, float] | None
    how: str


def _sensor_series(log: LogData, chosen: np.ndarray | None = None) -> dict[str, np.ndarray]:
    arrays = log.to_arrays()
    t_s = arrays.t_s
    out: dict[str, np.ndarray] = {}
    for name in REPORT_ORDER:
        values = getattr(arrays, name)
        keep = np.all(np.isfinite(values), axis=1)
        if chosen is not None:
            keep &= chosen
        out["t_" + name], out[name] = t_s[keep], values[keep]
    return out


def analyse_series(series: dict[str, np.ndarray], interval_s: tuple[float, float] | None = None,
                   how: str = "") -> RestCalibration:
    """Analyse per-sensor samples (keys t_acc, acc, t_gyr, gyr, t_mag, mag; seconds and sensor
    units). ConfigError when a library is missing."""
    try:
        analysis = analyse_rest(**series)
        allan = None
        if len(series.get("t_gyr", ())) >= 10:
            try:
                allan = allan_deviation(series["t_gyr"], series["gyr"])
            except ValueError:
                allan = None        # e.g. a constant (quantised) gyro axis
    except MissingLibrary as error:
        raise ConfigError(str(error)) from None
    return RestCalibration(analysis, allan, interval_s, how)


@dataclass
class RestSource:
    """Samples to take a rest stretch from: a log, or live samples collected.

    series: per sensor its times and values (keys t_acc, acc, t_gyr, gyr, t_mag, mag; seconds on
    the source's own time axis); origin_s: its first time (a stretch is given in seconds from
    there); duration_s; still: the longest still interval (absolute times; None: no still run
    of 1 s); moving_s: the stretches in which the phone moved (seconds from the origin); name:
    what it is, for the user ("walk.txt", "live samples")."""

    series: dict[str, np.ndarray]
    origin_s: float
    duration_s: float
    still: calibration.RestSegment | None
    moving_s: list[tuple[float, float]]
    name: str = ""

    def still_s(self) -> tuple[float, float] | None:
        """The longest still interval in seconds from the origin (None: there is none)."""
        if self.still is None:
            return None
        return (self.still.start_s - self.origin_s, self.still.end_s - self.origin_s)

    def between(self, low: float, high: float) -> dict[str, np.ndarray]:
        """The series of the samples at absolute times low..high (both included)."""
        out: dict[str, np.ndarray] = {}
        for name in REPORT_ORDER:
            t = self.series["t_" + name]
            keep = (t >= low) & (t <= high)
            out["t_" + name], out[name] = t[keep], self.series[name][keep]
        return out

    def count_between(self, low: float, high: float) -> int:
        return sum(int(np.count_nonzero((self.series["t_" + name] >= low)
                                        & (self.series["t_" + name] <= high)))
                   for name in REPORT_ORDER)


def _source(t_s: np.ndarray, gyr: np.ndarray, acc: np.ndarray,
            series: dict[str, np.ndarray], name: str) -> RestSource:
    """t_s with gyr and acc in the batch layout (NaN rows where a sensor has no sample)."""
    if len(t_s) == 0 or np.isnan(acc).all():
        raise ConfigError(f"calibrate: {name or 'the samples'}: no accelerometer samples")
    origin = float(t_s[0])
    segment = calibration.find_rest_segment(t_s, gyr, acc)
    moving = ~calibration.rest_mask(t_s, gyr, acc) if len(t_s) > 1 else np.zeros(1, bool)
    runs = [(a - origin, b - origin) for a, b in runs_of(t_s, moving)]
    return RestSource(series, origin, float(t_s[-1] - t_s[0]), segment, runs, name)


def rest_source(log: LogData) -> RestSource:
    """A log as a RestSource. ConfigError when it has no accelerometer samples."""
    arrays = log.to_arrays()
    if len(arrays.t_s) == 0 or np.isnan(arrays.acc).all():
        raise ConfigError("calibrate: the log has no ACC lines")
    return _source(arrays.t_s, arrays.gyr, arrays.acc, _sensor_series(log),
                   Path(log.path).name)


def collected_source(series: dict[str, np.ndarray], name: str = "live samples") -> RestSource:
    """Collected samples (SampleCollector.series()) as a RestSource."""
    t_all, columns = merged_axis({sensor: (np.asarray(series["t_" + sensor], float),
                                           np.asarray(series[sensor], float).reshape(-1, 3))
                                  for sensor in REPORT_ORDER})
    return _source(t_all, columns["gyr"], columns["acc"], dict(series), name)


def analyse_stretch(source: RestSource, start_s: float | None = None,
                    end_s: float | None = None, how: str | None = None) -> RestCalibration:
    """The rest calibration of [start_s, end_s] seconds from the source's origin (None: from
    its start / to its end; both None: all of it). ConfigError for an empty range."""
    whole = start_s is None and end_s is None
    low = source.origin_s + (start_s or 0.0)
    high = (source.origin_s + end_s if end_s is not None
            else source.origin_s + source.duration_s)
    if not whole:
        if not high > low:
            raise ConfigError(f"calibrate: empty range {start_s}..{end_s} s")
        if source.count_between(low, high) < 2:
            raise ConfigError(f"calibrate: nothing in the range {start_s or 0:g}.."
                              f"{'end' if end_s is None else format(end_s, 'g')} s "
                              f"(the log lasts {source.duration_s:.1f} s)")
    return analyse_series(source.between(low, high), None if whole else (low, high),
                          how or ("whole log" if whole else "chosen range"))


def analyse_still(source: RestSource) -> RestCalibration:
    """The rest calibration of the source's longest still interval. ConfigError when there is
    none."""
    if source.still is None:
        raise ConfigError("calibrate: found no still interval of at least 1 s "
                          "(use --whole to take all)")
    return analyse_series(source.between(source.still.start_s, source.still.end_s),
                          (source.still.start_s, source.still.end_s), "longest still interval")


def rest_from_log(log: LogData, start_s: float | None = None, end_s: float | None = None,
                  whole: bool = False) -> RestCalibration:
    """The rest calibration of a log: [start_s, end_s] seconds from the log's start when given,
    everything with `whole`, else the longest still interval. ConfigError when there is no
    accelerometer or no still interval."""
    source = rest_source(log)
    if start_s is not None or end_s is not None:
        return analyse_stretch(source, start_s if start_s is not None else 0.0, end_s)
    if whole:
        return analyse_stretch(source)
    return analyse_still(source)


def mag_from_log(log: LogData, start_s: float | None = None,
                 end_s: float | None = None) -> tuple[magcal.MagCalibration, np.ndarray]:
    """The magnetometer fit of a log's readings (optionally [start_s, end_s] from its start):
    (result, the raw readings (N, 3)). ConfigError without enough MAG lines."""
    series = _sensor_series(log)
    t, mag = series["t_mag"], series["mag"]
    if len(t) and (start_s is not None or end_s is not None):
        t0 = log.to_arrays().t_s[0]
        keep = (t >= t0 + (start_s or 0.0)) & (t <= t0 + (end_s if end_s is not None
                                                          else np.inf))
        mag = mag[keep]
    try:
        return magcal.calibrate_magnetometer(mag), mag
    except ValueError as error:
        raise ConfigError(f"calibrate-mag: {error}") from None


@dataclass
class SampleCollector:
    """Collect live samples for `duration_s` of phone time from the first sample on.

    add(plot_chunk) takes a snapshot's PlotChunk (t_acc/acc, t_gyr/gyr, t_mag/mag); `done`
    turns true once a sample later than the duration arrives (duration_s None: never, stop by
    hand); series() gives the per-sensor arrays analyse_series reads.
    max_samples bounds the memory per sensor."""

    duration_s: float | None = 10.0
    max_samples: int = 2_000_000
    _parts: dict[str, list[tuple[np.ndarray, np.ndarray]]] = field(
        default_factory=lambda: {name: [] for name in REPORT_ORDER})
    start_s: float | None = None
    latest_s: float | None = None
    counts: dict[str, int] = field(default_factory=lambda: {name: 0 for name in REPORT_ORDER})
    past_end: bool = False

    def add(self, chunk: object) -> None:
        if self.start_s is None:
            firsts = [float(getattr(chunk, "t_" + name)[0]) for name in REPORT_ORDER
                      if len(getattr(chunk, "t_" + name))]
            if not firsts:
                return
            self.start_s = min(firsts)
        for name in REPORT_ORDER:
            t = np.asarray(getattr(chunk, "t_" + name), dtype=float)
            if len(t) == 0 or self.counts[name] >= self.max_samples:
                continue
            values = np.asarray(getattr(chunk, name), dtype=float).reshape(-1, 3)
            if self.duration_s is not None:
                keep = t <= self.start_s + self.duration_s
                self.past_end |= not keep.all()
                t, values = t[keep], values[keep]
            if len(t):
                self._parts[name].append((t, values))
                self.counts[name] += len(t)
                self.latest_s = max(self.latest_s or -np.inf, float(t[-1]))

    @property
    def elapsed_s(self) -> float:
        if self.start_s is None or self.latest_s is None:
            return 0.0
        return self.latest_s - self.start_s

    @property
    def done(self) -> bool:
        """A sample beyond the duration has arrived: the stretch is complete."""
        return self.past_end

    def series(self) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for name in REPORT_ORDER:
            parts = self._parts[name]
            out["t_" + name] = (np.concatenate([p[0] for p in parts]) if parts
                                else np.empty(0))
            out[name] = np.concatenate([p[1] for p in parts]) if parts else np.empty((0, 3))
        return out
