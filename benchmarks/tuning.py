"""Re-filter and auto-tune figures.

* Instant re-filter: a whole simulated 10-minute session at 100 Hz (GYR/ACC/ORI 100 Hz, MAG
  50 Hz) run again with new settings through app.engine.offline.refilter (the compiled batch path),
  median of several runs after one warm-up. Target <= 0.2 s.
* Auto-tune (app.engine.tuning.autotune, scipy Nelder-Mead from the default preset): time and RMSE
  before/after on tsrt14_lab2_rotation.txt (vs the phone's ORI, after 3 s) checked on
  tsrt14_lab2_accdisturbance.txt, and on three BROAD trials (vs the optical truth, their score
  intervals), each checked on another trial.

    python benchmarks/tuning.py [--quick] [--evals N] [--repeats N]

--quick: a 60-second session, 6 evaluations, the phone log and one BROAD pair (a smoke test).
Missing shared data is reported and skipped. One process, one thread.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import ekf  # noqa: E402
from ekf.simulate import simulate  # noqa: E402
from app.engine import config  # noqa: E402
from app.engine.tuning import autotune  # noqa: E402
from app.engine.offline.refilter import refilter  # noqa: E402
from app.stream.demo import write_session  # noqa: E402

SHARED = REPO.parent / "shared" / "data"
PHONE = ("tsrt14_lab2_rotation.txt", "tsrt14_lab2_accdisturbance.txt")
BROAD_PAIRS = (("01_undisturbed_slow_rotation_A", "06_undisturbed_fast_rotation_A"),
               ("06_undisturbed_fast_rotation_A", "08_undisturbed_fast_rotation_with_breaks_A"),
               ("24_disturbed_tapping_A", "01_undisturbed_slow_rotation_A"))


def bench_refilter(duration_s: float, repeats: int) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "session.txt"
        write_session(simulate(duration_s=duration_s, seed=1), path)
        prepared = config.open_log(path)
    rows = len(prepared.t_ms)
    refilter(prepared, ekf.PRESETS["course"])            # warm-up (kernels loaded)
    times = []
    for k in range(repeats):
        settings = ekf.PRESETS["default"].with_changes(acc_gate=1.0 + 0.1 * k)
        started = time.perf_counter()
        result = refilter(prepared, settings)
        times.append(time.perf_counter() - started)
    print(f"re-filter, {duration_s / 60:.0f}-minute session at 100 Hz ({rows} samples, "
          f"{len(result.rows)} rows): median {1000 * statistics.median(times):.0f} ms, "
          f"min {1000 * min(times):.0f} ms, max {1000 * max(times):.0f} ms over {repeats} runs "
          f"(target <= 200 ms); total RMSE {result.summary.total_rmse_deg:.2f} deg")


def _target(path: Path, label: str, skip_s: float = 0.0) -> autotune.Target:
    prepared = config.open_log(path)
    sibling = path.with_suffix(".json")
    intervals = config.read_intervals(sibling) if sibling.is_file() else None
    return autotune.Target(prepared, intervals, skip_s, label)


def _report(name: str, result: autotune.TuneResult) -> None:
    def fig(s):
        return f"{s.total_rmse_deg:5.2f} ({s.heading_rmse_deg:4.2f}/{s.inclination_rmse_deg:4.2f})"
    print(f"{name:<34} tune {fig(result.tune_before)} -> {fig(result.tune_after)}   check "
          f"{fig(result.check_before)} -> {fig(result.check_after)}   {result.evaluations:>3} "
          f"runs {result.elapsed_s:6.1f} s")
    if result.overfit_warning:
        print(f"{'':<34} warning: {result.overfit_warning}")


def bench_tune(pairs: list[tuple[Path, Path, float]], evals: int) -> None:
    print(f"auto-tune from the default preset ({', '.join(autotune.DEFAULT_PARAMETERS)}), at most "
          f"{evals} runs; RMSE deg total (heading/inclination)")
    for tune_path, check_path, skip in pairs:
        if not (tune_path.is_file() and check_path.is_file()):
            print(f"{tune_path.stem}: shared data not found, skipped")
            continue
        target = _target(tune_path, tune_path.stem, skip)
        check = _target(check_path, check_path.stem, skip)
        result = autotune.tune(target, ekf.PRESETS["default"], None, check, max_evals=evals)
        _report(f"{tune_path.stem[:14]} -> {check_path.stem[:14]}", result)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a short smoke run")
    parser.add_argument("--evals", type=int, default=None, help="evaluations per search")
    parser.add_argument("--repeats", type=int, default=7, help="re-filter runs timed")
    args = parser.parse_args(argv)
    evals = args.evals or (6 if args.quick else 60)
    bench_refilter(60.0 if args.quick else 600.0, 3 if args.quick else args.repeats)
    phone = SHARED / "realphone"
    broad = SHARED / "broad"
    pairs = [(phone / PHONE[0], phone / PHONE[1], 3.0)]
    pairs += [(broad / f"{a}.txt", broad / f"{b}.txt", 0.0)
              for a, b in (BROAD_PAIRS[:1] if args.quick else BROAD_PAIRS)]
    bench_tune(pairs, evals)
    return 0


if __name__ == "__main__":
    sys.exit(main())
