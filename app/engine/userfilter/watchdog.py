"""A call into the user's code that does not come back (an endless loop in step, a ``while``
that never meets its condition) must not stop the stream: :func:`guard` marks a call, and a
watchdog thread raises :class:`UserCodeTimeout` inside the calling thread once the call has run
for ``limit_s`` (CPython's ``PyThreadState_SetAsyncExc``: the exception appears at the line the
user's code is on, so the problem names that file and line).

The exception is delivered at the thread's next bytecode boundary: an endless Python loop stops
within microseconds of the limit, a single long C call (a huge numpy operation, ``time.sleep``)
only when it returns. It derives from BaseException so a user's ``except Exception`` cannot
swallow it; a bare ``except:`` can, so the watchdog raises again every ``limit_s`` while the
call lasts. It is only raised while the marked call is in progress: the watchdog and the end of the call
take the same lock, and the end of the call drops an exception raised but not yet delivered, so
it is caught by the ``except UserCodeTimeout`` around the guarded call (which disarms the guard
again, in case it arrived while the call was ending) and never reaches the engine's code.
"""

from __future__ import annotations

import ctypes
import threading
import time

DEFAULT_LIMIT_S = 1.0        # a course filter's step takes well under a millisecond
_POLL_S = 0.05


class UserCodeTimeout(BaseException):
    """Raised inside the user's code when one call ran longer than the limit."""


class _Watchdog:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.calls: dict[int, list] = {}      # thread id -> [deadline, limit_s, what, raised]
        self._thread: threading.Thread | None = None
        self.fired = 0

    def start(self) -> None:
        """The watching thread, once (called with the lock held)."""
        if self._thread is None or not self._thread.is_alive():
            self._thread = threading.Thread(target=self._watch, name="user-code watchdog",
                                            daemon=True)
            self._thread.start()

    def _watch(self) -> None:
        while True:
            time.sleep(_POLL_S)
            now = time.monotonic()
            with self.lock:
                for ident, call in self.calls.items():
                    deadline, limit_s, what, _ = call
                    if now >= deadline:
                        call[0] = now + limit_s          # again later if it is swallowed
                        call[3] = True
                        self.fired += 1
                        message = (f"{what} ran for more than {limit_s:g} s and was stopped "
                                   "(an endless loop?)")
                        _raise_in(ident, message)


class Guard:
    """``with guard:`` around one call into the user's code (reusable, any thread; a plain
    class rather than a generator: it is entered once per sample). The handler that catches
    UserCodeTimeout calls :meth:`disarm` (the exception may have arrived before the end of the
    call was recorded)."""

    __slots__ = ("limit_s", "what")

    def __init__(self, limit_s: float, what: str) -> None:
        self.limit_s = float(limit_s)
        self.what = what

    def __enter__(self) -> None:
        if self.limit_s <= 0:
            return
        with _WATCHDOG.lock:
            _WATCHDOG.calls[threading.get_ident()] = [time.monotonic() + self.limit_s,
                                                      self.limit_s, self.what, False]
            _WATCHDOG.start()

    def __exit__(self, *exc) -> bool:
        self.disarm()
        return False

    def disarm(self) -> None:
        """The call is over: forget it and drop an exception raised for it but not yet
        delivered (under the watchdog's lock, so none can follow)."""
        if self.limit_s <= 0:
            return
        with _WATCHDOG.lock:
            ident = threading.get_ident()
            call = _WATCHDOG.calls.pop(ident, None)
            if call is not None and call[3]:        # raised for this call: not delivered twice
                ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(ident), None)


def _raise_in(ident: int, message: str) -> None:
    exception = type("UserCodeTimeout", (UserCodeTimeout,), {"__init__": _fixed_message(message)})
    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(ident), ctypes.py_object(exception))


def _fixed_message(message: str):
    # PyThreadState_SetAsyncExc takes a class and raises it without arguments: the message
    # comes with the class.
    def __init__(self, *args) -> None:   # noqa: N807
        UserCodeTimeout.__init__(self, *(args or (message,)))
    return __init__


_WATCHDOG = _Watchdog()


def guard(limit_s: float = DEFAULT_LIMIT_S, what: str = "your code") -> Guard:
    """A context manager: the user's code called inside it is stopped with UserCodeTimeout
    after limit_s seconds (a limit of 0 or less: not watched)."""
    return Guard(limit_s, what)


def times_fired() -> int:
    """How often the watchdog stopped a call (tests)."""
    return _WATCHDOG.fired
