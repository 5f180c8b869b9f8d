"""Your filter beside the main estimator, live: the runner hands every chunk's rows to a
:class:`UserLane`, which hands them to your filter's process (app.engine.userfilter.remote) and
takes its results when they are there. The engine never waits for your filter: YOURS lags OWN
by the time the process takes (:attr:`UserLane.lag_s`).

Everything the runner hands over goes into one queue in order: rows (with their phone times),
PHONE's samples, a restart of your filter, the end of a stream. The queue is worked through up
to the first rows whose results have not come back, so YOURS' rows, its errors against PHONE (at
PHONE's times, as OWN's) and its restarts happen in the order the engine saw them, only later.
Rows are sent with which sensors each row gives your filter (``given``: a sample there; the
runner hands the rows with the sensors switched off in OWN left out, app.engine.processing.runner),
so a switch takes effect at exactly its row, wherever it comes from (the configuration over time).

Never holding up the engine: with ``realtime`` (the live engine) at most LAG_BUDGET_S of your
filter's work (its process's time per row times the rows) is handed over and not yet answered;
a filter slower than the stream gets only some rows, evenly spread (decimated), the rows not run
show the latest row that was, and the lane reports it (:meth:`UserLane.used_fraction`). Offline every row
is run.

Catching up (after a reload or a seek): the engine thread keeps handing rows over, the lane
only buffers them, and a background thread runs first the log up to now and then the buffer
through the filter; when the buffer is empty the filter takes over, under the lane's lock, so
no row is run twice or skipped (see :mod:`app.engine.userfilter.host`).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable

import numpy as np

from app.engine.processing.compare import ErrorRows, ErrorSums, SameInstant
from app.engine.userfilter.remote import BlockResult, RemoteFilter

LAG_BUDGET_S = 0.1          # of your filter's work handed over and not answered yet (live)
FIRST_ROWS = 2000           # ... before its time per call is known
RECENT_S = 2.0              # used_fraction and the lag look back this far [s, wall clock]
LAG_PERCENTILE = 95
MAX_INNOVATIONS = 50_000
_NAN4 = np.full(4, np.nan)


@dataclass
class _Rows:
    """Rows handed over: their times and the indices sent (block None: none sent; nan: the
    filter had none to give, paused or catching up)."""

    t_ms: np.ndarray
    chosen: np.ndarray
    block: int | None
    nan: bool
    result: BlockResult | None = None


@dataclass
class _Phone:
    t_ms: np.ndarray
    quat: np.ndarray


@dataclass
class _Mark:
    kind: str                   # "reset": the filter restarts here; "finish": a stream ended


class UserLane:
    """Runs your filter's process on the runner's rows (see the module docstring)."""

    def __init__(self, remote: RemoteFilter | None = None, realtime: bool = False,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.lock = threading.RLock()     # the engine's thread and a catch-up's
        self.remote = remote
        self.realtime = realtime
        self._clock = clock
        self._queue: deque[_Rows | _Phone | _Mark] = deque()
        self._buffer: list[tuple[np.ndarray, ...]] | None = None
        self._token = 0                  # of the current catch-up
        self.buffered_rows = 0
        self.latest = _NAN4.copy()        # YOURS at the latest row worked through
        self.output_q: np.ndarray | None = None    # the latest output (kept while paused)
        self.lights: tuple[bool | None, bool | None, bool | None] = (None, None, None)
        self.cov: np.ndarray | None = None
        self.rows_given = 0
        self.rows_run = 0
        self._recent: deque[tuple[float, int, int]] = deque()   # (wall time, given, sent)
        self._lags: deque[tuple[float, float]] = deque()        # (wall time, lag [s])
        self.innovations: deque[tuple] = deque(maxlen=MAX_INNOVATIONS)
        self._held: tuple[int, np.ndarray] | None = None
        self._results: list[tuple[np.ndarray, np.ndarray]] = []
        self._errors: list[ErrorRows] = []
        self.reset_errors()

    # -- errors against PHONE (at PHONE's times, as OWN's) ---------------------------------------

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

    def _trim(self, queue: deque) -> None:
        now = self._clock()
        while queue and now - queue[0][0] > RECENT_S:
            queue.popleft()

    def used_fraction(self) -> float:
        """Of the rows given in the last RECENT_S, the fraction handed to the filter (1: all)."""
        self._trim(self._recent)
        given = sum(g for _, g, _ in self._recent)
        return 1.0 if not given else sum(r for _, _, r in self._recent) / given

    @property
    def lag_s(self) -> float:
        """How long YOURS' results took to come back in the last RECENT_S: the 95th percentile
        [s] (NaN: none came back)."""
        self._trim(self._lags)
        if not self._lags:
            return math.nan
        return float(np.percentile([lag for _, lag in self._lags], LAG_PERCENTILE))

    @property
    def backlog_rows(self) -> int:
        """Rows handed to the process and not answered yet."""
        return 0 if self.remote is None else self.remote.in_flight_rows

    def reset(self) -> None:
        """Start your filter afresh from the next rows (ResetFilter, a new stream)."""
        with self.lock:
            if self.remote is not None:
                self.remote.reset()
            self._queue.append(_Mark("reset"))
            self._work()

    def set_settings(self, settings) -> None:
        """New settings: your filter restarts with them from the next rows (its constructor is
        where it reads them)."""
        with self.lock:
            if self.remote is not None:
                self.remote.reset(settings)
            self._queue.append(_Mark("reset"))
            self._work()

    def finish(self) -> None:
        """A stream ended: its last row shows once its result is there."""
        with self.lock:
            self._queue.append(_Mark("finish"))
            self._work()

    def replace(self, remote: RemoteFilter | None) -> None:
        """Run `remote` from the next row on (None: nothing); ends a catch-up. What was handed
        to the previous one gives no results."""
        with self.lock:
            self._buffer = None
            self.buffered_rows = 0
            self._install(remote)

    def _install(self, remote: RemoteFilter | None) -> None:
        self._emit_held()
        self.remote = remote
        self._queue = deque(item for item in self._queue if isinstance(item, _Phone))
        self.latest = _NAN4.copy()
        self.output_q = None
        self.lights, self.cov = (None, None, None), None

    # -- catching up (the background thread's side) --------------------------------------------

    def begin_catch_up(self) -> int:
        """From now on rows are only buffered, until :meth:`take_buffered` hands over; the
        current process leaves the lane (the catch-up owns its replacement). Returns the
        catch-up's token."""
        with self.lock:
            self._buffer = []
            self._token += 1
            self.buffered_rows = 0
            self._install(None)
            self._held = None
            self._results = []
            self._errors = []
            self.reset_errors()
            return self._token

    def take_buffered(self, remote: RemoteFilter, token: int,
                      latest: tuple | None = None) -> list[tuple[np.ndarray, ...]] | None:
        """The rows buffered since the previous call; None when there were none: then `remote`
        has taken over (atomically, so the next row goes to it), its latest output (q, lights,
        P) `latest`. None too when the catch-up `token` was superseded."""
        with self.lock:
            if self._buffer is None or token != self._token:
                return None
            if self._buffer:
                rows, self._buffer = self._buffer, []
                return rows
            self._buffer = None
            self.buffered_rows = 0
            self._install(remote)
            if latest is not None and latest[0] is not None:
                self.output_q = np.array(latest[0], float)
                self.lights = tuple(latest[1])
                self.cov = None if latest[2] is None else np.array(latest[2], float)
            return None

    # -- the engine thread's side ---------------------------------------------------------------

    def give(self, t_ms: np.ndarray, t_s: np.ndarray, gyr: np.ndarray, acc: np.ndarray,
             mag: np.ndarray) -> None:
        """Rows to your filter (t_ms (R,) their phone times, t_s in seconds, the sensors (R, 3),
        NaN: no such sample). Never waits."""
        with self.lock:
            self._give(np.array(t_ms, np.int64), t_s, gyr, acc, mag)

    def _give(self, t_ms: np.ndarray, t_s: np.ndarray, gyr: np.ndarray, acc: np.ndarray,
              mag: np.ndarray) -> None:
        self.collect()
        n = len(t_ms)
        if n == 0:
            return
        if self._buffer is not None:
            self._buffer.append((t_s.copy(), gyr.copy(), acc.copy(), mag.copy()))
            self.buffered_rows += n
            self._queue.append(_Rows(t_ms, np.empty(0, np.int64), None, True))
            self._work()
            return
        remote = self.remote
        if remote is None or not remote.usable or remote.paused:
            self._queue.append(_Rows(t_ms, np.empty(0, np.int64), None, True))
            self._work()
            return
        given = np.stack([~np.isnan(x).any(axis=1) for x in (gyr, acc, mag)], axis=1)
        chosen = self._choose(n, remote)
        block = None
        if len(chosen):
            values = np.concatenate([gyr[chosen], acc[chosen], mag[chosen]], axis=1)
            block = remote.send_rows(t_s[chosen], given[chosen], values)
        self.rows_given += n
        self.rows_run += len(chosen) if block is not None else 0
        if self.realtime:
            self._recent.append((self._clock(), n, len(chosen) if block is not None else 0))
        self._queue.append(_Rows(t_ms, chosen if block is not None else np.empty(0, np.int64),
                                 block, block is None and len(chosen) > 0))
        self._work()

    def add_phone(self, t_ms: np.ndarray, quat: np.ndarray) -> None:
        """PHONE's samples, for YOURS' errors at their times."""
        with self.lock:
            self._queue.append(_Phone(np.array(t_ms, np.int64), np.array(quat, float)))
            self._work()

    def _choose(self, n: int, remote: RemoteFilter) -> np.ndarray:
        """All rows offline; live, as many as LAG_BUDGET_S of the filter's work (its process's
        time per row) allows beside what it has not answered yet, evenly spread, the last row
        always among them when any is sent."""
        if not self.realtime:
            return np.arange(n)
        cost = remote.cost_per_row_s
        allowed = FIRST_ROWS if not cost > 0.0 else max(1, int(LAG_BUDGET_S / cost))
        k = min(n, allowed - remote.in_flight_rows)
        if k >= n:
            return np.arange(n)
        if k <= 0:
            return np.empty(0, np.int64)
        return np.unique(np.floor(np.arange(1, k + 1) * (n / k)).astype(np.int64) - 1)

    def collect(self) -> bool:
        """Take the results that came back (never waits); True when there were any."""
        with self.lock:
            return self._collect()

    def _collect(self) -> bool:
        remote = self.remote
        if remote is None:
            return False
        results = remote.poll()
        if results:
            blocks = {item.block: item for item in self._queue
                      if isinstance(item, _Rows) and item.block is not None}
            now = self._clock()
            for result in results:
                item = blocks.get(result.id)
                if item is not None:
                    item.result = result
                self._took(result, now)
        self._work()
        return bool(results)

    def _took(self, result: BlockResult, now: float) -> None:
        self._lags.append((now, result.lag_s))
        last = result.q[-1] if len(result.q) else None
        if last is not None and np.isfinite(last).all():
            self.output_q = last.copy()
            self.lights = tuple(None if v < 0 else bool(v) for v in result.flags[-1])
            self.cov = None if result.P is None else result.P.copy()
        self.innovations.extend(result.innovations)

    def _work(self) -> None:
        """Work through the queue up to the first rows whose results are still to come."""
        remote = self.remote
        lost = remote is None or not remote.usable
        queue = self._queue
        while queue:
            item = queue[0]
            if isinstance(item, _Rows):
                if (item.block is not None and item.result is None and not lost
                        and remote.awaiting(item.block)):
                    return
                self._rows(item)
            elif isinstance(item, _Phone):
                self.same_instant.add_phone(item.t_ms, item.quat)
            elif item.kind == "reset":
                self._emit_held()
                self.latest = _NAN4.copy()
                self.reset_errors()
            else:
                self._emit_held()
            queue.popleft()

    def _rows(self, item: _Rows) -> None:
        n = len(item.t_ms)
        if item.nan:
            out = np.full((n, 4), np.nan)
        else:
            quats = np.full((len(item.chosen), 4), np.nan)
            result = item.result
            if result is not None:
                quats = result.q.copy()
                if result.paused_at >= 0:
                    quats[result.paused_at:] = np.nan
            out = forward_fill(quats, item.chosen, n, self.latest)
        self.latest = out[-1].copy()
        self._emit(item.t_ms, out)

    def _emit(self, t_ms: np.ndarray, quats: np.ndarray) -> None:
        """Rows of YOURS in order; of rows at the same time the last one counts (a time whose
        samples came in two chunks), so the latest row is held until a later time comes."""
        if self._held is not None:
            t_ms = np.concatenate(([self._held[0]], t_ms))
            quats = np.concatenate([self._held[1][None], quats])
        keep = np.append(t_ms[:-1] != t_ms[1:], False)
        self._held = (int(t_ms[-1]), quats[-1].copy())
        if keep.any():
            self._add(t_ms[keep], quats[keep])

    def _emit_held(self) -> None:
        if self._held is not None:
            t, q = self._held
            self._held = None
            self._add(np.array([t], np.int64), q[None])

    def _add(self, t_ms: np.ndarray, quats: np.ndarray) -> None:
        self._results.append((t_ms, quats))
        finite = np.isfinite(quats).all(axis=1)     # NaN: your filter has no estimate there
        errors = self.same_instant.add_estimates(t_ms[finite], quats[finite])
        self.errors.add(errors)
        if len(errors):
            self._errors.append(errors)

    # -- what the engine takes -----------------------------------------------------------------

    def take_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """YOURS' rows worked through since the previous call: t_ms (N,), quat (N, 4) (NaN
        where it has none)."""
        with self.lock:
            results, self._results = self._results, []
        if not results:
            return np.empty(0, np.int64), np.empty((0, 4))
        return (np.concatenate([t for t, _ in results]),
                np.concatenate([q for _, q in results]))

    def take_errors(self) -> ErrorRows:
        """YOURS' errors against PHONE resolved since the previous call."""
        with self.lock:
            errors, self._errors = self._errors, []
        if not errors:
            return ErrorRows.empty()
        return ErrorRows(np.concatenate([e.t_ms for e in errors]),
                         np.concatenate([e.error_deg for e in errors]))

    def take_innovations(self) -> list[tuple]:
        """(t, sensor, nu, S, accepted) returned by your filter since the previous call."""
        with self.lock:
            records = list(self.innovations)
            self.innovations.clear()
        return records


def forward_fill(quats: np.ndarray, chosen: np.ndarray, n: int, before: np.ndarray) -> np.ndarray:
    """Rows not run show the latest row that was (or `before`)."""
    if len(chosen) == n:
        return quats
    source = np.searchsorted(chosen, np.arange(n), side="right") - 1
    out = np.empty((n, 4))
    out[source < 0] = before
    out[source >= 0] = quats[source[source >= 0]]
    return out
