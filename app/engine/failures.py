"""The engine's failures: an exception while processing a batch, as the window and `serve` show it.

A failure never ends the engine silently: it is logged with its traceback and published in the
snapshots (:class:`~app.engine.snapshot.EngineFailure`, which the window shows with a "copy
details" button and `serve` prints), and the engine goes on with the next batch; after
MAX_FAILURES failures within FAILURE_WINDOW_S it stops cleanly instead (source closed, state
"stopped", the reason published).
"""

from __future__ import annotations

import logging
import time
import traceback
from collections import deque
from datetime import datetime, timezone
from pathlib import Path

from app.engine.snapshot import EngineFailure

log = logging.getLogger("orientation_lab.engine")

MAX_FAILURES = 5               # this many failures within FAILURE_WINDOW_S stop the engine
FAILURE_WINDOW_S = 10.0


class FailureLog:
    """The latest failures (oldest first, at most 20), how many there were in all, and whether
    there were too many too fast to go on."""

    def __init__(self) -> None:
        self.items: deque[EngineFailure] = deque(maxlen=20)
        self.count = 0
        self._times: deque[float] = deque(maxlen=MAX_FAILURES)

    def record(self, error: BaseException) -> EngineFailure:
        """Log `error` and keep it; the failure is fatal when it is the MAX_FAILURES-th within
        FAILURE_WINDOW_S."""
        frames = traceback.extract_tb(error.__traceback__)
        where = ""
        if frames:
            last = frames[-1]
            where = f" ({Path(last.filename).name}, line {last.lineno}, in {last.name})"
        message = f"{type(error).__name__}: {error}{where}"
        details = "".join(traceback.format_exception(type(error), error, error.__traceback__))
        now = time.monotonic()
        self._times.append(now)
        fatal = len(self._times) == MAX_FAILURES and now - self._times[0] <= FAILURE_WINDOW_S
        self.count += 1
        failure = EngineFailure(self.count, message, details,
                                datetime.now(timezone.utc).isoformat(timespec="seconds"), fatal)
        self.items.append(failure)
        log.error("engine failure %d%s: %s\n%s", failure.number,
                  " (engine stopped)" if fatal else " (going on with the next batch)",
                  message, details)
        return failure
