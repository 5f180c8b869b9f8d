"""Cost of running a user's filter (a plug-in, `--filter FILE.py`) beside ours.

A trivial plug-in (``step`` returns a constant quaternion) measures what the plumbing costs per
sample; the course EKF written as a student would (``examples/course_ekf.py``) what a real
one costs. Each is timed at four depths:

* ``bare``:   ``Filter.step`` called in a Python loop (the user's code alone);
* ``adapter``: ``UserFilterEstimator.step`` (argument copies, timing, the output check);
* ``lane``:   the live engine's path, ``UserLane.run_rows`` on chunks of 64 rows;
* ``engine``: ``EstimatorRunner.feed_arrays`` with the lane minus without it (the runner's
              extra work per row: forward fill, errors against PHONE).

Rows are the distinct times of a simulated 500 Hz session (GYR and ACC at 500 Hz, MAG at
100 Hz). The target: a trivial plug-in keeps up with a 500 Hz stream with room to spare, i.e.
its samples/s are many times the stream's rows/s (its share of one core stays small).

    .venv/bin/python benchmarks/plugin.py [--seconds 60] [--repeats 5] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ekf.simulate import simulate  # noqa: E402
from app.engine.warmup import warm_up  # noqa: E402
from app.engine.runner import EstimatorRunner  # noqa: E402
from app.engine.userfilter.filter import UserFilterEstimator  # noqa: E402
from app.engine.userfilter.lane import UserLane  # noqa: E402
from app.stream.fastparse import samples_to_arrays  # noqa: E402
from app.stream.protocol import Sample  # noqa: E402

TRIVIAL = """
    class Filter:
        def step(self, t, gyr, acc, mag):
            return (1.0, 0.0, 0.0, 0.0)
"""
COURSE_EKF = REPO / "examples" / "course_ekf.py"
RATE_HZ = 500.0


def session(seconds: float):
    """The samples (filter-tag arrays) and the rows (t, gyr, acc, mag) of a 500 Hz session."""
    sim = simulate(duration_s=seconds, rates_hz={"gyr": RATE_HZ, "acc": RATE_HZ, "mag": 100.0,
                                                 "ori": 100.0}, seed=5)
    arrays = samples_to_arrays([Sample(t, tag, values) for t, tag, values in sim.iter_rows()])
    runner = EstimatorRunner("gyro")
    runner.feed_arrays(arrays.t_ms, arrays.tag, arrays.values)
    times = np.unique(arrays.t_ms[arrays.tag < 3])
    columns = []
    for code in range(3):
        column = np.full((len(times), 3), np.nan)
        chosen = arrays.tag == code
        column[np.searchsorted(times, arrays.t_ms[chosen])] = arrays.values[chosen, :3]
        columns.append(column)
    return arrays, times / 1000.0, columns


def best(run, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        run()
        times.append(time.perf_counter() - started)
    return min(times)


def measure(path: Path, arrays, t, columns, repeats: int) -> dict[str, float]:
    """Seconds per row at each depth (engine: the extra over the runner without the lane)."""
    gyr, acc, mag = columns
    n = len(t)
    has = [~np.isnan(c).any(axis=1) for c in columns]

    def bare() -> None:
        filt = UserFilterEstimator(path).filter
        for k in range(n):
            filt.step(t[k], gyr[k] if has[0][k] else None, acc[k] if has[1][k] else None,
                      mag[k] if has[2][k] else None)

    def adapter() -> None:
        UserFilterEstimator(path).run_batch(t, gyr, acc, mag)

    def lane() -> None:
        lane = UserLane(UserFilterEstimator(path))
        for start in range(0, n, 64):
            lane.run_rows(t[start:start + 64], gyr[start:start + 64], acc[start:start + 64],
                          mag[start:start + 64])

    def runner(with_lane: bool):
        def run() -> None:
            r = EstimatorRunner("ekf")
            if with_lane:
                r.set_user_lane(lanes.pop())
            for start in range(0, len(arrays.t_ms), 256):
                r.feed_arrays(arrays.t_ms[start:start + 256], arrays.tag[start:start + 256],
                              arrays.values[start:start + 256])
        return run

    out = {name: best(run, repeats) / n for name, run in
           (("bare", bare), ("adapter", adapter), ("lane", lane))}
    lanes = [UserLane(UserFilterEstimator(path)) for _ in range(repeats)]   # loaded untimed
    out["engine"] = (best(runner(True), repeats) - best(runner(False), repeats)) / n
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="session length (default 60)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="a smoke run: 3 s, 1 repeat")
    args = parser.parse_args()
    seconds, repeats = (3.0, 1) if args.quick else (args.seconds, args.repeats)
    warm_up()                      # the compiled kernels, before anything is timed
    arrays, t, columns = session(seconds)
    rows_per_s = len(t) / seconds
    with tempfile.TemporaryDirectory() as folder:
        trivial = Path(folder) / "trivial.py"
        trivial.write_text(textwrap.dedent(TRIVIAL))
        print(f"{len(t)} rows ({seconds:g} s of a {RATE_HZ:g} Hz stream: {rows_per_s:.0f} rows/s)"
              + (" [--quick: not a figure]" if args.quick else ""))
        print(f"{'plug-in':<16}{'depth':<9}{'us/row':>9}{'rows/s':>12}{'x the stream':>14}"
              f"{'core share':>12}")
        for label, path in (("trivial", trivial), ("course_ekf.py", COURSE_EKF)):
            for depth, per_row in measure(path, arrays, t, columns, repeats).items():
                rate = 1.0 / per_row if per_row > 0 else float("inf")
                print(f"{label:<16}{depth:<9}{per_row * 1e6:>9.2f}{rate:>12,.0f}"
                      f"{rate / rows_per_s:>13.0f}x{per_row * rows_per_s:>11.1%}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
