"""Your filter beside the main estimator: the runner hands every chunk's rows to a
:class:`UserLane`, which runs them through the user's filter and returns its quaternion per
row (NaN while it is paused, catching up or not started).

Never holding up the engine: with ``realtime`` (the live engine), the user's code gets at most
``share`` of the wall-clock time. A filter slower than that gets only some rows, evenly spread
(decimated), and the lane reports it (:meth:`UserLane.used_fraction`, the time per call). Offline
(`filter`, `evaluate`, a re-run) every row is run.

Catching up (after a reload or a seek): the engine thread keeps handing rows over, the lane
only buffers them, and a background thread runs first the log up to now and then the buffer
through the new filter; when the buffer is empty the new filter takes over, under the lane's
lock, so no row is run twice or skipped (see :mod:`app.engine.userfilter.host`).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Callable

import numpy as np

from app.engine.compare import ErrorSums, SameInstant
from app.engine.userfilter.filter import UserFilterEstimator

MAX_BUDGET_S = 0.1          # unused time carried forward at most this long
RECENT_S = 2.0              # used_fraction and "slow" look back this far [s, wall clock]
_NAN4 = np.full(4, np.nan)


class UserLane:
    """Runs a :class:`UserFilterEstimator` on the runner's rows. Thread-safe hand-over."""

    def __init__(self, estimator: UserFilterEstimator | None = None, realtime: bool = False,
                 share: float = 0.5, clock: Callable[[], float] = time.perf_counter) -> None:
        self.lock = threading.Lock()
        self.estimator = estimator
        self.realtime = realtime
        self.share = share
        self._clock = clock
        self._budget = 0.0
        self._last_call: float | None = None
        self._recent: deque[tuple[float, int, int]] = deque()   # (wall time, given, run)
        self._buffer: list[tuple[np.ndarray, ...]] | None = None
        self._token = 0                  # of the current catch-up
        self.buffered_rows = 0
        self.latest = _NAN4.copy()        # the quaternion of the latest row
        self.rows_given = 0
        self.rows_run = 0
        self.reset_errors()

    # -- errors against PHONE (kept by the runner as for the comparisons: at PHONE's times) -----

    def reset_errors(self) -> None:
        self.same_instant = SameInstant()
        self.errors = ErrorSums()

    @property
    def rmse_deg(self) -> float:
        """RMSE of the total angle against PHONE [deg] (errors.rmse(): also heading, tilt)."""
        return float(self.errors.rmse()[0])

    @property
    def angle_to_phone_deg(self) -> float:
        return float(self.errors.latest[0])

    # -- state ---------------------------------------------------------------------------------

    @property
    def catching_up(self) -> bool:
        return self._buffer is not None

    def used_fraction(self) -> float:
        """Of the rows given in the last RECENT_S, the fraction the filter ran (1: all)."""
        now = self._clock()
        while self._recent and now - self._recent[0][0] > RECENT_S:
            self._recent.popleft()
        given = sum(g for _, g, _ in self._recent)
        return 1.0 if not given else sum(r for _, _, r in self._recent) / given

    def reset(self) -> None:
        """Start the user's filter afresh (ResetFilter, a new stream)."""
        if self.estimator is not None:
            self.estimator.reset()
        self.latest = _NAN4.copy()
        self.reset_errors()

    def replace(self, estimator: UserFilterEstimator | None) -> None:
        """Run `estimator` from the next row on (None: nothing); ends a catch-up."""
        with self.lock:
            self._buffer = None
            self.buffered_rows = 0
            self._install(estimator)

    def _install(self, estimator: UserFilterEstimator | None) -> None:
        self.estimator = estimator
        self.latest = _NAN4.copy()
        self._budget = 0.0
        self._last_call = None

    # -- catching up (the background thread's side) --------------------------------------------

    def begin_catch_up(self) -> int:
        """From now on rows are only buffered, until :meth:`take_buffered` hands over; the
        current estimator leaves the lane (the catch-up owns its replacement). Returns the
        catch-up's token."""
        with self.lock:
            self._buffer = []
            self._token += 1
            self.buffered_rows = 0
            self.estimator = None
            self.latest = _NAN4.copy()
            self.reset_errors()
            return self._token

    def take_buffered(self, estimator: UserFilterEstimator,
                      token: int) -> list[tuple[np.ndarray, ...]] | None:
        """The rows buffered since the previous call; None when there were none: then
        `estimator` has taken over (atomically, so the next row goes to it). None too when the
        catch-up `token` was superseded."""
        with self.lock:
            if self._buffer is None or token != self._token:
                return None
            if self._buffer:
                rows, self._buffer = self._buffer, []
                return rows
            self._buffer = None
            self.buffered_rows = 0
            self._install(estimator)
            return None

    # -- the engine thread's side ---------------------------------------------------------------

    def run_rows(self, t_s: np.ndarray, gyr: np.ndarray, acc: np.ndarray,
                 mag: np.ndarray) -> np.ndarray:
        """The user's quaternion after each row (R, 4); NaN where there is none. The columns
        are the runner's with a switched-off sensor as NaN (app.engine.runner): the user's step
        gets None for it."""
        n = len(t_s)
        with self.lock:
            if self._buffer is not None:
                self._buffer.append((t_s.copy(), gyr.copy(), acc.copy(), mag.copy()))
                self.buffered_rows += n
                return np.full((n, 4), np.nan)
            estimator = self.estimator
        if estimator is None or estimator.paused or n == 0:
            self.latest = _NAN4.copy()
            return np.full((n, 4), np.nan)
        chosen = self._choose(n, estimator)
        started = self._clock()
        quats = run_chosen(estimator, chosen, t_s, gyr, acc, mag)
        if self.realtime:
            self._budget -= self._clock() - started
            self._recent.append((self._clock(), n, len(chosen)))
        self.rows_given += n
        self.rows_run += len(chosen)
        out = forward_fill(quats, chosen, n, self.latest)
        self.latest = out[-1].copy()
        return out

    def _choose(self, n: int, estimator: UserFilterEstimator) -> np.ndarray:
        """All rows offline; live, as many as the time budget allows, evenly spread, the last
        row always among them when any runs."""
        if not self.realtime:
            return np.arange(n)
        now = self._clock()
        elapsed = 0.02 if self._last_call is None else now - self._last_call
        self._last_call = now
        self._budget = min(self._budget + self.share * elapsed, MAX_BUDGET_S)
        cost = estimator.time_per_call_s
        if not cost > 0.0 or cost * n <= self._budget:
            return np.arange(n)
        k = max(0, min(n, int(self._budget / cost)))
        if k == 0:
            return np.empty(0, np.int64)
        return np.unique(np.floor(np.arange(1, k + 1) * (n / k)).astype(np.int64) - 1)

    def take_innovations(self) -> list[tuple]:
        """(t, sensor, nu, S, accepted) returned by the user's filter since the last call."""
        estimator = self.estimator
        if estimator is None or not estimator.innovations:
            return []
        records = []
        queue = estimator.innovations
        while queue:
            records.append(queue.popleft())
        return records


def run_chosen(estimator: UserFilterEstimator, chosen: np.ndarray, t_s: np.ndarray,
               gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray) -> np.ndarray:
    """Step the chosen rows; the quaternion after each (NaN once paused or before the first
    output)."""
    out = np.full((len(chosen), 4), np.nan)
    has = [~np.isnan(x[chosen]).any(axis=1) for x in (gyr, acc, mag)]
    for i, k in enumerate(chosen.tolist()):
        estimator.step(t_s[k], gyr[k] if has[0][i] else None, acc[k] if has[1][i] else None,
                       mag[k] if has[2][i] else None)
        if estimator.paused:
            break
        if estimator.initialised:
            out[i] = estimator.quat
    return out


def forward_fill(quats: np.ndarray, chosen: np.ndarray, n: int, before: np.ndarray) -> np.ndarray:
    """Rows not run show the latest row that was (or `before`)."""
    if len(chosen) == n:
        return quats
    source = np.searchsorted(chosen, np.arange(n), side="right") - 1
    out = np.empty((n, 4))
    out[source < 0] = before
    out[source >= 0] = quats[source[source >= 0]]
    return out
