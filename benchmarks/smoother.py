"""The offline smoother against its own forward filter and offline VQF, per recording and held out.

For every shared recording with truth (BROAD, the Nexus 5 logs and their raw-magnetometer twins,
``benchmarks/datasets.py``) the smoother runs once (``ekf.smoother.smooth_parts``): per row the
combined estimate, the forward filter's (the filter as set, the default preset) and the
consistency statistic. Each gate threshold then picks per row, as ``ekf.smooth_batch`` does:

* ``99%``: the textbook 99 % point of the chi-square distribution (3 degrees of freedom: the
  attitude), the default;
* ``x10``, ``x100``: ten and a hundred times it;
* ``none``: no gate (the combination everywhere).

Offline VQF 9D (``vqf.offlineVQF``, forward-backward) runs on the same samples in the same run.
The table gives total RMSE [deg] per recording and ``smoothed - forward`` at the default gate;
then the folds: the threshold chosen on the other recordings (lowest mean smoothed RMSE among
the thresholds that leave no training recording more than 0.5 deg worse than its forward
filter; the textbook value if none does), scored on the held-out ones. Folds hold out a person
(Guillaume, Jakob: the Nexus 5 logs, BROAD in training) and a dataset (BROAD, Nexus 5). The raw
twins are scored, never chosen on.

    .venv/bin/python benchmarks/smoother.py [--only NAME,...]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from datasets import SHARED, load_all, run_vqf  # noqa: E402

from ekf.smoother import CHI2_99, smooth_parts  # noqa: E402

GATES = {"99%": CHI2_99[3], "x10": 10 * CHI2_99[3], "x100": 100 * CHI2_99[3], "none": math.inf}


def _person(name: str) -> str:
    return name.split("_")[0]


def _folds(recs) -> dict[str, tuple[list, list]]:
    tyrex = [r for r in recs if r.kind == "tyrex"]
    broad = [r for r in recs if r.kind == "broad"]
    folds = {}
    for person in sorted({_person(r.name) for r in tyrex}):
        held = [r for r in tyrex if _person(r.name) == person]
        folds[f"person {person}"] = (held, [r for r in tyrex + broad if r not in held])
    if broad and tyrex:
        folds["dataset BROAD"] = (broad, tyrex)
        folds["dataset Nexus 5"] = (tyrex, broad)
    return folds


def _choose(train, scores) -> str:
    ok = [g for g in GATES
          if all(scores[r.name][g] <= scores[r.name]["forward"] + 0.5 for r in train)]
    if not ok:
        return "99%"
    return min(ok, key=lambda g: np.mean([scores[r.name][g] for r in train]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", help="comma-separated parts of recording names")
    args = ap.parse_args()
    if not SHARED.is_dir():
        print(f"no shared data at {SHARED}: nothing to measure")
        return 0
    recs = load_all(("broad", "tyrex", "tyrex-raw"), args.only.split(",") if args.only else None)
    scores: dict[str, dict[str, float]] = {}
    print(f"{'recording':<42}{'forward':>8}" + "".join(f"{g:>8}" for g in GATES)
          + f"{'vqf-off':>8}{'sm-fw':>8}{'gated':>7}")
    for rec in recs:
        t, x_s, x_set, stat, _, _ = smooth_parts(rec.t_s, rec.gyr, rec.acc, rec.mag, "default")
        row = {"forward": rec.score(t, x_set[:, :4]).total_rmse_deg}
        for name, gate in GATES.items():
            q = np.where((stat <= gate)[:, None], x_s[:, :4], x_set[:, :4])
            row[name] = rec.score(t, q).total_rmse_deg
        tv, qv = run_vqf(rec, offline=True)
        row["vqf"] = rec.score(tv, qv).total_rmse_deg
        scores[rec.name] = row
        kept = float(np.mean(~(stat <= GATES["99%"])))
        print(f"{rec.name[:42]:<42}{row['forward']:8.2f}" + "".join(f"{row[g]:8.2f}" for g in GATES)
              + f"{row['vqf']:8.2f}{row['99%'] - row['forward']:+8.2f}{kept:7.0%}", flush=True)
    worst = max(scores, key=lambda n: scores[n]["99%"] - scores[n]["forward"])
    print(f"\nworst smoothed - forward (default gate): "
          f"{scores[worst]['99%'] - scores[worst]['forward']:+.2f} deg ({worst}); "
          "'gated': the rows that keep the forward estimate")
    print("\nheld out (mean total RMSE [deg], ratio to offline VQF in the same run):")
    print(f"{'fold':<22}{'chosen':>8}{'forward':>16}{'chosen gate':>16}{'99%':>16}"
          f"{'none':>16}{'vqf-off':>9}")
    for fold, (held, train) in _folds([r for r in recs if r.kind != "tyrex-raw"]).items():
        chosen = _choose(train, scores)
        vqf = np.mean([scores[r.name]["vqf"] for r in held])

        def cell(key: str) -> str:
            v = np.mean([scores[r.name][key] for r in held])
            return f"{v:7.2f} {v / vqf:5.2f}x  "

        print(f"{fold:<22}{chosen:>8}{cell('forward'):>16}{cell(chosen):>16}{cell('99%'):>16}"
              f"{cell('none'):>16}{vqf:9.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
