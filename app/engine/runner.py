"""Ordered samples -> estimator steps -> rows of estimates. One code path for live and offline.

:class:`EstimatorRunner` feeds time-ordered filter-tag samples (from
:class:`app.stream.ordering.TimeOrderer`) into the main estimator and, optionally, the comparison
estimators; ORI is the phone's own estimate and never reaches a filter. It produces one row
per distinct phone time. The live engine and :func:`run_offline` both use it on the same
ordered samples (chunk by chunk: each estimator runs over a chunk in one compiled call) and the
result does not depend on the chunking, so a file and its live replay give bit-identical
estimates.

Times: phone ms (aligned) in, seconds (t_ms / 1000) to the estimators. Quaternions w-first,
sensor -> ENU, w >= 0. Angles in degrees.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numba import njit

import ekf
from ekf import SENSORS
from app.engine.innovations import YOURS, InnovationBuffer, InnovationProbe
from app.engine.user_filter import make_estimator
from app.engine.user_lane import UserLane
from app.stream.fastparse import samples_to_arrays
from app.stream.protocol import Sample

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
    PHONE; acc_rejected, mag_rejected, at_rest (N,) bool: the main estimator's lights;
    has_sample (N,) bool: a GYR, ACC or MAG sample has this time (False: ORI only);
    user_quat (N, 4): your filter's quaternion (YOURS; NaN where it has none), None when no
    user filter runs beside the main estimator.
    """

    t_ms: np.ndarray
    quat: np.ndarray
    phone_quat: np.ndarray
    angle_deg: np.ndarray
    acc_rejected: np.ndarray
    mag_rejected: np.ndarray
    at_rest: np.ndarray
    has_sample: np.ndarray
    user_quat: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t_ms)

    @property
    def t_s(self) -> np.ndarray:
        return self.t_ms.astype(np.float64) / 1000.0

    @staticmethod
    def empty() -> Rows:
        return Rows(np.empty(0, np.int64), np.empty((0, 4)), np.empty((0, 4)), np.empty(0),
                    np.empty(0, bool), np.empty(0, bool), np.empty(0, bool), np.empty(0, bool))

    def select(self, mask: np.ndarray) -> Rows:
        """The rows where `mask` is true."""
        return Rows(*(None if getattr(self, name) is None else getattr(self, name)[mask]
                      for name in self.__dataclass_fields__))

    @staticmethod
    def concatenate(parts: list[Rows]) -> Rows:
        """Rows of several pieces, in order (user_quat NaN for pieces without one)."""
        if not parts:
            return Rows.empty()
        user = None
        if any(part.user_quat is not None for part in parts):
            user = np.concatenate([np.full((len(part), 4), np.nan) if part.user_quat is None
                                   else part.user_quat for part in parts])
        return Rows(*(np.concatenate([getattr(part, name) for part in parts])
                      for name in Rows.__dataclass_fields__ if name != "user_quat"),
                    user_quat=user)


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


_NAN4 = (math.nan, math.nan, math.nan, math.nan)
_jit = njit(cache=True, nogil=True)


@_jit
def _layout(t_ms, tag, row_of, row_t, group_last, group_row, group_ori):
    """Ordered samples -> estimator rows and distinct-time groups.

    Rows: consecutive sensor samples (GYR 0, ACC 1, MAG 2) of one time with strictly increasing
    tags, so feeding a row gyr, acc, mag is feeding its samples in their order. row_of[k]: the
    row of sample k (-1 for ORI, 3). Groups: runs of equal time; group_last its last sample,
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
        if code == 3:
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


@_jit
def _angle_deg(p0, p1, p2, p3, q0, q1, q2, q3):
    """:func:`angle_deg`, compiled (the same operations, so the same bits)."""
    dot = abs(p0 * q0 + p1 * q1 + p2 * q2 + p3 * q3)
    norm = math.sqrt((p0 * p0 + p1 * p1 + p2 * p2 + p3 * p3)
                     * (q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3))
    if not norm > 0.0:
        return math.nan
    return math.degrees(2.0 * math.acos(min(1.0, dot / norm)))


@_jit
def _accumulate_errors(quat, phone, squared_sum, count, latest):
    """Per row with a phone quaternion: the angle to it; returns the running (squared_sum,
    count, latest angle) as :meth:`EstimatorRunner._commit_row` would, row by row."""
    for k in range(quat.shape[0]):
        if math.isnan(phone[k, 0]):
            continue
        error = _angle_deg(quat[k, 0], quat[k, 1], quat[k, 2], quat[k, 3],
                           phone[k, 0], phone[k, 1], phone[k, 2], phone[k, 3])
        latest = error
        if error == error:
            squared_sum += error * error
            count += 1
    return squared_sum, count, latest


class _RowsResult:
    """Per estimator row: quat (R, 4), flags (R, 3) after the row (acc_rejected, mag_rejected,
    at_rest), and the acc/mag rejected flag right after the row's ACC/MAG sample."""

    __slots__ = ("quat", "flags", "acc_rejected", "mag_rejected")

    def __init__(self, quat, flags, acc_rejected, mag_rejected) -> None:
        self.quat = quat
        self.flags = flags
        self.acc_rejected = acc_rejected
        self.mag_rejected = mag_rejected


def _run_rows(estimator: ekf.Estimator, t_s: np.ndarray, gyr: np.ndarray, acc: np.ndarray,
              mag: np.ndarray) -> _RowsResult:
    """Feed rows (NaN rows: no such sample) gyr, acc, mag through the estimator's run_batch
    (one compiled nogil call for the EKFs). A flag is only written by its sensor's update, so
    the flags after a row are those right after the row's sample."""
    result = estimator.run_batch(t_s, gyr, acc, mag)
    flags = np.stack([result.acc_rejected, result.mag_rejected, result.at_rest], axis=1)
    return _RowsResult(result.quat, flags, result.acc_rejected, result.mag_rejected)


class _ChunkLayout:
    """A chunk of ordered samples cut into estimator rows and distinct-time groups (_layout).

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
        self.n_rows, groups = _layout(t_ms, tag, self.row_of, row_t, group_last, group_row,
                                      group_ori)
        self.row_t = row_t[:self.n_rows]
        self.group_last = group_last[:groups]
        self.group_row = group_row[:groups]
        self.group_ori = group_ori[:groups]
        group_first = np.concatenate(([0], self.group_last[:-1] + 1))
        self.own_sample = np.maximum.reduceat((tag < 3).astype(np.int8), group_first) > 0
        self.columns = []
        for code in range(3):
            column = np.full((self.n_rows, 3), np.nan)
            chosen = tag == code
            if chosen.any():
                column[self.row_of[chosen]] = values[chosen, :3]
            self.columns.append(column)


class EstimatorRunner:
    """Feed ordered samples; read the latest estimates; take the rows produced so far.

    estimator: a name from ekf.ESTIMATORS, a user's filter file (FILE.py) or an estimator
    object (``ekf.Estimator``); settings: ekf.EKFSettings or None (default preset);
    sensors: the sensors enabled in the main estimator; comparisons: also run the 7 EKF sensor
    combinations. collect_plot: keep the raw ACC/GYR/MAG samples with their rejected flags for
    plotting (:meth:`take_plot_samples`).

    Samples must come in time order (at equal times GYR, ACC, MAG, as TimeOrderer releases
    them). :meth:`feed_arrays` takes a chunk as arrays and runs each estimator over it in one
    compiled call; :meth:`feed_many` takes Samples through the same path. The
    result does not depend on the chunking: it is what feeding the samples one by one with
    update_gyr/acc/mag gives, bit for bit, with one row per distinct time committed when a
    later time arrives (or at :meth:`finish`) from the estimators' state at that moment.

    Beside the main estimator: your filter (:meth:`set_user_lane`, YOURS: its quaternion per row
    in Rows.user_quat, its error against PHONE in the lane) and, on request, our EKF's
    innovations (:meth:`set_consistency_enabled`); both go to :meth:`take_innovations`.
    """

    def __init__(self, estimator: str | ekf.Estimator = "ekf",
                 settings: ekf.EKFSettings | None = None,
                 sensors: Iterable[str] = SENSORS, comparisons: bool = False,
                 collect_plot: bool = False) -> None:
        self.settings = settings if settings is not None else ekf.PRESETS["default"]
        self._sensors = tuple(s for s in SENSORS if s in tuple(sensors))
        self.main: ekf.Estimator = make_estimator(estimator, self.settings, self._sensors)
        self.estimator_name = estimator if isinstance(estimator, str) else self.main.name
        self.user: UserLane | None = None
        self.innovations = InnovationBuffer()
        self.probe: InnovationProbe | None = None
        self.samples_fed = 0                      # filter-tag samples fed so far
        self.collect_plot = collect_plot
        self.comparisons: list[ComparisonState] = []
        if comparisons:
            self.set_comparisons_enabled(True)
        self.phone_quat: tuple[float, float, float, float] | None = None
        self.latest_t_ms: int | None = None
        self._row_t: int | None = None           # the latest time: its row is still open
        self._row_has_sample = False             # ... and whether it has a sensor sample
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
        if self.user is not None:
            self.user.set_enabled(sensor, enabled)

    def set_estimator(self, name: str) -> None:
        """Switch the main estimator (it starts afresh, with the current sensor switches)."""
        enabled = self.main.enabled
        self.main = make_estimator(name, self.settings,
                                   tuple(s for s in SENSORS if enabled[s]) or SENSORS)
        self.main.set_enabled(**enabled)
        self.estimator_name = name

    def set_settings(self, settings: ekf.EKFSettings) -> None:
        """New settings from the next sample on, for the main and comparison estimators."""
        self.settings = settings
        for estimator in [self.main] + [c.estimator for c in self.comparisons]:
            estimator.set_settings(settings)
        if self.user is not None and self.user.estimator is not None:
            self.user.estimator.set_settings(settings)   # restarts it: its constructor reads them

    def reset(self) -> None:
        """Forget the orientation of every estimator; they re-initialise from the next samples."""
        self.main.reset()
        for comparison in self.comparisons:
            comparison.estimator.reset()
            comparison.squared_sum, comparison.count = 0.0, 0
            comparison.angle_to_phone_deg = math.nan
        if self.user is not None:
            self.user.reset()

    def align_heading(self) -> bool:
        """Turn OWN's world about up so its heading matches PHONE's. False without ORI yet."""
        if self.phone_quat is None:
            return False
        self.main.align_heading(np.array(self.phone_quat))
        return True

    def set_user_lane(self, lane: UserLane | None) -> None:
        """Run your filter beside the main estimator (None: stop). The lane takes the current
        sensor switches."""
        self.user = lane
        if lane is not None:
            for sensor, on in self.main.enabled.items():
                lane.set_enabled(sensor, on)

    def set_consistency_enabled(self, enabled: bool) -> None:
        """Collect our EKF's innovations (a twin's per-update replay, see
        app.engine.innovations) for :meth:`take_innovations`."""
        self.probe = InnovationProbe(self.innovations) if enabled else None

    def take_innovations(self) -> dict[str, np.ndarray]:
        """Innovation records (OWN and YOURS) since the previous call, as PlotChunk fields."""
        if self.user is not None:
            for t, sensor, nu, S, accepted in self.user.take_innovations():
                self.innovations.add(t, YOURS, sensor, nu, S, accepted)
        return self.innovations.take()

    def set_comparisons_enabled(self, enabled: bool) -> None:
        if not enabled:
            self.comparisons = []
        elif not self.comparisons:
            self.comparisons = [
                ComparisonState(combination_name(combo), combo,
                                ekf.make_estimator("ekf", self.settings, combo))
                for combo in COMBINATIONS]

    # -- samples ------------------------------------------------------------------------------

    def feed_many(self, samples: Iterable[Sample]) -> None:
        """Samples in order (non-filter tags are ignored)."""
        arrays = samples_to_arrays(list(samples))
        self.feed_arrays(arrays.t_ms, arrays.tag, arrays.values)

    def feed_arrays(self, t_ms: np.ndarray, tag: np.ndarray, values: np.ndarray) -> None:
        """Ordered filter-tag samples: t_ms (n,) int phone ms, tag (n,) codes GYR 0, ACC 1,
        MAG 2, ORI 3, values (n, 4) (rad/s, m/s^2, uT; ORI w x y z)."""
        if len(t_ms) == 0:
            return
        t_ms = np.ascontiguousarray(t_ms, dtype=np.int64)
        tag = np.ascontiguousarray(tag, dtype=np.int64)
        continuing = self._row_t is not None and int(t_ms[0]) == self._row_t
        if self._row_t is not None and not continuing:
            self._commit_row()
        layout = _ChunkLayout(t_ms, tag, values)
        if continuing:
            layout.own_sample[0] |= self._row_has_sample
        # the state before this chunk: what times without a row of their own show
        before = self._state_before()
        t_s = layout.row_t.astype(np.float64) / 1000.0
        gyr, acc, mag = layout.columns
        probed = self.probe.capture(self.main) if self.probe is not None else None
        result = _run_rows(self.main, t_s, gyr, acc, mag)
        if probed is not None and layout.n_rows:
            self.probe.replay(probed, t_s, gyr, acc, mag)
        # comparisons are always compiled EKFs
        compared = [c.estimator.run_batch(t_s, gyr, acc, mag).quat if layout.n_rows
                    else np.empty((0, 4)) for c in self.comparisons]
        users = None if self.user is None else self.user.run_rows(t_s, gyr, acc, mag)
        self._commit_groups(layout, result, compared, before, users)
        self.samples_fed += len(t_ms)
        ori = np.flatnonzero(tag == 3)
        if len(ori):
            self.phone_quat = tuple(values[ori[-1]].tolist())
        if self.collect_plot:
            self._collect_plot(layout, result)
        self.latest_t_ms = int(t_ms[-1])
        self._row_t = self.latest_t_ms
        self._row_has_sample = bool(layout.own_sample[-1])

    def _state_before(self) -> tuple:
        status = self.main.flags
        flags = (status.acc_rejected, status.mag_rejected, status.at_rest)
        phone = self.phone_quat if self.phone_quat is not None else _NAN4
        user = None if self.user is None else self.user.latest.copy()
        return self.main.quat, flags, [c.estimator.quat for c in self.comparisons], phone, user

    def _commit_groups(self, layout: _ChunkLayout, result: _RowsResult,
                       compared: list[np.ndarray], before: tuple,
                       users: np.ndarray | None = None) -> None:
        """Rows of the distinct times completed in this chunk (the last one stays open until a
        later time arrives)."""
        done = len(layout.group_last) - 1
        if done <= 0:
            return
        quat_before, flags_before, compare_before, phone_before, user_before = before
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
        if self.comparisons and not np.isnan(phone[:, 0]).all():
            for comparison, compared_quat, previous in zip(self.comparisons, compared,
                                                           compare_before):
                rows = np.where(has_row[:, None], 0.0 if empty else compared_quat[index],
                                previous)
                comparison.squared_sum, comparison.count, comparison.angle_to_phone_deg = \
                    _accumulate_errors(rows, phone, comparison.squared_sum, comparison.count,
                                       comparison.angle_to_phone_deg)
        user = None
        if users is not None:
            lane = self.user
            before_user = user_before if user_before is not None else _NAN4
            user = np.where(has_row[:, None], users[index] if not empty else np.nan,
                            np.asarray(before_user))
            lane.squared_sum, lane.count, lane.angle_to_phone_deg = _accumulate_errors(
                user, phone, lane.squared_sum, lane.count, lane.angle_to_phone_deg)
        self._add_rows(layout.t_ms[layout.group_last[:done]], quat, phone, flags,
                       layout.own_sample[:done], user)

    def _collect_plot(self, layout: _ChunkLayout, result: _RowsResult) -> None:
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

    @property
    def flags(self) -> ekf.Flags:
        """The main estimator's flags (a copy)."""
        return self.main.flags

    @property
    def own_quat(self) -> np.ndarray:
        return self.main.quat

    @property
    def angle_deg(self) -> float:
        return angle_deg(self.main.quat, self.phone_quat)

    # -- rows ---------------------------------------------------------------------------------

    def _reset_rows(self) -> None:
        self._rows: list[tuple[np.ndarray, ...]] = []

    def _add_rows(self, t_ms: np.ndarray, quat: np.ndarray, phone: np.ndarray,
                  flags: np.ndarray, has_sample: np.ndarray,
                  user: np.ndarray | None = None) -> None:
        self._rows.append((t_ms, quat, phone, flags, has_sample, user))

    def _merged_rows(self) -> tuple[np.ndarray, ...]:
        if len(self._rows) == 1:
            return self._rows[0]
        merged = [np.concatenate(parts) for parts in zip(*(r[:5] for r in self._rows))]
        users = [r[5] for r in self._rows]
        if all(u is None for u in users):
            return (*merged, None)
        return (*merged, np.concatenate([np.full((len(r[0]), 4), np.nan) if r[5] is None
                                         else r[5] for r in self._rows]))

    def _commit_row(self) -> None:
        """The row of the pending time, from the estimators' state now."""
        q = self.main.quat
        phone = self.phone_quat
        status = self.main.flags
        user = None if self.user is None else self.user.latest.copy()
        if phone is not None:
            lanes = [(c, c.estimator.quat) for c in self.comparisons]
            if user is not None:
                lanes.append((self.user, user))
            for lane, lane_quat in lanes:
                error = angle_deg(lane_quat, phone)
                lane.angle_to_phone_deg = error
                if error == error:
                    lane.squared_sum += error * error
                    lane.count += 1
        self._add_rows(np.array([self._row_t], np.int64), q.reshape(1, 4),
                       np.array([phone if phone is not None else _NAN4], np.float64),
                       np.array([[status.acc_rejected, status.mag_rejected, status.at_rest]],
                                bool), np.array([self._row_has_sample]),
                       None if user is None else user.reshape(1, 4))

    def take_rows(self) -> Rows:
        """The rows committed since the previous call (the row of the latest time is committed
        when a later time arrives or at finish())."""
        if not self._rows:
            return Rows.empty()
        t_ms, quat, phone, flags, has_sample, user = self._merged_rows()
        quat = np.ascontiguousarray(quat, dtype=np.float64)
        phone = np.ascontiguousarray(phone, dtype=np.float64)
        rows = Rows(np.asarray(t_ms, dtype=np.int64), quat, phone, angles_deg(quat, phone),
                    flags[:, 0].copy(), flags[:, 1].copy(), flags[:, 2].copy(),
                    np.asarray(has_sample, dtype=bool),
                    None if user is None else np.ascontiguousarray(user, dtype=np.float64))
        self._reset_rows()
        return rows

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
