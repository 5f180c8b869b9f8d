"""Robustness: the Nexus 5 recordings made harder (``benchmarks/augment.py``), ours beside VQF.

The real recordings are one person's in one room; the scenarios add what other people, other
buildings and other phones bring (stronger world-frame disturbances, a disturbed start, a
magnet in the case, more gyroscope bias) to the real sensor readings, so the optical truth
still holds. Every estimator gets the same perturbed samples and is scored like
``benchmarks/accuracy.py`` (total RMSE at the truth's time stamps over the score intervals).

    .venv/bin/python benchmarks/robustness.py [--copies 3] [--only NAME,...] [--settings FILE]
                                              [--scenarios building-50,desk-start,...] [--quick]

Prints per scenario the mean total RMSE of ours (the default preset, or ``--settings``) and of
VQF 9D, their ratio, the worst recording's ratio, how many recordings are beyond 2x VQF and how
many of ours beyond 30 deg; the unperturbed recordings first, from the same run. A raw
magnetometer beside a calibrated gyroscope: ``--scenarios magnet-400,building-50+magnet-400``.

``mag-off`` (a scenario of this benchmark only): the magnetometer switched off 8 s into each
real recording (the app's sensor switch, a phone whose magnetometer gives out), scored from
there on. The peer is VQF fed the same way: 9D for the first 8 s, then 6D, its last heading
correction (``getDelta``) kept, which is what its 9D estimate does once no reading comes.
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import ekf  # noqa: E402
from ekf import quaternion as Q  # noqa: E402
from augment import SCENARIOS, known, perturbed  # noqa: E402
from datasets import load_all, run_ours, run_vqf  # noqa: E402


def summary(label: str, ours: np.ndarray, vqf: np.ndarray, names: list[str]) -> str:
    ratio = ours / vqf
    worst = int(np.argmax(ratio))
    return (f"{label:<24}{ours.mean():>8.2f}{vqf.mean():>8.2f}{ours.mean() / vqf.mean():>8.2f}x"
            f"{ratio[worst]:>8.2f}x  {int(np.sum(ratio > 2.0)):>3}  {int(np.sum(ours > 30.0)):>4}"
            f"   {names[worst]}")


MAG_OFF_S = 8.0


def magnetometer_off(rec, after_s: float = MAG_OFF_S):
    """A copy of `rec` without magnetometer readings from `after_s` on, scored from there."""
    out = copy.copy(rec)
    out._sync = None
    out.name = f"{rec.name}+mag-off"
    out.mag = rec.mag.copy()
    out.mag[rec.t_s >= rec.t_s[0] + after_s] = np.nan
    out.skip_s = max(rec.skip_s, after_s)
    return out


def run_vqf_mag_off(rec, after_s: float = MAG_OFF_S):
    """VQF 9D until `after_s`, then 6D with its last heading correction: (t, quaternions)."""
    import vqf
    t, g, a, m, Ts = rec.sync
    k = int(np.searchsorted(t, t[0] + after_s))
    f = vqf.VQF(Ts)
    first = f.updateBatch(g[:k], a[:k], m[:k])["quat9D"]
    delta = f.getDelta()
    rest = f.updateBatch(g[k:], a[k:])["quat6D"]
    turn = np.array([math.cos(delta / 2), 0.0, 0.0, math.sin(delta / 2)])
    return t, np.vstack([first, Q.multiply(np.tile(turn, (len(rest), 1)), rest)])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--copies", type=int, default=3, help="perturbed copies per recording and "
                    "scenario (each seeded differently)")
    ap.add_argument("--scenarios", default=",".join(SCENARIOS + ("mag-off",)),
                    help=f"comma-separated, from {', '.join(SCENARIOS)}, mag-off; magnet-N and "
                         "building-N take any strength [uT]; a+b applies a, then b")
    ap.add_argument("--only", default="", help="recordings whose names contain one of these")
    ap.add_argument("--settings", default="", help="a settings JSON file instead of the default")
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: one recording, one copy of two scenarios")
    args = ap.parse_args()
    if args.quick:
        args.copies, args.scenarios, args.only = 1, "desk-start,magnet-20,mag-off", \
            "NoDist_Texting"
    scenarios = [s for s in args.scenarios.split(",") if s]
    unknown = [s for s in scenarios if s != "mag-off" and not known(s)]
    if unknown:
        print(f"--scenarios: unknown {', '.join(unknown)}; choose from {', '.join(SCENARIOS)}, "
              "mag-off, magnet-N, building-N, or several joined by +", file=sys.stderr)
        return 2
    try:
        import vqf  # noqa: F401
    except ImportError as error:
        print(f"needs the bench extra ({error}); `make bench` installs it")
        return 0
    settings = ekf.EKFSettings.load(args.settings) if args.settings else ekf.PRESETS["default"]
    recs = load_all(("tyrex",), [o for o in args.only.split(",") if o] or None)
    if not recs:
        print("no shared data (../shared/data/tyrex): nothing to measure")
        return 0
    print(f"{len(recs)} Nexus 5 recordings, {args.copies} copies per scenario; mean total RMSE "
          f"[deg] at the truth's time stamps\n")
    print(f"{'scenario':<24}{'ours':>8}{'VQF 9D':>8}{'ratio':>9}{'worst':>9}  >2x  >30°   "
          f"worst recording")
    rows = [("real", [(r, 0) for r in recs])]
    rows += [(s, [(r, k) for r in recs for k in range(args.copies if s != "mag-off" else 1)])
             for s in scenarios]
    for scenario, items in rows:
        ours, peer, names = [], [], []
        for rec, k in items:
            if scenario == "mag-off":
                r = magnetometer_off(rec)
                peer.append(r.score(*run_vqf_mag_off(r)).total_rmse_deg)
            else:
                r = rec if scenario == "real" else perturbed(rec, scenario, k)
                peer.append(r.score(*run_vqf(r)).total_rmse_deg)
            ours.append(r.score(*run_ours(r, settings)).total_rmse_deg)
            names.append(r.name)
        print(summary(scenario, np.array(ours), np.array(peer), names), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
