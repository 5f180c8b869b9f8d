"""Ordered samples -> estimator steps -> rows of estimates. One code path for live and offline.

:class:`EstimatorRunner` feeds time-ordered filter-tag samples (from
:class:`app.stream.ordering.TimeOrderer`) into the main estimator and, optionally, the
comparison estimators; ORI is the phone's own estimate and never reaches a filter. It produces
one row per distinct phone time. The live engine and
:func:`~app.engine.offline.filtering.run_offline` both use it on the same ordered samples (chunk
by chunk: each estimator runs over a chunk in one compiled call) and the result does not depend
on the chunking, so a file and its live replay give bit-identical estimates.

A row is what one estimator step is fed: the sensor samples of one phone time in code order
(gyr, acc, mag; :mod:`app.stream.protocol`). :class:`ChunkLayout` cuts a chunk of ordered samples
into rows and distinct-time groups, :func:`run_rows` / :func:`step_rows` run an estimator over
the rows and :class:`Rows` holds the estimates per distinct time that the runner gives.

Times: phone ms (aligned) in, seconds (t_ms / 1000) to the estimators. Quaternions w-first,
sensor -> ENU, w >= 0. Angles in degrees.
"""
from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

import ekf
from ekf import SENSORS, magcal
from ekf.fast.jit import check_cache
from app.engine.processing.compare import ErrorRows, ErrorSums, SameInstant
from app.engine.processing.innovations import YOURS, InnovationBuffer, InnovationProbe
from app.engine.userfilter.filter import estimator_for
from app.engine.userfilter.lane import UserLane
from app.stream.ordering import Last, repeats
from app.stream.protocol import FILTER_TAGS, REFERENCE_CODE, SENSOR_CODES, TABLE_KEY, WIDTHS, jit


@dataclass
class ComparisonState:
    """One comparison estimator (a sensor combination) and its running error against the
    phone's own estimate, compared at the phone's time stamps (the runner compares the 7 in
    one call: they share their times)."""

    name: str
    sensors: tuple[str, ...]
    estimator: ekf.Estimator
    errors: ErrorSums = field(default_factory=ErrorSums)


_NAN4 = (math.nan, math.nan, math.nan, math.nan)


def _restored(current: ekf.Estimator, snapshot: dict, name: str, settings: ekf.EKFSettings,
              sensors: tuple[str, ...] = SENSORS) -> ekf.Estimator:
    """`current` restored from `snapshot`, or a new estimator of `name` when `current` cannot
    take it (another kind)."""
    try:
        current.restore(snapshot)
        return current
    except ValueError:
        estimator = ekf.make_estimator(name, settings, sensors)
        estimator.restore(snapshot)
        return estimator


class EstimatorRunner:
    """Feed ordered samples; read the latest estimates; take the rows produced so far.

    estimator: a name from ekf.ESTIMATORS, a user's filter file (FILE.py) or an estimator
    object (``ekf.Estimator``); settings: ekf.EKFSettings or None (default preset);
    sensors: the sensors enabled in the main estimator; comparisons: also run the 7 sensor
    combinations of `comparison_estimator` (default the EKF with the same settings).
    collect_plot: keep the raw ACC/GYR/MAG samples with their rejected flags for plotting
    (:meth:`take_plot_samples`).

    Samples must come in time order (at equal times GYR, ACC, MAG, as TimeOrderer releases
    them). :meth:`feed_arrays` takes a chunk as arrays and runs each estimator over it in one
    compiled call. The result does not depend on the chunking: it is what feeding the samples one by
    one with update_gyr/acc/mag gives, bit for bit, with one row per distinct time committed when a
    later time arrives (or at :meth:`finish`) from the estimators' state at that moment.

    Against the phone's own estimate (ORI) every estimator is compared at the phone's time
    stamps (app.engine.processing.compare): the main one's errors per ORI sample come out of
    :meth:`take_errors`, the comparisons keep running RMSEs.

    Beside the main estimator: your filter (:meth:`set_user_lane`, YOURS: every row and every
    ORI sample is handed to its lane, which runs it in your filter's own process and never
    waits for it; its rows, as they come back, from :meth:`take_user_rows`, its errors against
    PHONE, at PHONE's times, from :meth:`take_user_errors` and in the lane's running RMSEs)
    and, on request, our EKF's innovations (:meth:`set_consistency_enabled`); both go to
    :meth:`take_innovations`.
    """

    def __init__(self, estimator: str | ekf.Estimator = "ekf",
                 settings: ekf.EKFSettings | None = None,
                 sensors: Iterable[str] = SENSORS, comparisons: bool = False,
                 collect_plot: bool = False, comparison_estimator: str = "ekf",
                 collect_cov: bool = False) -> None:
        self.settings = settings if settings is not None else ekf.PRESETS["default"]
        self._mag_correction = magcal.settings_correction(self.settings)
        self._sensors = tuple(s for s in SENSORS if s in tuple(sensors))
        self.main: ekf.Estimator = estimator_for(estimator, self.settings, self._sensors)
        self.estimator_name = estimator if isinstance(estimator, str) else self.main.name
        self.user: UserLane | None = None
        self.innovations = InnovationBuffer()
        self.probe: InnovationProbe | None = None
        self.samples_fed = 0                      # filter-tag samples fed so far
        self.repeated = 0                         # of them, exact repeats used once
        self._last_sample: Last = None
        # samples of each tag (GYR, ACC, MAG, ORI) in this session: which sensors the stream
        # delivers (see :attr:`session_samples`)
        self._tag_counts = np.zeros(len(TAG_NAMES), np.int64)
        self.collect_plot = collect_plot
        self.collect_cov = collect_cov
        self.comparison_estimator = comparison_estimator
        self.comparisons: list[ComparisonState] = []
        self._comparisons_same_instant = SameInstant()   # the 7 comparisons, as one
        if comparisons:
            self.set_comparisons_enabled(True)
        self.phone_quat: tuple[float, float, float, float] | None = None
        self.latest_t_ms: int | None = None
        self._row_t: int | None = None           # the latest time: its row is still open
        self._row_has_sample = False             # ... and whether it has a sensor sample
        self._main_same_instant = SameInstant()
        self._errors: list[ErrorRows] = []
        self._phone_samples: list[tuple[np.ndarray, np.ndarray]] = []   # (t_ms, quat) ORI
        self._reset_rows()
        self._reset_plot()

    # -- commands -----------------------------------------------------------------------------

    @property
    def session_samples(self) -> dict[str, int]:
        """Samples of each tag fed in this session (since the last new_session), by name:
        {"gyr": 0, "acc": 1200, "mag": 600, "ori": 1200} for a stream without a gyroscope."""
        return dict(zip(TAG_NAMES, (int(n) for n in self._tag_counts)))

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
        self.main = estimator_for(name, self.settings,
                                   tuple(s for s in SENSORS if enabled[s]) or SENSORS)
        self.main.set_enabled(**enabled)
        self.estimator_name = name
        self._main_same_instant.reset()

    def set_settings(self, settings: ekf.EKFSettings) -> None:
        """New settings from the next sample on, for the main and comparison estimators."""
        self.settings = settings
        self._mag_correction = magcal.settings_correction(settings)
        for estimator in [self.main] + [c.estimator for c in self.comparisons]:
            estimator.set_settings(settings)
        if self.user is not None:
            self.user.set_settings(settings)   # restarts it: its constructor reads them

    def new_session(self) -> None:
        """A stream whose clock does not continue the previous one (another phone, a reboot,
        an earlier connection's fake clock): commit the open row, forget every estimator's state
        and the phone's orientation; nothing of the earlier stream carries over."""
        self.finish()
        self.reset()
        self.phone_quat = None
        self._last_sample = None
        self._tag_counts = np.zeros(len(TAG_NAMES), np.int64)

    def reset(self) -> None:
        """Forget the orientation of every estimator; they re-initialise from the next samples."""
        self.main.reset()
        self._main_same_instant.reset()
        for comparison in self.comparisons:
            comparison.estimator.reset()
            comparison.errors.clear()
        self._comparisons_same_instant.reset()
        if self.user is not None:
            self.user.reset()

    def align_heading(self) -> float | None:
        """Turn OWN's world about up so its heading matches PHONE's; returns the angle turned
        [deg], None without ORI yet."""
        if self.phone_quat is None:
            return None
        before = self.main.quat
        self.main.align_heading(np.array(self.phone_quat))
        turn = ekf.quaternion.heading_of(ekf.quaternion.multiply(
            self.main.quat, ekf.quaternion.conjugate(before)))
        return math.degrees(turn)

    def set_comparisons_enabled(self, enabled: bool, estimator: str | None = None) -> None:
        """Run (or stop) the 7 sensor combinations of `estimator` (None: keep the current one);
        a new estimator starts them afresh."""
        if estimator is not None and estimator != self.comparison_estimator:
            if estimator not in ekf.ESTIMATORS:
                raise ValueError(f"unknown estimator {estimator!r}")
            self.comparison_estimator = estimator
            self.comparisons = []
        if not enabled:
            self.comparisons = []
        elif not self.comparisons:
            self._comparisons_same_instant.reset()
            self.comparisons = [
                ComparisonState(combination_name(combo), combo,
                                ekf.make_estimator(self.comparison_estimator, self.settings, combo))
                for combo in COMBINATIONS]

    def set_user_lane(self, lane: UserLane | None) -> None:
        """Run your filter beside the main estimator (None: stop). It gets the rows the main
        estimator gets, a switched-off sensor as no sample (None in its step)."""
        self.user = lane

    def set_consistency_enabled(self, enabled: bool) -> None:
        """Collect our EKF's innovations (a twin's per-update replay, see
        app.engine.processing.innovations) for :meth:`take_innovations`."""
        self.probe = InnovationProbe(self.innovations) if enabled else None

    def take_innovations(self) -> dict[str, np.ndarray]:
        """Innovation records (OWN and YOURS) since the previous call, as PlotChunk fields."""
        if self.user is not None:
            for t, sensor, nu, S, accepted in self.user.take_innovations():
                self.innovations.add(t, YOURS, sensor, nu, S, accepted)
        return self.innovations.take()

    # -- snapshots ----------------------------------------------------------------------------

    def snapshot(self) -> dict:
        """Everything the runner and its estimators keep (copies), to continue later from exactly
        here with :meth:`restore` (a replay's checkpoints). Each estimator's own snapshot() is
        used; outputs not yet taken (rows, errors, plot samples) are not part of it."""
        return {
            "estimator": self.estimator_name, "settings": self.settings,
            "main": self.main.snapshot(), "main_same_instant": self._main_same_instant.snapshot(),
            "comparison_estimator": self.comparison_estimator,
            "comparisons": [(c.name, c.sensors, c.estimator.snapshot(),
                             (c.errors.squared.copy(), c.errors.count, c.errors.latest.copy()))
                            for c in self.comparisons],
            "comparisons_same_instant": self._comparisons_same_instant.snapshot(),
            "phone_quat": self.phone_quat, "latest_t_ms": self.latest_t_ms,
            "row_t": self._row_t, "row_has_sample": self._row_has_sample,
            "last_sample": self._last_sample,
            "tag_counts": tuple(int(n) for n in self._tag_counts),
        }

    def restore(self, snapshot: dict) -> None:
        """Continue from a :meth:`snapshot` (estimators of another kind are made anew first);
        the outputs not yet taken are dropped."""
        self.settings = snapshot["settings"]
        self.estimator_name = snapshot["estimator"]
        self.main = _restored(self.main, snapshot["main"], self.estimator_name, self.settings)
        self._main_same_instant.restore(snapshot["main_same_instant"])
        self.comparison_estimator = snapshot["comparison_estimator"]
        old = {c.name: c for c in self.comparisons}
        comparisons = []
        for name, sensors, estimator, (squared, count, latest) in snapshot["comparisons"]:
            state = old.get(name) or ComparisonState(
                name, tuple(sensors), ekf.make_estimator(self.comparison_estimator,
                                                         self.settings, tuple(sensors)))
            state.estimator = _restored(state.estimator, estimator, self.comparison_estimator,
                                        self.settings, tuple(sensors))
            state.errors = ErrorSums(squared.copy(), int(count), latest.copy())
            comparisons.append(state)
        self.comparisons = comparisons
        self._comparisons_same_instant.restore(snapshot["comparisons_same_instant"])
        phone = snapshot["phone_quat"]
        self.phone_quat = None if phone is None else tuple(float(v) for v in phone)
        self.latest_t_ms = snapshot["latest_t_ms"]
        self._row_t = snapshot["row_t"]
        self._row_has_sample = snapshot["row_has_sample"]
        self._last_sample = snapshot.get("last_sample")
        # (a start_state without counts: none seen)
        counts = snapshot.get("tag_counts") or (0,) * len(TAG_NAMES)
        self._tag_counts = np.array([int(n) for n in counts], np.int64)
        self.take_rows()
        self._errors = []
        self._phone_samples = []
        self._reset_plot()

    # -- samples ------------------------------------------------------------------------------

    def feed_arrays(self, t_ms: np.ndarray, tag: np.ndarray, values: np.ndarray) -> None:
        """Ordered filter-tag samples: t_ms (n,) int phone ms, tag (n,) codes GYR 0, ACC 1,
        MAG 2, ORI 3, values (n, 4) (rad/s, m/s^2, uT; ORI w x y z)."""
        if len(t_ms) == 0:
            return
        t_ms = np.ascontiguousarray(t_ms, dtype=np.int64)
        tag = np.ascontiguousarray(tag, dtype=np.int64)
        repeated, self._last_sample = repeats(t_ms, tag, values, self._last_sample)
        if repeated.any():
            self.repeated += int(repeated.sum())
            self.samples_fed += int(repeated.sum())
            keep = ~repeated
            t_ms, tag, values = t_ms[keep], tag[keep], np.asarray(values)[keep]
            if len(t_ms) == 0:
                return
        continuing = self._row_t is not None and int(t_ms[0]) == self._row_t
        if self._row_t is not None and not continuing:
            self._commit_row()
        layout = ChunkLayout(t_ms, tag, values)
        if continuing:
            layout.own_sample[0] |= self._row_has_sample
        # the state before this chunk: what times without a row of their own show
        before = self._state_before()
        cov_before = self._main_cov() if self.collect_cov else None
        t_s = layout.row_t.astype(np.float64) / 1000.0
        gyr, acc, mag = layout.columns
        if self._mag_correction is not None:
            # The magnetometer correction (settings mag_hard_iron, mag_soft_iron) is applied
            # here, once, for every estimator; the plot samples stay as the phone sent them.
            mag = magcal.correct(mag, *self._mag_correction)
        probed = self.probe.capture(self.main) if self.probe is not None else None
        result = (step_rows if self.collect_cov else run_rows)(self.main, t_s, gyr, acc, mag)
        if probed is not None and layout.n_rows:
            self.probe.replay(probed, t_s, gyr, acc, mag)
        # (k, R, 4): the comparisons' estimates after every row
        compared = np.stack([c.estimator.run_batch(t_s, gyr, acc, mag).quat if layout.n_rows
                             else np.empty((0, 4)) for c in self.comparisons]) \
            if self.comparisons else None
        ori = np.flatnonzero(tag == REFERENCE_CODE)
        if len(ori):
            self._add_phone(t_ms[ori], values[ori])
            self.phone_quat = tuple(values[ori[-1]].tolist())
        if self.user is not None:       # after the chunk's ORI samples, as they are compared
            self.user.give(layout.row_t, t_s, *self._switched(gyr, acc, mag))
        self._commit_groups(layout, result, compared, before)
        if self.collect_cov:
            self._commit_covariances(layout, result, cov_before)
        if self.collect_plot:
            self._collect_plot(layout, result)
        self.samples_fed += len(t_ms)
        self._tag_counts += np.bincount(tag, minlength=len(TAG_NAMES))[:len(TAG_NAMES)]
        self.latest_t_ms = int(t_ms[-1])
        self._row_t = self.latest_t_ms
        self._row_has_sample = bool(layout.own_sample[-1])

    def _switched(self, *columns: np.ndarray) -> tuple[np.ndarray, ...]:
        """The GYR, ACC, MAG row columns with the sensors switched off in the main estimator as
        no sample (NaN): what your filter gets, exactly when OWN runs without them."""
        enabled = self.main.enabled
        return tuple(column if enabled[sensor] else np.full_like(column, np.nan)
                     for sensor, column in zip(SENSORS, columns))

    def _add_phone(self, t_ms: np.ndarray, quat: np.ndarray) -> None:
        quat = np.asarray(quat, float)
        self._main_same_instant.add_phone(t_ms, quat)
        if self.comparisons:
            self._comparisons_same_instant.add_phone(t_ms, quat)
        if self.user is not None:
            self.user.add_phone(t_ms, quat)
        if self.collect_plot:
            self._phone_samples.append((np.asarray(t_ms, np.int64), quat))

    def _state_before(self) -> tuple:
        status = self.main.flags
        flags = (status.acc_rejected, status.mag_rejected, status.at_rest)
        phone = self.phone_quat if self.phone_quat is not None else _NAN4
        compare = np.stack([c.estimator.quat for c in self.comparisons]) \
            if self.comparisons else None
        return self.main.quat, flags, compare, phone

    def _commit_groups(self, layout: ChunkLayout, result: RowsResult,
                       compared: np.ndarray | None, before: tuple) -> None:
        """Rows of the distinct times completed in this chunk (the last one stays open until a
        later time arrives)."""
        done = len(layout.group_last) - 1
        if done <= 0:
            return
        quat_before, flags_before, compare_before, phone_before = before
        has_row = layout.group_row[:done] >= 0
        index = np.where(has_row, layout.group_row[:done], 0)
        empty = not layout.n_rows
        quat = np.where(has_row[:, None], 0.0 if empty else result.quat[index], quat_before)
        flags = np.where(has_row[:, None], False if empty else result.flags[index],
                         np.array(flags_before))
        group_ori = layout.group_ori[:done]
        has_ori = group_ori >= 0
        phone = np.where(has_ori[:, None], layout.values[np.where(has_ori, group_ori, 0)],
                         np.array(phone_before))
        t_rows = layout.t_ms[layout.group_last[:done]]
        own = layout.own_sample[:done]
        rows_compared = None
        if compared is not None:
            chosen = np.flatnonzero(own)
            rows_compared = np.where(has_row[None, chosen, None],
                                     0.0 if empty else compared[:, index[chosen]],
                                     compare_before[:, None, :])
        self._compare(t_rows[own], quat[own], rows_compared)
        self._add_rows(t_rows, quat, phone, flags, own)

    def _main_cov(self) -> np.ndarray:
        cov = self.main.cov
        return np.full((4, 4), np.nan) if cov is None else np.array(cov, float)[:4, :4]

    def _commit_covariances(self, layout: ChunkLayout, result: RowsResult,
                            before: np.ndarray) -> None:
        """collect_cov: the covariance of q at each row committed by _commit_groups."""
        done = len(layout.group_last) - 1
        if done <= 0:
            return
        has_row = layout.group_row[:done] >= 0
        if not layout.n_rows:
            self._covs.append(np.broadcast_to(before, (done, 4, 4)).copy())
            return
        index = np.where(has_row, layout.group_row[:done], 0)
        self._covs.append(np.where(has_row[:, None, None], result.cov[index], before))

    def take_covariances(self) -> np.ndarray:
        """collect_cov: (N, 4, 4) covariance of q of the rows committed since the previous call
        (call it before take_rows, which it matches row for row)."""
        covs, self._covs = self._covs, []
        return np.concatenate(covs) if covs else np.empty((0, 4, 4))

    def _compare(self, t_ms: np.ndarray, quat: np.ndarray, compared: np.ndarray | None) -> None:
        """Committed estimates (sensor times only) against the ORI samples they bracket."""
        if not len(t_ms):
            return
        errors = self._main_same_instant.add_estimates(t_ms, quat)
        if len(errors):
            self._errors.append(errors)
        if compared is not None and self.comparisons:
            resolved = self._comparisons_same_instant.add_estimates(t_ms, compared)
            if len(resolved):
                for comparison, error_deg in zip(self.comparisons, resolved.error_deg):
                    comparison.errors.add_errors(error_deg)

    def _collect_plot(self, layout: ChunkLayout, result: RowsResult) -> None:
        rejected = {1: result.acc_rejected, 2: result.mag_rejected}
        for code, name in ((0, "gyr"), (1, "acc"), (2, "mag")):
            chosen = layout.tag == code
            if not chosen.any():
                continue
            times, values, flags = self._plot[name]
            times.append(layout.t_ms[chosen])
            values.append(layout.values[chosen, :3])
            if code in rejected:
                flags.append(rejected[code][layout.row_of[chosen]])

    def finish(self) -> None:
        """End of stream: commit the row of the last time."""
        if self._row_t is not None:
            self._commit_row()
            self._row_t = None
        if self.user is not None:
            self.user.finish()

    @property
    def flags(self) -> ekf.Flags:
        """The main estimator's flags (a copy)."""
        return self.main.flags

    @property
    def own_quat(self) -> np.ndarray:
        return self.main.quat

    # -- rows ---------------------------------------------------------------------------------

    def _reset_rows(self) -> None:
        self._rows: list[tuple[np.ndarray, ...]] = []
        self._covs: list[np.ndarray] = []

    def _add_rows(self, t_ms: np.ndarray, quat: np.ndarray, phone: np.ndarray,
                  flags: np.ndarray, has_sample: np.ndarray) -> None:
        self._rows.append((t_ms, quat, phone, flags, has_sample))

    def _commit_row(self) -> None:
        """The row of the pending time, from the estimators' state now."""
        q = self.main.quat
        phone = self.phone_quat
        status = self.main.flags
        t = np.array([self._row_t], np.int64)
        if self._row_has_sample:
            self._compare(t, q.reshape(1, 4),
                          np.stack([c.estimator.quat.reshape(1, 4) for c in self.comparisons])
                          if self.comparisons else None)
        if self.collect_cov:
            self._covs.append(self._main_cov()[None])
        self._add_rows(t, q.reshape(1, 4),
                       np.array([phone if phone is not None else _NAN4], np.float64),
                       np.array([[status.acc_rejected, status.mag_rejected, status.at_rest]],
                                bool), np.array([self._row_has_sample]))

    def take_rows(self) -> Rows:
        """The rows committed since the previous call (the row of the latest time is committed
        when a later time arrives or at finish())."""
        if not self._rows:
            return Rows.empty()
        t_ms, quat, phone, flags, has_sample = (np.concatenate(parts)
                                                for parts in zip(*self._rows))
        rows = Rows(np.asarray(t_ms, dtype=np.int64), np.ascontiguousarray(quat, np.float64),
                    np.ascontiguousarray(phone, np.float64), flags[:, 0].copy(),
                    flags[:, 1].copy(), flags[:, 2].copy(), np.asarray(has_sample, dtype=bool))
        self._reset_rows()
        return rows

    def take_errors(self) -> ErrorRows:
        """The main estimator's errors against ORI resolved since the previous call: per ORI
        sample, total/heading/inclination [deg] with our estimate slerped to its time."""
        errors, self._errors = self._errors, []
        if not errors:
            return ErrorRows.empty()
        return ErrorRows(np.concatenate([e.t_ms for e in errors]),
                         np.concatenate([e.error_deg for e in errors]))

    def take_user_errors(self) -> ErrorRows:
        """Your filter's errors against ORI resolved since the previous call (as take_errors;
        they come later than OWN's: when your filter's results come back)."""
        return ErrorRows.empty() if self.user is None else self.user.take_errors()

    def take_user_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """YOURS' rows that came back since the previous call: t_ms (N,), quat (N, 4) (NaN
        where your filter has none)."""
        if self.user is None:
            return np.empty(0, np.int64), np.empty((0, 4))
        return self.user.take_rows()

    def take_phone_samples(self) -> tuple[np.ndarray, np.ndarray]:
        """ORI samples fed since the previous call (with collect_plot): t_ms (n,), quat (n, 4)."""
        samples, self._phone_samples = self._phone_samples, []
        if not samples:
            return np.empty(0, np.int64), np.empty((0, 4))
        return (np.concatenate([t for t, _ in samples]),
                np.concatenate([q for _, q in samples]))

    # -- plot samples ---------------------------------------------------------------------------

    def _reset_plot(self) -> None:
        # per sensor: [times (ms) pieces, values pieces, rejected pieces]
        self._plot: dict[str, list[list[np.ndarray]]] = {
            name: [[], [], []] for name in ("gyr", "acc", "mag")}

    def take_plot_samples(self) -> dict[str, np.ndarray]:
        """Raw sensor samples fed since the previous call: t_acc/t_gyr/t_mag (ms, int64),
        acc/gyr/mag (n, 3), acc_rejected/mag_rejected (n,) bool."""
        out: dict[str, np.ndarray] = {}
        for name in ("acc", "gyr", "mag"):
            times, values, rejected = self._plot[name]
            out["t_" + name] = (np.concatenate(times) if times else np.empty(0, np.int64))
            out[name] = np.concatenate(values) if values else np.empty((0, 3))
            if name != "gyr":
                out[name + "_rejected"] = (np.concatenate(rejected) if rejected
                                           else np.empty(0, bool))
        self._reset_plot()
        return out


__all__ = ["COMBINATIONS", "SENSORS", "TAG_NAMES", "ComparisonState", "EstimatorRunner", "Rows",
           "combination_name"]


#: The tag codes' names (GYR 0, ACC 1, MAG 2, ORI 3), as the sensors are named elsewhere.
TAG_NAMES: tuple[str, ...] = tuple(tag.lower() for tag in FILTER_TAGS)

#: The 7 non-empty sensor combinations of the EKF, "gyr+acc+mag" first.
COMBINATIONS: tuple[tuple[str, ...], ...] = tuple(
    combo for size in (3, 2, 1) for combo in itertools.combinations(SENSORS, size))


def combination_name(sensors: Iterable[str]) -> str:
    """("gyr", "acc") -> "gyr+acc"."""
    return "+".join(sensors)


@dataclass
class Rows:
    """Per distinct phone time (rows in time order).

    t_ms (N,) int64; quat (N, 4) the main estimate after every sample at that time; phone_quat
    (N, 4) the latest ORI at or before that time (NaN before the first); acc_rejected,
    mag_rejected, at_rest (N,) bool: the main estimator's lights;
    has_sample (N,) bool: a GYR, ACC or MAG sample has this time (False: ORI only). (Your
    filter's rows come back later, on their own: EstimatorRunner.take_user_rows.)
    """

    t_ms: np.ndarray
    quat: np.ndarray
    phone_quat: np.ndarray
    acc_rejected: np.ndarray
    mag_rejected: np.ndarray
    at_rest: np.ndarray
    has_sample: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ms)

    @property
    def t_s(self) -> np.ndarray:
        return self.t_ms.astype(np.float64) / 1000.0

    @staticmethod
    def empty() -> Rows:
        return Rows(np.empty(0, np.int64), np.empty((0, 4)), np.empty((0, 4)),
                    np.empty(0, bool), np.empty(0, bool), np.empty(0, bool), np.empty(0, bool))

    def select(self, mask: np.ndarray) -> Rows:
        """The rows where `mask` is true."""
        return Rows(*(getattr(self, name)[mask] for name in self.__dataclass_fields__))

    @staticmethod
    def concatenate(parts: list[Rows]) -> Rows:
        """Rows of several pieces, in order."""
        if not parts:
            return Rows.empty()
        return Rows(*(np.concatenate([getattr(part, name) for part in parts])
                      for name in Rows.__dataclass_fields__))


@jit
def layout_rows(t_ms, tag, row_of, row_t, group_last, group_row, group_ori):
    """Ordered samples -> estimator rows and distinct-time groups.

    Rows: consecutive sensor samples (GYR 0, ACC 1, MAG 2) of one time with strictly increasing
    tags, so feeding a row gyr, acc, mag is feeding its samples in their order. row_of[k]: the
    row of sample k (-1 for the phone's orientation, ORI). Groups: runs of equal time; group_last its last sample,
    group_row the latest row at or before it (-1: none in this chunk), group_ori the latest ORI
    sample at or before it (-1: none). Returns (rows, groups)."""
    rows = 0
    groups = 0
    current = -1
    current_tag = 0
    last_ori = -1
    n = t_ms.shape[0]
    for k in range(n):
        t = t_ms[k]
        if k > 0 and t != t_ms[k - 1]:
            group_last[groups] = k - 1
            group_row[groups] = current
            group_ori[groups] = last_ori
            groups += 1
        code = tag[k]
        if code == REFERENCE_CODE:
            last_ori = k
            row_of[k] = -1
            continue
        if current < 0 or t != row_t[current] or code <= current_tag:
            current = rows
            row_t[current] = t
            rows += 1
        current_tag = code
        row_of[k] = current
    if n > 0:
        group_last[groups] = n - 1
        group_row[groups] = current
        group_ori[groups] = last_ori
        groups += 1
    return rows, groups


class RowsResult:
    """Per estimator row: quat (R, 4), flags (R, 3) after the row (acc_rejected, mag_rejected,
    at_rest), and the acc/mag rejected flag right after the row's ACC/MAG sample."""

    __slots__ = ("quat", "flags", "acc_rejected", "mag_rejected", "cov")

    def __init__(self, quat, flags, acc_rejected, mag_rejected, cov=None) -> None:
        self.quat = quat
        self.flags = flags
        self.acc_rejected = acc_rejected
        self.mag_rejected = mag_rejected
        self.cov = cov          # (R, 4, 4) covariance of q after each row (collect_cov only)


def run_rows(estimator: ekf.Estimator, t_s: np.ndarray, gyr: np.ndarray, acc: np.ndarray,
              mag: np.ndarray) -> RowsResult:
    """Feed rows (NaN rows: no such sample) gyr, acc, mag through the estimator's run_batch
    (one compiled nogil call for the EKFs). A flag is only written by its sensor's update, so
    the flags after a row are those right after the row's sample."""
    result = estimator.run_batch(t_s, gyr, acc, mag)
    flags = np.stack([result.acc_rejected, result.mag_rejected, result.at_rest], axis=1)
    return RowsResult(result.quat, flags, result.acc_rejected, result.mag_rejected)


def step_rows(estimator: ekf.Estimator, t_s: np.ndarray, gyr: np.ndarray, acc: np.ndarray,
               mag: np.ndarray) -> RowsResult:
    """What run_rows gives (step is the filter run_batch runs), plus the covariance of q
    after each row: one Python step per row, for exports that need P (xhat.P)."""
    n = len(t_s)
    quat = np.empty((n, 4))
    flags = np.zeros((n, 3), bool)
    cov = np.full((n, 4, 4), np.nan)
    present = [~np.isnan(column).any(axis=1) for column in (gyr, acc, mag)]
    for k in range(n):
        estimator.step(float(t_s[k]), *(column[k] if has[k] else None
                                         for column, has in zip((gyr, acc, mag), present)))
        quat[k] = estimator.quat
        status = estimator.flags
        flags[k] = (status.acc_rejected, status.mag_rejected, status.at_rest)
        covariance = estimator.cov
        if covariance is not None:
            cov[k] = np.asarray(covariance)[:4, :4]
    return RowsResult(quat, flags, flags[:, 0].copy(), flags[:, 1].copy(), cov)



class ChunkLayout:
    """A chunk of ordered samples cut into estimator rows and distinct-time groups (layout_rows).

    row_of (n,): the row of each sample (-1 for ORI); row_t (R,): each row's time; columns: the
    (R, 3) gyr, acc, mag arrays of the rows (NaN: no such sample); group_last, group_row,
    group_ori (G,): per distinct time its last sample, the latest row and the latest ORI sample
    at or before it (-1: none in this chunk); own_sample (G,): a sensor sample has that time."""

    def __init__(self, t_ms: np.ndarray, tag: np.ndarray, values: np.ndarray) -> None:
        n = len(t_ms)
        self.t_ms, self.tag, self.values = t_ms, tag, values
        self.row_of = np.empty(n, np.int64)
        row_t = np.empty(n, np.int64)
        group_last = np.empty(n, np.int64)
        group_row = np.empty(n, np.int64)
        group_ori = np.empty(n, np.int64)
        self.n_rows, groups = layout_rows(t_ms, tag, self.row_of, row_t, group_last, group_row,
                                      group_ori)
        self.row_t = row_t[:self.n_rows]
        self.group_last = group_last[:groups]
        self.group_row = group_row[:groups]
        self.group_ori = group_ori[:groups]
        group_first = np.concatenate(([0], self.group_last[:-1] + 1))
        self.own_sample = np.maximum.reduceat((tag != REFERENCE_CODE).astype(np.int8), group_first) > 0
        self.columns = []
        for code in SENSOR_CODES:
            column = np.full((self.n_rows, WIDTHS[code]), np.nan)
            chosen = tag == code
            if chosen.any():
                column[self.row_of[chosen]] = values[chosen, :WIDTHS[code]]
            self.columns.append(column)


@jit
def _table_key():
    return TABLE_KEY


check_cache(_table_key, globals(), TABLE_KEY)
