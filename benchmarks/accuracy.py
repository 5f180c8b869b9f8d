"""Accuracy of Orientation Lab's estimators beside the public state of the art, same data, same metric.

Recordings (``benchmarks/datasets.py``):

* BROAD (``../shared/data/broad``): optical truth, scored over each trial's score intervals;
* the Nexus 5 recordings (``../shared/data/tyrex``): optical truth from ``NAME.truth.txt``,
  scored over ``NAME.json``'s intervals; the phone's own estimate (the log's ORI) is a row of
  its own; means for the undisturbed and the magnetically disturbed ones;
* the three Nexus 5 logs with a raw magnetometer (``NAME.uncalibrated.txt``, about 410 uT of
  hard iron), scored like their calibrated twins (``datasets.load_tyrex_raw``);
* the real phone logs that carry ORI (``../shared/data/realphone``): scored against the
  phone's own estimate after the first 3 s (no truth there).

Every estimate is compared with the reference at the reference's time stamps (slerp,
``ekf.metrics.interpolate_quat``): total / heading / inclination RMSE in degrees for
Orientation Lab (default and course presets, and the default smoothed offline,
``ekf.smooth_batch``), VQF 9D (the causal filter, ``VQF.updateBatch``), offline VQF 9D
(``vqf.offlineVQF``, a forward-backward peer of the smoother), VQF 6D, x-io Fusion (README
settings), Madgwick (ahrs, beta 0.12) and the ahrs EKF, all fed the same parsed samples.

    make bench            # or: .venv/bin/python benchmarks/accuracy.py [--quick] [--only NAME,...]

Peers run on the rows where the gyroscope has a sample, with the latest accelerometer and
magnetometer readings held (they need synchronous input) and the mean sample period of those
rows; Orientation Lab gets the asynchronous samples as they are.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import ekf  # noqa: E402
from ekf import quaternion as Q  # noqa: E402
from datasets import SHARED, Recording, load_all, run_ours, run_vqf  # noqa: E402

NED_TO_ENU = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])   # world NED -> ENU
NWU_TO_ENU = Q.from_axis_angle([0, 0, 1], np.pi / 2)            # world NWU -> ENU (north = +y)


def run_smoothed(rec: Recording):
    r = ekf.smooth_batch(rec.t_s, rec.gyr, rec.acc, rec.mag, settings="default")
    return rec.t_s, r.quat


def run_fusion(rec: Recording):
    import imufusion
    t, g, a, m, Ts = rec.sync
    ahrs = imufusion.Ahrs()
    rate = int(round(1.0 / Ts))
    # The settings of the Fusion README's advanced example, in ENU.
    s = imufusion.AhrsSettings()
    s.convention = imufusion.CONVENTION_ENU
    s.gain = 0.5
    s.gyroscope_range = 2000
    s.acceleration_rejection = 10
    s.magnetic_rejection = 10
    s.sample_rate = rate
    s.rejection_timeout = 5 * rate
    ahrs.set_settings(s)
    ahrs.set_sample_period(Ts)
    q = np.empty((len(t), 4))
    gyr_dps = np.rad2deg(g)
    acc_g = a / 9.81
    for k in range(len(q)):
        ahrs.update(gyr_dps[k], acc_g[k], m[k])
        q[k] = ahrs.get_quaternion()
    return t, Q.normalize(q)


def run_madgwick(rec: Recording):
    from ahrs.filters import Madgwick
    t, g, a, m, Ts = rec.sync
    f = Madgwick(gyr=g, acc=a, mag=m, frequency=1.0 / Ts, gain=0.12)
    # ahrs' Madgwick (MARG) works in North-West-Up: turn its world into ENU.
    return t, Q.normalize(Q.multiply(NWU_TO_ENU, f.Q))


def run_ahrs_ekf(rec: Recording):
    from ahrs.filters import EKF
    t, g, a, m, Ts = rec.sync
    # ahrs' EKF in its NED mode expects the accelerometer along gravity (the negated specific
    # force the phone reports); its quaternion is sensor -> NED, turned here into ENU. (Its ENU
    # mode did not give a consistent frame on BROAD.)
    f = EKF(gyr=g, acc=-a, mag=m, frequency=1.0 / Ts, frame="NED")
    return t, Q.normalize(Q.multiply(NED_TO_ENU, f.Q))


def run_phone(rec: Recording):
    if rec.phone_q is None:
        raise LookupError("no phone estimate apart from the reference")
    return rec.phone_t_ms / 1000.0, rec.phone_q


ESTIMATORS = {
    "ours-default": lambda r: run_ours(r, "default"),
    "ours-course": lambda r: run_ours(r, "course"),
    "ours-smoothed": run_smoothed,
    "vqf-9d": lambda r: run_vqf(r, True),
    "vqf-offline": lambda r: run_vqf(r, True, offline=True),
    "vqf-6d": lambda r: run_vqf(r, False),
    "fusion": run_fusion,
    "madgwick": run_madgwick,
    "ahrs-ekf": run_ahrs_ekf,
    "phone": run_phone,
}
GROUPS = {
    "broad": lambda r: r.kind == "broad",
    "nexus5 undisturbed": lambda r: r.kind == "tyrex" and not r.disturbed,
    "nexus5 disturbed": lambda r: r.kind == "tyrex" and r.disturbed,
    "nexus5 all": lambda r: r.kind == "tyrex",
    "nexus5 raw magnetometer": lambda r: r.kind == "tyrex-raw",
    "phone logs (vs ORI)": lambda r: r.kind == "phone",
}


def _recordings(quick: bool) -> list[Recording]:
    kinds = ("broad", "tyrex", "tyrex-raw", "phone")
    if not quick:
        return load_all(kinds)
    return load_all(kinds, only=["01_undisturbed", "06_undisturbed", "NoDist_Texting",
                                 "tsrt14_lab2_rotation"])


def _table(results, names, recs, col: int, metric: str) -> None:
    print(f"\nRMSE {metric} [deg] (vs optical truth at its time stamps; phone logs: vs the "
          "phone's ORI after 3 s)")
    print(f"{'recording':<40}" + "".join(f"{n:>14}" for n in names))
    for group, member in GROUPS.items():
        chosen = [r for r in recs if member(r)]
        if not chosen:
            continue
        if group != "nexus5 all":
            for r in chosen:
                res = results[r.name]
                print(f"{r.name[:40]:<40}" + "".join(
                    f"{res[n][col]:>14.2f}" if n in res else f"{'-':>14}" for n in names))
        print(f"{'mean ' + group:<40}" + "".join(
            f"{np.mean([results[r.name][n][col] for r in chosen]):>14.2f}"
            if all(n in results[r.name] for r in chosen) else f"{'-':>14}" for n in names))


def _ratio(results, recs, a: str, b: str) -> str:
    if not recs or not all(a in results[r.name] and b in results[r.name] for r in recs):
        return "-"
    x = np.array([results[r.name][a][0] for r in recs])
    y = np.array([results[r.name][b][0] for r in recs])
    worst = int(np.argmax(x / y))
    return (f"{x.mean():.2f} vs {y.mean():.2f} deg = {x.mean() / y.mean():.2f}x "
            f"(worst {x[worst] / y[worst]:.2f}x, {recs[worst].name})")


def _summary(results, recs) -> None:
    print("\nsummary (mean total RMSE, same run):")
    for group in ("broad", "nexus5 undisturbed", "nexus5 disturbed", "nexus5 all",
                  "nexus5 raw magnetometer"):
        chosen = [r for r in recs if GROUPS[group](r)]
        if not chosen:
            continue
        print(f"  {group}: ours-default / vqf-9d {_ratio(results, chosen, 'ours-default', 'vqf-9d')}")
        print(f"  {group}: ours-default / vqf-offline "
              f"{_ratio(results, chosen, 'ours-default', 'vqf-offline')}")
        print(f"  {group}: ours-smoothed / vqf-offline "
              f"{_ratio(results, chosen, 'ours-smoothed', 'vqf-offline')}")
        if group.startswith("nexus5"):
            print(f"  {group}: ours-default / phone "
                  f"{_ratio(results, chosen, 'ours-default', 'phone')}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="two BROAD trials, one Nexus 5 recording and one phone log")
    ap.add_argument("--only", help="comma-separated estimators (default all): " + ", ".join(ESTIMATORS))
    args = ap.parse_args()
    if not SHARED.is_dir():
        print(f"no shared data at {SHARED}: nothing to measure")
        return 0
    names = args.only.split(",") if args.only else list(ESTIMATORS)
    unknown = [n for n in names if n not in ESTIMATORS]
    if unknown:
        print(f"unknown estimator(s): {', '.join(unknown)}", file=sys.stderr)
        return 2
    ekf.filter_batch(np.arange(3) * 0.01, np.zeros((3, 3)), np.tile([0, 0, 9.81], (3, 1)),
                     np.tile([0, 20, -40.0], (3, 1)))   # compile the fast path outside the timing
    recs = _recordings(args.quick)
    results: dict[str, dict[str, tuple]] = {}
    missing: set[str] = set()
    for rec in recs:
        results[rec.name] = {}
        for name in names:
            t0 = time.perf_counter()
            try:
                t_est, q_est = ESTIMATORS[name](rec)
            except ImportError as e:
                if name not in missing:
                    print(f"  {name}: not installed ({e}); `make bench` installs the peers",
                          file=sys.stderr)
                    missing.add(name)
                continue
            except LookupError:
                continue
            s = rec.score(np.asarray(t_est), np.asarray(q_est))
            results[rec.name][name] = (s.total_rmse_deg, s.heading_rmse_deg,
                                       s.inclination_rmse_deg, time.perf_counter() - t0)
        row = "  ".join(f"{n}={v[0]:.2f}" for n, v in results[rec.name].items())
        print(f"{rec.name}: {row}", flush=True)
    for col, metric in enumerate(("total", "heading", "inclination")):
        _table(results, names, recs, col, metric)
    _summary(results, recs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
