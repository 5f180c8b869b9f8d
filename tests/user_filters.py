"""Helpers for the user-filter tests: write small filter files, and a synthetic phone log.

Each filter body is the source of a module defining class Filter; FILTERS holds the ones
several tests share.
"""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

FILTERS = {
    "flat": """
        class Filter:
            def step(self, t, gyr, acc, mag):
                return [1.0, 0.0, 0.0, 0.0]
    """,
    "turned": """
        import math
        class Filter:
            def step(self, t, gyr, acc, mag):
                return [math.cos(0.5), 0.0, 0.0, math.sin(0.5)]   # 57.3 deg about up
    """,
    "raises": """
        import numpy as np
        class Filter:
            calls = 0
            def step(self, t, gyr, acc, mag):
                Filter.calls += 1
                if t > 1.5:
                    return self.update(acc)
                return [1.0, 0.0, 0.0, 0.0]
            def update(self, acc):
                return np.ones(2) @ acc        # line 11: the shapes do not match
    """,
    "nan": """
        class Filter:
            def step(self, t, gyr, acc, mag):
                return {"q": [float("nan"), 0.0, 0.0, 0.0]} if t > 1.5 else [1.0, 0, 0, 0]
    """,
    "shape": """
        class Filter:
            def step(self, t, gyr, acc, mag):
                return [1.0, 0.0, 0.0]
    """,
    "nonunit": """
        class Filter:
            def step(self, t, gyr, acc, mag):
                return [1.2, 0.0, 0.0, 0.0]
    """,
    "endless": """
        class Filter:
            def step(self, t, gyr, acc, mag):
                if t > 1.5:
                    q = [1.0, 0.0, 0.0, 0.0]
                    while q[0] > 0:            # never false: an endless loop
                        q[0] = q[0] * 1.0
                return [1.0, 0.0, 0.0, 0.0]
    """,
    "slow": """
        import time
        class Filter:
            def step(self, t, gyr, acc, mag):
                time.sleep(0.003)          # slow on purpose: 3 ms a step
                return [1.0, 0.0, 0.0, 0.0]
    """,
}


def write_filter(folder: Path, name: str, body: str | None = None) -> Path:
    """FILTERS[name] (or `body`) as folder/name.py."""
    path = Path(folder) / f"{name}.py"
    path.write_text(textwrap.dedent(FILTERS[name] if body is None else body))
    return path


def save_again(path: Path, body: str) -> None:
    """Rewrite a filter file so that a watcher sees it saved (its mtime moves on even on a
    coarse-clocked file system)."""
    before = path.stat().st_mtime_ns
    path.write_text(textwrap.dedent(body))
    os.utime(path, ns=(before + 2_000_000_000, before + 2_000_000_000))


def log_lines(seconds: float, rate_hz: float = 100.0, t0: int = 1000,
              turn_rate: float = 0.5) -> list[bytes]:
    """A phone flat at rest for 1 s, then turning about up at turn_rate rad/s: GYR and ACC at
    rate_hz, MAG at half of it, ORI (identity) at rate_hz."""
    out = []
    period = 1000.0 / rate_hz
    for k in range(int(seconds * rate_hz)):
        t = t0 + int(round(k * period))
        rate = turn_rate if k > rate_hz else 0.0
        out += [f"{t}\tGYR\t0.0\t0.0\t{rate}\n".encode(), f"{t}\tACC\t0.0\t0.0\t9.81\n".encode(),
                f"{t}\tORI\t1.0\t0.0\t0.0\t0.0\n".encode()]
        if k % 2 == 0:
            out.append(f"{t}\tMAG\t0.0\t20.0\t-40.0\n".encode())
    return out
