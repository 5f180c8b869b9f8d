"""Ordered samples -> estimator steps -> rows of estimates. One code path for live and offline.

:class:`EstimatorRunner` feeds time-ordered filter-tag samples (from
:class:`app.io.ordering.TimeOrderer`) into the main estimator and, optionally, the comparison
estimators; ORI is the phone's own estimate and never reaches a filter. It produces one row
per distinct phone time. The live engine and :func:`run_offline` both use it, sample by sample
in the same order, so a file and its live replay give bit-identical estimates.

Times: phone ms (aligned) in, seconds (t_ms / 1000) to the estimators. Quaternions w-first,
sensor -> ENU, w >= 0. Angles in degrees.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

import ekf
from app.io.protocol import Sample

SENSORS = ("gyr", "acc", "mag")
#: The 7 non-empty sensor combinations of the EKF, "gyr+acc+mag" first.
COMBINATIONS: tuple[tuple[str, ...], ...] = tuple(
    combo for size in (3, 2, 1) for combo in itertools.combinations(SENSORS, size))


def combination_name(sensors: Iterable[str]) -> str:
    """("gyr", "acc") -> "gyr+acc"."""
    return "+".join(sensors)


def angle_deg(p, q) -> float:
    """Angle between two unit quaternions (rotation from one to the other), degrees; NaN if
    either is missing. Plain floats: this runs once per row."""
    if p is None or q is None:
        return math.nan
    dot = abs(p[0] * q[0] + p[1] * q[1] + p[2] * q[2] + p[3] * q[3])
    norm = math.sqrt((p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3])
                     * (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]))
    if not norm > 0.0:
        return math.nan
    return math.degrees(2.0 * math.acos(min(1.0, dot / norm)))


def angles_deg(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Row-wise angle between quaternion stacks (N, 4), degrees; NaN where a row is NaN."""
    dot = np.abs(np.sum(p * q, axis=1))
    norm = np.sqrt(np.sum(p * p, axis=1) * np.sum(q * q, axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.degrees(2.0 * np.arccos(np.minimum(1.0, dot / norm)))


@dataclass
class Rows:
    """Per distinct phone time (rows in time order).

    t_ms (N,) int64; quat (N, 4) the main estimate after every sample at that time; phone_quat
    (N, 4) the latest ORI at or before that time (NaN before the first); angle_deg (N,) OWN vs
    PHONE; acc_rejected, mag_rejected, at_rest (N,) bool: the main estimator's lights.
    """

    t_ms: np.ndarray
    quat: np.ndarray
    phone_quat: np.ndarray
    angle_deg: np.ndarray
    acc_rejected: np.ndarray
    mag_rejected: np.ndarray
    at_rest: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ms)

    @property
    def t_s(self) -> np.ndarray:
        return self.t_ms.astype(np.float64) / 1000.0

    @staticmethod
    def empty() -> Rows:
        return Rows(np.empty(0, np.int64), np.empty((0, 4)), np.empty((0, 4)), np.empty(0),
                    np.empty(0, bool), np.empty(0, bool), np.empty(0, bool))


@dataclass
class ComparisonState:
    """One comparison estimator and its running error against the phone."""

    name: str
    sensors: tuple[str, ...]
    estimator: object
    angle_to_phone_deg: float = math.nan
    squared_sum: float = 0.0
    count: int = 0

    @property
    def rmse_deg(self) -> float:
        return math.sqrt(self.squared_sum / self.count) if self.count else math.nan


_FILTER_TAGS = frozenset(("GYR", "ACC", "MAG", "ORI"))
_NAN4 = (math.nan, math.nan, math.nan, math.nan)


class EstimatorRunner:
    """Feed ordered Samples; read the latest estimates; take the rows produced so far.

    estimator: a name from ekf.ESTIMATORS; settings: ekf.EKFSettings or None (default preset);
    sensors: the sensors enabled in the main estimator; comparisons: also run the 7 EKF sensor
    combinations. collect_plot: keep the raw ACC/GYR/MAG samples with their rejected flags for
    plotting (:meth:`take_plot_samples`).

    Samples must come in time order (at equal times GYR, ACC, MAG, as TimeOrderer releases them).
    """

    def __init__(self, estimator: str = "ekf", settings: ekf.EKFSettings | None = None,
                 sensors: Iterable[str] = SENSORS, comparisons: bool = False,
                 collect_plot: bool = False, max_rows: int | None = None) -> None:
        self.estimator_name = estimator
        self.settings = settings if settings is not None else ekf.PRESETS["default"]
        self._sensors = tuple(s for s in SENSORS if s in tuple(sensors))
        self.main = ekf.make_estimator(estimator, self.settings, self._sensors)
        self.collect_plot = collect_plot
        self.max_rows = max_rows       # bound on rows kept between take_rows() calls (live)
        self.comparisons: list[ComparisonState] = []
        if comparisons:
            self.set_comparisons_enabled(True)
        self.phone_quat: tuple[float, float, float, float] | None = None
        self.latest_t_ms: int | None = None
        self.samples_fed = 0
        self.dropped_rows = 0
        self._row_t: int | None = None
        self._reset_rows()
        self._reset_plot()

    # -- commands -----------------------------------------------------------------------------

    @property
    def sensors_enabled(self) -> dict[str, bool]:
        return dict(self.main.enabled)

    def set_sensor_enabled(self, sensor: str, enabled: bool) -> None:
        if sensor not in SENSORS:
            raise ValueError(f"unknown sensor {sensor!r}")
        self.main.set_enabled(**{sensor: bool(enabled)})

    def set_estimator(self, name: str) -> None:
        """Switch the main estimator (it starts afresh, with the current sensor switches)."""
        enabled = self.main.enabled
        self.main = ekf.make_estimator(name, self.settings,
                                       tuple(s for s in SENSORS if enabled[s]) or SENSORS)
        self.main.set_enabled(**enabled)
        self.estimator_name = name

    def set_settings(self, settings: ekf.EKFSettings) -> None:
        """New settings from the next sample on, for the main and comparison estimators."""
        self.settings = settings
        for estimator in [self.main] + [c.estimator for c in self.comparisons]:
            if hasattr(estimator, "set_settings"):
                estimator.set_settings(settings)
            else:
                estimator.settings = settings

    def reset(self) -> None:
        """Forget the orientation of every estimator; they re-initialise from the next samples."""
        self.main.reset()
        for comparison in self.comparisons:
            comparison.estimator.reset()
            comparison.squared_sum, comparison.count = 0.0, 0
            comparison.angle_to_phone_deg = math.nan

    def align_heading(self) -> bool:
        """Turn OWN's world about up so its heading matches PHONE's. False without ORI yet."""
        if self.phone_quat is None:
            return False
        self.main.align_heading(np.array(self.phone_quat))
        return True

    def set_comparisons_enabled(self, enabled: bool) -> None:
        if not enabled:
            self.comparisons = []
        elif not self.comparisons:
            self.comparisons = [
                ComparisonState(combination_name(combo), combo,
                                ekf.make_estimator("ekf", self.settings, combo))
                for combo in COMBINATIONS]

    # -- samples ------------------------------------------------------------------------------

    def feed(self, sample: Sample) -> None:
        """One sample (non-filter tags are ignored)."""
        tag = sample.tag
        if tag not in _FILTER_TAGS:
            return
        t_ms = sample.t_ms
        if self._row_t is not None and t_ms != self._row_t:
            self._commit_row()
        if tag == "ORI":
            self.phone_quat = sample.values
        elif tag == "GYR" or tag == "ACC" or tag == "MAG":
            t_s = t_ms / 1000.0
            main = self.main
            if tag == "GYR":
                status = main.update_gyr(t_s, sample.values)
                for comparison in self.comparisons:
                    comparison.estimator.update_gyr(t_s, sample.values)
                if self.collect_plot:
                    self._plot_gyr_t.append(t_ms)
                    self._plot_gyr.append(sample.values)
            elif tag == "ACC":
                status = main.update_acc(t_s, sample.values)
                for comparison in self.comparisons:
                    comparison.estimator.update_acc(t_s, sample.values)
                if self.collect_plot:
                    self._plot_acc_t.append(t_ms)
                    self._plot_acc.append(sample.values)
                    self._plot_acc_rejected.append(bool(status.acc_rejected))
            else:
                status = main.update_mag(t_s, sample.values)
                for comparison in self.comparisons:
                    comparison.estimator.update_mag(t_s, sample.values)
                if self.collect_plot:
                    self._plot_mag_t.append(t_ms)
                    self._plot_mag.append(sample.values)
                    self._plot_mag_rejected.append(bool(status.mag_rejected))
        self.samples_fed += 1
        self.latest_t_ms = t_ms
        self._row_t = t_ms

    def feed_many(self, samples: Iterable[Sample]) -> None:
        for sample in samples:
            self.feed(sample)

    def finish(self) -> None:
        """End of stream: commit the row of the last time."""
        if self._row_t is not None:
            self._commit_row()
            self._row_t = None

    @property
    def status(self):
        """The main estimator's ekf.Status (live object; copy what you keep)."""
        return self.main.status

    @property
    def own_quat(self) -> np.ndarray:
        return self.main.quat

    @property
    def angle_deg(self) -> float:
        return angle_deg(self.main.quat, self.phone_quat)

    # -- rows ---------------------------------------------------------------------------------

    def _reset_rows(self) -> None:
        self._rows_t: list[int] = []
        self._rows_q: list[np.ndarray] = []
        self._rows_phone: list[tuple[float, ...]] = []
        self._rows_flags: list[tuple[bool, bool, bool]] = []

    def _commit_row(self) -> None:
        q = self.main.quat
        phone = self.phone_quat
        status = self.main.status
        self._rows_t.append(self._row_t)
        self._rows_q.append(q)
        self._rows_phone.append(phone if phone is not None else _NAN4)
        self._rows_flags.append((status.acc_rejected, status.mag_rejected, status.at_rest))
        if phone is not None:
            for comparison in self.comparisons:
                error = angle_deg(comparison.estimator.quat, phone)
                comparison.angle_to_phone_deg = error
                if error == error:
                    comparison.squared_sum += error * error
                    comparison.count += 1
        if self.max_rows is not None and len(self._rows_t) > self.max_rows:
            # Nobody took the rows for a long time (GUI stalled): keep the newest.
            drop = len(self._rows_t) - self.max_rows
            for rows in (self._rows_t, self._rows_q, self._rows_phone, self._rows_flags):
                del rows[:drop]
            self.dropped_rows += drop

    def take_rows(self) -> Rows:
        """The rows committed since the previous call (the row of the latest time is committed
        when a later time arrives or at finish())."""
        if not self._rows_t:
            return Rows.empty()
        flags = np.array(self._rows_flags, dtype=bool).reshape(-1, 3)
        quat = np.array(self._rows_q, dtype=np.float64).reshape(-1, 4)
        phone = np.array(self._rows_phone, dtype=np.float64).reshape(-1, 4)
        rows = Rows(np.array(self._rows_t, dtype=np.int64), quat, phone,
                    angles_deg(quat, phone),
                    flags[:, 0].copy(), flags[:, 1].copy(), flags[:, 2].copy())
        self._reset_rows()
        return rows

    # -- plot samples ---------------------------------------------------------------------------

    def _reset_plot(self) -> None:
        self._plot_acc_t: list[int] = []
        self._plot_acc: list[tuple[float, ...]] = []
        self._plot_acc_rejected: list[bool] = []
        self._plot_gyr_t: list[int] = []
        self._plot_gyr: list[tuple[float, ...]] = []
        self._plot_mag_t: list[int] = []
        self._plot_mag: list[tuple[float, ...]] = []
        self._plot_mag_rejected: list[bool] = []

    def take_plot_samples(self) -> dict[str, np.ndarray]:
        """Raw sensor samples fed since the previous call: t_acc/t_gyr/t_mag (ms, int64),
        acc/gyr/mag (n, 3), acc_rejected/mag_rejected (n,) bool."""
        out = {
            "t_acc": np.array(self._plot_acc_t, dtype=np.int64),
            "acc": np.array(self._plot_acc, dtype=np.float64).reshape(-1, 3),
            "acc_rejected": np.array(self._plot_acc_rejected, dtype=bool),
            "t_gyr": np.array(self._plot_gyr_t, dtype=np.int64),
            "gyr": np.array(self._plot_gyr, dtype=np.float64).reshape(-1, 3),
            "t_mag": np.array(self._plot_mag_t, dtype=np.int64),
            "mag": np.array(self._plot_mag, dtype=np.float64).reshape(-1, 3),
            "mag_rejected": np.array(self._plot_mag_rejected, dtype=bool),
        }
        self._reset_plot()
        return out


def run_offline(samples: Iterable[Sample], estimator_name: str = "ekf",
                settings: ekf.EKFSettings | None = None,
                sensors: Iterable[str] = SENSORS) -> Rows:
    """Run one estimator over ordered samples (e.g. ``read_log(path).samples``): one row per
    distinct phone time. Bit-identical to the live engine on the same samples."""
    runner = EstimatorRunner(estimator_name, settings, sensors)
    runner.feed_many(samples)
    runner.finish()
    return runner.take_rows()
