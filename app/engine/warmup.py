"""Compile, or load from numba's on-disk cache, every kernel the engine uses.

With an empty cache (a first start after an install) the stream's kernels (the parser and the
time orderer) are compiled by a second process while this one compiles the EKF's, so the two
take the time of the longer one on a machine with two cores; this process then loads the
stream's kernels from the cache the other one wrote (or compiles them itself when it failed).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

from ekf import fast
from ekf.simulate import simulate
from app.engine.processing.runner import EstimatorRunner
from app.stream import fastparse, ordering
from app.stream.demo import write_session
from app.stream.logfile import read_log

_done = False
_HELPER_TIMEOUT_S = 300.0


def warm_up_stream() -> None:
    """The parser's and the time orderer's kernels."""
    fastparse.warm_up()
    ordering.warm_up()


def _cache_is_empty() -> bool:
    """No cache entry of the parser's kernel yet (a first start); False when unknown."""
    return fastparse.kernel_cached() is False


def _start_stream_helper() -> subprocess.Popen | None:
    """A process compiling the stream's kernels into the cache, or None when none can start."""
    if (os.cpu_count() or 1) < 2:
        return None
    root = str(Path(__file__).resolve().parents[2])       # where this copy of app is
    path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)
    try:
        return subprocess.Popen([sys.executable, "-c",
                                 "from app.engine.warmup import warm_up_stream; warm_up_stream()"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, env=dict(os.environ, PYTHONPATH=path))
    except OSError:
        return None


def _wait(helper: subprocess.Popen | None) -> None:
    if helper is None:
        return
    try:
        helper.wait(_HELPER_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        helper.kill()
        helper.wait()


def warm_up() -> None:
    """The EKF, the parser, the time orderer and the runner's own kernels, by running two seconds
    of a simulated phone through them (the first time about half a minute on two cores; from
    numba's cache about a second; once per process). `make run` and `make test` call it once
    after installing; the engine calls it before its first sample."""
    global _done
    if _done:
        return
    helper = _start_stream_helper() if _cache_is_empty() else None
    try:
        fast.warm_up()
    finally:
        _wait(helper)
    warm_up_stream()
    with tempfile.TemporaryDirectory() as directory:
        log = read_log(write_session(simulate(duration_s=2.0, seed=0), Path(directory) / "w.txt"))
    runner = EstimatorRunner(comparisons=True, collect_plot=True)
    runner.feed_arrays(log.t_ms, log.tag, log.values)
    runner.finish()
    runner.take_rows()
    _done = True


if __name__ == "__main__":   # python -m app.engine.warmup (the Makefile's set-up step)
    warm_up()
