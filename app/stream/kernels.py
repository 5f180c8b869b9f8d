"""The stream layer's compiled functions: their decorator, and the guard that keeps numba's
on-disk cache honest about the tag table.

numba caches each compiled function keyed on its own source file only and freezes module
globals as constants, so a kernel that reads the tag table's arrays or a layout made from them
(:mod:`app.stream.tags`) would keep stale code after the table changes. Every module of such
kernels compiles a tiny function returning :data:`~app.stream.tags.TABLE_KEY` and calls
:func:`check_cache` when imported: when the cached key differs, the module's cache entries are
flushed and it recompiles once.
"""

from __future__ import annotations

from typing import Any

from numba import njit
from numba.core.dispatcher import Dispatcher

from app.stream.tags import TABLE_KEY

jit = njit(cache=True, nogil=True)


def check_cache(compiled_key: Dispatcher, module_globals: dict[str, Any]) -> None:
    """Flush the cached compilations of the module whose globals are given when they were built
    against another tag table (`compiled_key` returns the key frozen at its compilation)."""
    if compiled_key() == TABLE_KEY:
        return
    module = module_globals["__name__"]
    for value in module_globals.values():
        if isinstance(value, Dispatcher) and value.py_func.__module__ == module:
            value._cache.flush()
    compiled_key.recompile()
