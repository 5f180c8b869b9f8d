"""Compile, or load from numba's on-disk cache, every kernel the engine uses."""

from __future__ import annotations

import tempfile
from pathlib import Path

from ekf import fast
from ekf.simulate import simulate
from app.engine.runner import EstimatorRunner
from app.stream import fastparse, ordering
from app.stream.demo import write_session
from app.stream.logfile import read_log


_done = False


def warm_up() -> None:
    """The EKF, the parser, the time orderer and the runner's own kernels, by running two seconds
    of a simulated phone through them (the first time about a minute on two cores; from numba's
    cache about a second; once per process). `make run` and `make test` call it once after
    installing; the engine calls it before its first sample."""
    global _done
    if _done:
        return
    fast.warm_up()
    fastparse.warm_up()
    ordering.warm_up()
    with tempfile.TemporaryDirectory() as directory:
        log = read_log(write_session(simulate(duration_s=2.0, seed=0), Path(directory) / "w.txt"))
    runner = EstimatorRunner(comparisons=True, collect_plot=True)
    runner.feed_many(log.samples)
    runner.finish()
    runner.take_rows()
    _done = True


if __name__ == "__main__":   # python -m app.engine.warmup (the Makefile's set-up step)
    warm_up()
