"""Cost of running a user's filter (a plug-in, `--filter FILE.py`) beside ours, in its own process,
and how far YOURS lags OWN live.

A trivial plug-in (``step`` returns a constant quaternion) measures what the plumbing costs per
row; the course EKF written as a student would (``examples/course_ekf.py``) what a real one
costs. Throughput, at four depths:

* ``bare``:     ``Filter.step`` called in a Python loop (the user's code alone, this process);
* ``instance``: ``FilterInstance.run_block`` in this process: what the filter's process does per
                row (argument copies, timing, the output check, innovations);
* ``process``:  ``UserFilterEstimator.run_batch``: every row through the pipes to the filter's
                process and back (`filter`, `evaluate`, Tune's re-runs), blocks of 4096 rows;
* ``engine``:   the engine thread's own CPU time per row for YOURS: ``EstimatorRunner.feed_arrays``
                with the lane minus without it (handing rows over, taking results, errors
                against PHONE), chunks of 256 samples.

Rows are the distinct times of a simulated 500 Hz session (GYR and ACC at 500 Hz, MAG at
100 Hz).

Lag, live: the engine (a TCP source) gets a simulated phone streaming 100 Hz per sensor (GYR,
ACC, MAG, ORI) in real time for --live-seconds; this process polls snapshots like the window
does and notes when each row's time first appears in OWN's plot samples and in YOURS'. YOURS'
lag behind OWN per row: p50, p95, max [ms] (target: p95 <= 100 ms for the course EKF). The
phone emulator runs in this process too.

    .venv/bin/python benchmarks/plugin.py [--seconds 60] [--repeats 5] [--live-seconds 30]
    .venv/bin/python benchmarks/plugin.py --quick
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import textwrap
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ekf.simulate import simulate  # noqa: E402
from app.engine.warmup import warm_up  # noqa: E402
from app.engine.processing.runner import EstimatorRunner  # noqa: E402
from app.engine.userfilter.code import instantiate, load_code  # noqa: E402
from app.engine.userfilter.filter import UserFilterEstimator  # noqa: E402
from app.engine.userfilter.instance import FilterInstance  # noqa: E402
from app.engine.userfilter.lane import UserLane  # noqa: E402
from app.engine.userfilter.remote import RemoteFilter, filter_settings  # noqa: E402
from app.engine.live.worker import Engine  # noqa: E402
from app.stream.emulator import PhoneEmulator  # noqa: E402
from app.stream.fastparse import samples_to_arrays  # noqa: E402
from app.stream.protocol import Sample, format_line  # noqa: E402
from app.stream.sources import TcpSource  # noqa: E402
import ekf  # noqa: E402

TRIVIAL = """
    class Filter:
        def step(self, t, gyr, acc, mag):
            return (1.0, 0.0, 0.0, 0.0)
"""
COURSE_EKF = REPO / "examples" / "course_ekf.py"
RATE_HZ = 500.0
LIVE_RATES = {"gyr": 100.0, "acc": 100.0, "mag": 100.0, "ori": 100.0}


def session(seconds: float):
    """The samples (filter-tag arrays) and the rows (t, gyr, acc, mag) of a 500 Hz session."""
    sim = simulate(duration_s=seconds, rates_hz={"gyr": RATE_HZ, "acc": RATE_HZ, "mag": 100.0,
                                                 "ori": 100.0}, seed=5)
    arrays = samples_to_arrays([Sample(t, tag, values) for t, tag, values in sim.iter_rows()])
    times = np.unique(arrays.t_ms[arrays.tag < 3])
    columns = []
    for code in range(3):
        column = np.full((len(times), 3), np.nan)
        chosen = arrays.tag == code
        column[np.searchsorted(times, arrays.t_ms[chosen])] = arrays.values[chosen, :3]
        columns.append(column)
    return arrays, times / 1000.0, columns


def best(run, repeats: int, clock=time.perf_counter) -> float:
    times = []
    for _ in range(repeats):
        started = clock()
        run()
        times.append(clock() - started)
    return min(times)


def measure(path: Path, arrays, t, columns, repeats: int) -> dict[str, float]:
    """Seconds per row at each depth (engine: the engine thread's extra CPU time)."""
    gyr, acc, mag = columns
    n = len(t)
    has = [~np.isnan(c).any(axis=1) for c in columns]
    settings = filter_settings(ekf.PRESETS["default"])
    code = load_code(path)

    def bare() -> None:
        filt = instantiate(code, settings)
        for k in range(n):
            filt.step(t[k], gyr[k] if has[0][k] else None, acc[k] if has[1][k] else None,
                      mag[k] if has[2][k] else None)

    given = np.stack(has, axis=1)
    values = np.concatenate([np.nan_to_num(c) for c in columns], axis=1)

    def instance() -> None:
        FilterInstance(code, settings).run_block(t, given, values)

    estimators = [UserFilterEstimator(path) for _ in range(repeats)]    # started untimed

    def process() -> None:
        estimators.pop().run_batch(t, gyr, acc, mag)

    out = {name: best(run, repeats) / n for name, run in
           (("bare", bare), ("instance", instance), ("process", process))}

    def runner(with_lane: bool):
        def run() -> None:
            r = EstimatorRunner("ekf")
            lane = None
            if with_lane:
                lane = UserLane(remotes.pop(), realtime=False)
                r.set_user_lane(lane)
            for start in range(0, len(arrays.t_ms), 256):
                r.feed_arrays(arrays.t_ms[start:start + 256], arrays.tag[start:start + 256],
                              arrays.values[start:start + 256])
            r.finish()
            while lane is not None and lane.backlog_rows:      # every result taken
                lane.remote.wait(0.05)
                lane.collect()
        return run

    remotes = [RemoteFilter.load(path, ekf.PRESETS["default"]) for _ in range(repeats)]
    out["engine"] = (best(runner(True), repeats, time.thread_time)
                     - best(runner(False), repeats, time.thread_time)) / n
    for remote in remotes:
        remote.close()
    return out


def live_lag(path: Path, seconds: float) -> dict[str, float]:
    """YOURS' lag behind OWN per row [s] while a phone streams in real time (module docstring)."""
    sim = simulate(duration_s=seconds, rates_hz=LIVE_RATES, seed=7)
    lines = [(format_line(Sample(t, tag, values)) + "\n").encode("ascii")
             for t, tag, values in sim.iter_rows()]
    own: dict[float, float] = {}
    yours: dict[float, float] = {}
    engine = Engine(TcpSource("127.0.0.1", 0), comparisons=False, index=False,
                    user_filter=path)
    with engine:
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:             # the file loaded, the kernels ready
            status = engine.snapshot_now().user
            if status is not None and status.state == "running" and not engine.preparing:
                break
            time.sleep(0.05)
        done = threading.Event()
        with PhoneEmulator("127.0.0.1", engine.source.port) as phone:
            sender = threading.Thread(target=lambda: (phone.stream_lines(lines, 1.0),
                                                      done.set()), daemon=True)
            sender.start()
            quiet_since = None
            while True:
                snapshot = engine.poll()
                now = time.perf_counter()
                if snapshot is not None:
                    for t in snapshot.plot.t_est.tolist():
                        own.setdefault(t, now)
                    for t in snapshot.plot.t_user.tolist():
                        yours.setdefault(t, now)
                if done.is_set():
                    quiet_since = quiet_since or now
                    if now - quiet_since > 1.0:
                        break
                time.sleep(0.002)
            sender.join()
    lags = np.array([yours[t] - own[t] for t in own if t in yours])
    return {"rows": len(own), "answered": len(lags), "p50": float(np.percentile(lags, 50)),
            "p95": float(np.percentile(lags, 95)), "max": float(lags.max())}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="session length (default 60)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--live-seconds", type=float, default=30.0,
                        help="live streaming for the lag (default 30)")
    parser.add_argument("--quick", action="store_true", help="a smoke run: 3 s, 1 repeat")
    args = parser.parse_args()
    seconds, repeats, live = (3.0, 1, 3.0) if args.quick else (args.seconds, args.repeats,
                                                                args.live_seconds)
    warm_up()                      # the compiled kernels, before anything is timed
    arrays, t, columns = session(seconds)
    rows_per_s = len(t) / seconds
    with tempfile.TemporaryDirectory() as folder:
        trivial = Path(folder) / "trivial.py"
        trivial.write_text(textwrap.dedent(TRIVIAL))
        print(f"{len(t)} rows ({seconds:g} s of a {RATE_HZ:g} Hz stream: {rows_per_s:.0f} rows/s)"
              + (" [--quick: not a figure]" if args.quick else ""))
        print(f"{'plug-in':<16}{'depth':<10}{'us/row':>9}{'rows/s':>12}{'x the stream':>14}"
              f"{'core share':>12}")
        for label, path in (("trivial", trivial), ("course_ekf.py", COURSE_EKF)):
            for depth, per_row in measure(path, arrays, t, columns, repeats).items():
                rate = 1.0 / per_row if per_row > 0 else float("inf")
                print(f"{label:<16}{depth:<10}{per_row * 1e6:>9.2f}{rate:>12,.0f}"
                      f"{rate / rows_per_s:>13.0f}x{per_row * rows_per_s:>11.1%}")
        print(f"\nlive, {live:g} s at 100 Hz per sensor: YOURS behind OWN per row")
        print(f"{'plug-in':<16}{'rows':>7}{'answered':>10}{'p50 ms':>9}{'p95 ms':>9}{'max ms':>9}")
        for label, path in (("trivial", trivial), ("course_ekf.py", COURSE_EKF)):
            lag = live_lag(path, live)
            print(f"{label:<16}{lag['rows']:>7}{lag['answered']:>10}{lag['p50'] * 1e3:>9.1f}"
                  f"{lag['p95'] * 1e3:>9.1f}{lag['max'] * 1e3:>9.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
