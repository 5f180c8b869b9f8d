"""The compiled filter's decorator, and the guard that keeps numba's on-disk cache honest.

numba caches each compiled function keyed on its own source file only, and freezes module
globals (the layouts ``S`` and ``C``, the gate codes, the reference's constants) as constants.
A kernel that calls a function of another kernel module, or reads a layout generated from the
declarations in ``ekf/state.py``, ``ekf/settings.py`` and ``ekf/diagnostics.py``, would keep
stale code from the cache after those change (numba issue #1833). So every kernel module
compiles a tiny function returning a key (for the filter :data:`CACHE_KEY`: a hash of the
layouts, the gate codes, the compile options, the reference's constants and the source of every
kernel module) and calls :func:`check_cache` with the key when imported: when the cached key
differs, the module's cache entries are flushed and it recompiles once. :func:`check_cache` is
the guard of every numba kernel of the program (the stream layer's kernels pass their own key).
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

from numba import njit
from numba.core.dispatcher import Dispatcher

import ekf.diagnostics as diagnostics
from ekf.fast.layout import describe

# The kernels allocate nothing and only index the arrays they are handed, so numba's reference
# counting of those arrays is switched off (`_nrt=False`, an option of numba's own, see
# numba#2350): it cost an atomic increment and decrement per array at every call level that
# the refcount pruning pass cannot remove in branching code, more than half the time per
# sample (BROAD trial 01, default preset: 408 -> 174 ns per row, the same estimates bit for bit).
_OPTIONS = dict(cache=True, fastmath=False, nogil=True, _nrt=False)
# No numba-level inlining (inline="always"): it copies a callee's IR into every caller before
# typing, so each kernel was typed and optimised once per call site, which made the first
# compile of the engine's kernels twice as long. LLVM still inlines the small helpers, and the
# n-specialised bodies, called with n = 4 or 7 as a literal, are still compiled once for each n
# so that the fixed loops unroll (docs/decisions/compile-time.md).
jit = njit(**_OPTIONS)

KERNEL_MODULES = ("algebra", "kernels", "filter")
"""The modules of ekf.fast that hold compiled functions (file stems)."""


def _cache_key() -> int:
    h = hashlib.sha256(describe().encode())
    codes = sorted((k, v) for k, v in vars(diagnostics).items() if k.isupper() and isinstance(v, int))
    h.update(repr(codes).encode())
    here = Path(__file__).resolve().parent
    for stem in KERNEL_MODULES + ("jit",):   # jit: the compile options
        h.update((here / f"{stem}.py").read_bytes())
    h.update((here.parent / "reference.py").read_bytes())   # constants the kernels import
    return int.from_bytes(h.digest()[:7], "little")   # < 2**56: an int64 constant


CACHE_KEY = _cache_key()


def check_cache(compiled_key: Dispatcher, module_globals: dict[str, Any], key: int) -> None:
    """Flush the cached compilations of the module whose globals are given when they were built
    against something else than `key` describes (`compiled_key` returns the key frozen at its
    compilation)."""
    if compiled_key() == key:
        return
    module = module_globals["__name__"]
    for value in module_globals.values():
        if isinstance(value, Dispatcher) and value.py_func.__module__ == module:
            value._cache.flush()
    compiled_key.recompile()
