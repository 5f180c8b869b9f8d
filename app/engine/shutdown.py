"""Ending the process on SIGTERM and SIGHUP as on Ctrl-C: a recording is finished, not cut.

SIGTERM (`kill`, a service manager) and SIGHUP (the terminal that started the program was
closed) end a process at once by default: raw.txt keeps what was flushed, session.json is never
finalised. `serve` and the window call :func:`on_finishing_signals` so that these signals ask
them to stop instead; they then stop the engine, which closes the recording (raw.txt flushed,
session.json with its stop time and counts, estimates.csv to the last row).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable

FINISHING_SIGNALS = ("SIGTERM", "SIGHUP")


def on_finishing_signals(handler: Callable[[], None]) -> Callable[[], None]:
    """From now on SIGTERM and SIGHUP call handler() (in the main thread, between two Python
    steps) instead of ending the process. A signal the process ignores stays ignored (SIGHUP
    under `nohup`); a platform without it (SIGHUP on Windows) is skipped; outside the main
    thread nothing changes. Returns the function that puts the previous handlers back."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = {}
    for name in FINISHING_SIGNALS:
        number = getattr(signal, name, None)
        if number is None or signal.getsignal(number) == signal.SIG_IGN:
            continue
        previous[number] = signal.signal(number, lambda *_: handler())

    def restore() -> None:
        for number, old in previous.items():
            signal.signal(number, old)
    return restore
