"""Ordered samples cut into estimator rows, the rows' results and the rows of estimates.

A row is what one estimator step is fed: the sensor samples of one phone time in code order
(gyr, acc, mag; :mod:`app.stream.protocol`). :class:`ChunkLayout` cuts a chunk of ordered samples
into rows and distinct-time groups, :func:`run_rows` / :func:`step_rows` run an estimator over
the rows and :class:`Rows` holds the estimates per distinct time that
:class:`app.engine.runner.EstimatorRunner` gives.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

import ekf
from ekf import SENSORS
from ekf.fast._jit import check_cache
from app.stream.protocol import (FILTER_TAGS, REFERENCE_CODE, SENSOR_CODES, TABLE_KEY, WIDTHS,
                                 jit)

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
