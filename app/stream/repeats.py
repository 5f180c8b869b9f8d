"""Samples repeated exactly: a line the phone (or a copy of a log) wrote twice.

A repeat is a sample with the same time, tag and values as one released before it (release
times never go back, so only the samples of the latest time need remembering); the estimators
use it once (the runner drops it) and the log's summary counts it. A sample at the
same time with other values is not a repeat: both are used, as the phone sent them.
"""

from __future__ import annotations

import numpy as np

# the samples of the previous chunk's last time: (t_ms, tag, values)
Last = tuple[np.ndarray, np.ndarray, np.ndarray] | None


def _same_values(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return ((a == b) | (np.isnan(a) & np.isnan(b))).all(axis=-1)


def repeats(t_ms: np.ndarray, tag: np.ndarray, values: np.ndarray,
            last: Last) -> tuple[np.ndarray, Last]:
    """(mask of the samples that repeat an earlier one, what to carry into the next chunk).
    t_ms, tag (n,), values (n, 4) in release order (times never going back); last: what the
    previous chunk returned (None at the start)."""
    n = len(t_ms)
    if n == 0:
        return np.zeros(0, bool), last
    t = np.asarray(t_ms, np.int64)
    g = np.asarray(tag, np.int64)
    v = np.asarray(values, np.float64).reshape(n, -1)
    carried = 0
    if last is not None and len(last[0]) and last[0][-1] == t[0]:
        carried = len(last[0])
        t, g, v = (np.concatenate([last[0], t]), np.concatenate([last[1], g]),
                   np.concatenate([last[2], v]))
    mask = np.zeros(len(t), bool)
    lag = 1
    while lag < len(t):
        same_time = t[lag:] == t[:-lag]
        if not same_time.any():
            break
        mask[lag:] |= same_time & (g[lag:] == g[:-lag]) & _same_values(v[lag:], v[:-lag])
        lag += 1
    group = len(t) - 1
    while group > 0 and t[group - 1] == t[-1]:
        group -= 1
    return mask[carried:], (t[group:].copy(), g[group:].copy(), v[group:].copy())
