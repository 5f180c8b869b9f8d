"""The engine's problems as plain data: what the user asked for that cannot be done, why your
filter is paused, and an exception while processing a batch.

* :class:`ConfigError`: the engine's one error for "what the user asked for cannot be done" (a
  one-line message; the command line prints it and exits with status 2, the window shows it).
* :class:`UserProblem`: why your filter is paused, as the snapshots show it and as your filter's
  own process reports it (that process imports this module and nothing else of the engine, so it
  imports only the standard library).
* :class:`EngineFailure` and :class:`FailureLog`: an exception while processing a batch never
  ends the engine silently: it is logged with its traceback and published in the snapshots
  (the window shows it with a "copy details" button, `serve` prints it), and the engine goes on
  with the next batch; after MAX_FAILURES failures within FAILURE_WINDOW_S it stops cleanly
  instead (source closed, state "stopped", the reason published).
"""

from __future__ import annotations

import logging
import time
import traceback
from collections import deque
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path



class ConfigError(Exception):
    """Something the user asked for cannot be done: a one-line message, no traceback."""


@dataclass(frozen=True)
class EngineFailure:
    """An exception inside the engine: what the window shows and `serve` prints.

    number counts failures from 1; message is one line with the exception and where it was
    raised (file, line, function); details the whole traceback (the "copy details" text);
    when the UTC time; fatal: the engine stopped after it (too many failures in a row)."""

    number: int
    message: str
    details: str
    when: str
    fatal: bool = False


@dataclass(frozen=True)
class UserProblem:
    """Why your filter is paused: an exception in your code, a return value that breaks the
    contract, a file that does not load, a call that does not return, or its process ended.

    kind: "load" | "exception" | "output" | "stuck" | "ended"; message: one line with your file,
    line and what went wrong ("my_filter.py:42 in mu_g: ValueError: ..."); details: the
    traceback of your code (the "show details" text) or the full explanation; t_s: the phone time
    of the sample [s]."""

    kind: str
    message: str
    details: str = ""
    file: str | None = None
    line: int | None = None
    function: str | None = None
    t_s: float | None = None


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
