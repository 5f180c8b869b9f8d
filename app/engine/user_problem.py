"""Why your filter is paused, as plain data: what the snapshots show and what your filter's own
process reports (it imports this module and nothing else of the engine)."""

from __future__ import annotations

from dataclasses import dataclass


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
