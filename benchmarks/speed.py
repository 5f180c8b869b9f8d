"""Speed of the compiled EKF (ekf.fast) beside VQF's and Fusion's C/C++ filters, same process.

On one BROAD trial (default: 01_undisturbed_slow_rotation_A, 285.7 Hz, GYR/ACC/MAG on every row):

* batch:     ``ekf.filter_batch`` (one compiled loop) vs ``vqf.VQF(Ts).updateBatch`` and
             ``vqf.offlineVQF`` (rows per second, and the ratio);
* streaming: ``est.step(t, gyr, acc, mag)`` called from Python per row, vs ``imufusion.Ahrs.update``
             per row, and the readable reference (a slice of the trial: it is slow).

Every figure is the best of `--repeats` runs (the machine may be shared; --cpu-time measures process
CPU time instead of wall time). Targets: batch >= 1.0 x VQF's updateBatch in the same run (timed
in alternation, so load from other processes hits both alike), streaming >= 200 000 rows/s.

    .venv/bin/python benchmarks/speed.py [--trial PATH] [--repeats 7] [--cpu-time]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import ekf  # noqa: E402
from ekf.fast import FastEKF, warm_up  # noqa: E402
from ekf.reference import OrientationEKF  # noqa: E402

SHARED = Path(os.environ.get("ORIENTATION_LAB_SHARED", REPO.parent / "shared"))
DEFAULT_TRIAL = SHARED / "data" / "broad" / "01_undisturbed_slow_rotation_A.txt"


def load_rows(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """t [s] (N,), gyr, acc, mag (N, 3) from a TAB-separated `t_ms TAG v1 v2 v3 [v4]` log; rows =
    distinct times (sorted), NaN where a sensor has no sample at that time."""
    rows: dict[int, dict[str, list[float]]] = {}
    with open(path) as f:
        for line in f:
            parts = line.split("\t")
            if len(parts) >= 5 and parts[1] in ("GYR", "ACC", "MAG"):
                rows.setdefault(int(parts[0]), {})[parts[1]] = [float(v) for v in parts[2:5]]
    times = sorted(rows)
    t = np.array(times, dtype=float) / 1000.0
    gyr, acc, mag = (np.array([rows[k].get(tag, [np.nan] * 3) for k in times])
                     for tag in ("GYR", "ACC", "MAG"))
    return t, gyr, acc, mag


CLOCK = time.perf_counter


def best_time(run, repeats: int) -> float:
    """Shortest time [s] of `repeats` calls of run(), on CLOCK (wall, or process CPU time with
    --cpu-time: steadier when other processes share the cores)."""
    best = float("inf")
    for _ in range(repeats):
        t0 = CLOCK()
        run()
        best = min(best, CLOCK() - t0)
    return best


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trial", type=Path, default=DEFAULT_TRIAL)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--reference-rows", type=int, default=3000,
                        help="rows for the (slow) readable reference's streaming figure")
    parser.add_argument("--cpu-time", action="store_true",
                        help="time with process CPU time instead of wall time (shared machines)")
    parser.add_argument("--quick", action="store_true",
                        help="a smoke run: 20,000 rows (a simulated session when the trial is "
                             "missing), one repeat; the figures are not the benchmark's")
    args = parser.parse_args(argv)
    global CLOCK
    if args.cpu_time:
        CLOCK = time.process_time
    if args.quick:
        args.repeats, args.reference_rows = 1, 200
    if args.trial.exists():
        t, gyr, acc, mag = load_rows(args.trial)
    elif args.quick:
        from ekf.simulate import simulate
        args.trial = Path("simulated session")
        t, gyr, acc, mag = simulate(duration_s=200.0, rates_hz={"gyr": 100.0, "acc": 100.0,
                                                                "mag": 100.0, "ori": 1.0},
                                    seed=0).to_batch_arrays()
    else:
        print(f"trial not found: {args.trial} (set ORIENTATION_LAB_SHARED)", file=sys.stderr)
        return 2
    if args.quick:
        t, gyr, acc, mag = t[:20_000], gyr[:20_000], acc[:20_000], mag[:20_000]
    n = t.size
    every_row = not (np.isnan(gyr).any() or np.isnan(acc).any() or np.isnan(mag).any())
    print(f"trial {args.trial.name}: {n} rows, {(n - 1) / (t[-1] - t[0]):.1f} Hz, "
          f"all three sensors on every row: {every_row}; load average {os.getloadavg()[0]:.2f} "
          f"on {os.cpu_count()} CPUs")
    t0 = time.perf_counter()
    warm_up()
    print(f"warm_up (compile or load the numba cache): {time.perf_counter() - t0:.2f} s")

    results: dict[str, float] = {}

    # ---- batch ------------------------------------------------------------------------------
    dt = best_time(lambda: ekf.filter_batch(t, gyr, acc, mag), args.repeats)
    results["ekf.filter_batch (default preset)"] = n / dt
    dt = best_time(lambda: ekf.filter_batch(t, gyr, acc, mag, estimator="course"), args.repeats)
    results["ekf.filter_batch (course preset)"] = n / dt
    # the same filter with every slow update run on every sample: what update_period_s saves
    every = ekf.PRESETS["default"].with_changes(update_period_s=0.0)
    dt = best_time(lambda: ekf.filter_batch(t, gyr, acc, mag, settings=every), args.repeats)
    results["ekf.filter_batch (default, update_period_s=0)"] = n / dt
    try:
        import vqf
    except ImportError:
        vqf = None
    pair_ratios: list[float] = []
    if vqf is not None:
        Ts = float((t[-1] - t[0]) / (n - 1))
        g, a, m = (np.ascontiguousarray(x) for x in (gyr, acc, mag))
        # ours and VQF's batch call in alternation: each pair sees the same machine load
        ours_best = vqf_best = math.inf
        for _ in range(args.repeats):
            ours = best_time(lambda: ekf.filter_batch(t, gyr, acc, mag), 1)
            theirs = best_time(lambda: vqf.VQF(Ts).updateBatch(g, a, m), 1)
            pair_ratios.append(theirs / ours)
            ours_best, vqf_best = min(ours_best, ours), min(vqf_best, theirs)
        results["ekf.filter_batch (default preset)"] = n / min(ours_best, n / results[
            "ekf.filter_batch (default preset)"])
        results["vqf.VQF.updateBatch (C++)"] = n / vqf_best
        dt = best_time(lambda: vqf.offlineVQF(g, a, m, Ts, None), args.repeats)
        results["vqf.offlineVQF (C++)"] = n / dt

    # ---- streaming --------------------------------------------------------------------------
    rows = [(float(t[k]), gyr[k], acc[k], mag[k]) for k in range(n)]

    def stream_fast() -> None:
        est = FastEKF()
        step = est.step
        for tk, gk, ak, mk in rows:
            step(tk, gk, ak, mk)

    dt = best_time(stream_fast, max(2, args.repeats // 2))
    results["FastEKF.step per row (Python loop)"] = n / dt

    def stream_fast_with_quat() -> None:
        est = FastEKF()
        step = est.step
        for tk, gk, ak, mk in rows:
            step(tk, gk, ak, mk)
            est.quat

    dt = best_time(stream_fast_with_quat, max(2, args.repeats // 2))
    results["FastEKF.step + .quat per row"] = n / dt

    try:
        import imufusion
    except ImportError:
        imufusion = None
    if imufusion is not None:
        gyr_deg = np.rad2deg(gyr)
        acc_g = acc / 9.81
        fusion_rows = [(gyr_deg[k], acc_g[k], mag[k]) for k in range(n)]
        period = (t[-1] - t[0]) / (n - 1)

        def stream_fusion() -> None:
            ahrs = imufusion.Ahrs()
            ahrs.set_sample_period(period)   # fixed-rate API (imufusion >= 1.3)
            update = ahrs.update
            for gk, ak, mk in fusion_rows:
                update(gk, ak, mk)

        dt = best_time(stream_fusion, max(2, args.repeats // 2))
        results["imufusion.Ahrs.update per row (C)"] = n / dt

    m_ref = min(args.reference_rows, n)
    if m_ref > 0:
        def stream_reference() -> None:
            est = OrientationEKF()
            for tk, gk, ak, mk in rows[:m_ref]:
                est.step(tk, gk, ak, mk)

        dt = best_time(stream_reference, 1)
        results[f"OrientationEKF.step per row (reference, {m_ref} rows)"] = m_ref / dt

    width = max(len(k) for k in results)
    print(f"\n(best of {args.repeats}, {'process CPU' if args.cpu_time else 'wall'} time)")
    for name, rate in results.items():
        print(f"{name:<{width}}  {rate:12,.0f} rows/s")
    batch = results["ekf.filter_batch (default preset)"]
    print()
    stream = results["FastEKF.step per row (Python loop)"]
    if vqf is not None:
        print(f"filter_batch / VQF.updateBatch: "
              f"{batch / results['vqf.VQF.updateBatch (C++)']:.2f}x (best of each); "
              f"median of {len(pair_ratios)} alternating pairs {np.median(pair_ratios):.2f}x; "
              f"/ offlineVQF: {batch / results['vqf.offlineVQF (C++)']:.2f}x")
    if imufusion is not None:
        print(f"FastEKF.step / imufusion.Ahrs.update: "
              f"{stream / results['imufusion.Ahrs.update per row (C)']:.2f}x")
    if vqf is not None:
        ratio = float(np.median(pair_ratios))
        print(f"targets: filter_batch >= 1.0 x VQF.updateBatch: {ratio:.2f}x "
              f"({'met' if ratio >= 1.0 else 'NOT met'}); ", end="")
    print(f"streaming >= 200 000 rows/s: {stream:.0f} ({'met' if stream >= 2e5 else 'NOT met'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
