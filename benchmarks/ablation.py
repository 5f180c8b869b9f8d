"""Ablation: does every mechanism of the default preset earn its place on recordings it was not
chosen on?

A *mechanism* is a setting, or a group of settings that act together, that the default preset
switches on beyond the course filter (``MECHANISMS``: name -> the changes that switch it off,
back to the course's behaviour). Two tables, both on the folds of ``tune_defaults.py --folds
user`` (what a user brings: leave one **person** out of the Nexus 5 recordings, leave one
**dataset** out, BROAD or the Nexus 5):

1. **One at a time.** The preset with one mechanism off, every recording filtered, reported
   per held-out set (Guillaume's Nexus 5, Jakob's Nexus 5, BROAD): the ratio of the mean total
   RMSE to VQF 9D's on the same samples, the worst recording's ratio and the count of
   recordings beyond 2x VQF. A fixed preset is not tuned, so this is the preset's figure on
   every set; it shows what each mechanism does.
2. **Decided inside the folds.** Per fold, backward elimination on the fold's *training*
   recordings only: repeatedly switch off the mechanism whose removal gives the best training
   objective (``tune_defaults.objective``), as long as that objective is no worse than
   ``--margin`` above the current one (a tie removes: fewer mechanisms). The fold's held-out
   recordings are then filtered with what the training side kept: those are the **held-out**
   figures. The same elimination on every recording gives the preset the procedure proposes.

Every configuration is filtered once over all recordings and cached, so the elimination costs
one pass (~1 s) per new configuration.

    .venv/bin/python benchmarks/ablation.py [--preset default] [--settings FILE] [--margin 0.005]
                                            [--jobs 2] [--quick] [--one-at-a-time-only]
"""

from __future__ import annotations

import argparse
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import ekf  # noqa: E402
from datasets import Recording, load_all, run_ours, run_vqf  # noqa: E402
from tune_defaults import FOLD_SETS, _family, objective, person_of  # noqa: E402

COURSE = ekf.PRESETS["course"]


def _course(*names: str) -> dict:
    return {n: getattr(COURSE, n) for n in names}


# name -> the changes that switch the mechanism off (its settings back to the course's)
MECHANISMS: dict[str, dict] = {
    "exact discretisation": _course("exact_discretisation"),
    "rate before its sample": _course("gyr_rate_before_sample"),
    "gyro scale noise": _course("gyr_scale_noise"),
    "bias in the state": _course("estimate_gyro_bias"),
    "carried acc low-pass": _course("acc_lowpass_s"),
    "adaptive R_a": _course("acc_noise_adapt"),
    "tilt only when mag silent": _course("acc_tilt_only_after_s"),
    "acc range clipping": _course("acc_range"),
    "mag heading only": _course("mag_heading_only"),
    "unevenness R_m": _course("mag_noise_adapt"),
    "unevenness clip": _course("mag_noise_adapt_clip"),
    "heading gain cap": _course("mag_return_s"),
    "dip gate": _course("mag_dip_gate_deg", "mag_dip_from_estimate"),
    "settling": _course("mag_settle_s"),
    "reference mean": _course("mag_reference_s"),
    "no-gyroscope bound": _course("mag_max_reject_no_gyro_s"),
    "world-frame re-learning": _course("mag_strength_update", "mag_relearn_s",
                                       "mag_relearn_world", "mag_relearn_min_rate",
                                       "mag_first_relearn_s"),
    "young field": _course("mag_first_relearn_s"),
    "bias-innovation limit": _course("mag_bias_innovation_limit"),
    "hard-iron fit": _course("mag_hard_iron_tau_s"),
    "mag delay": _course("mag_delay_s"),
    "slow-update period": _course("update_period_s"),
}


def present(settings: ekf.EKFSettings) -> list[str]:
    """The mechanisms that are on in `settings` (switching them off changes a setting)."""
    return [m for m, off in MECHANISMS.items()
            if any(getattr(settings, k) != v for k, v in off.items())]


def without(base: ekf.EKFSettings, removed: frozenset[str]) -> ekf.EKFSettings:
    changes: dict = {}
    for m in sorted(removed):
        changes.update(MECHANISMS[m])
    return base.with_changes(**changes)


_STATE: dict = {}


def _errors_job(removed: frozenset[str]) -> tuple[frozenset[str], np.ndarray]:
    recs, base = _STATE["recs"], _STATE["base"]
    s = without(base, removed)
    return removed, np.array([r.score(*run_ours(r, s)).total_rmse_deg for r in recs])


class Cache:
    """Per configuration (the set of mechanisms switched off) every recording's total RMSE."""

    def __init__(self, recs: list[Recording], base: ekf.EKFSettings, jobs: int) -> None:
        _STATE.update(recs=recs, base=base)
        self.done: dict[frozenset[str], np.ndarray] = {}
        self.pool = ProcessPoolExecutor(jobs) if jobs > 1 else None

    def get_many(self, configs: list[frozenset[str]]) -> list[np.ndarray]:
        todo = [c for c in dict.fromkeys(configs) if c not in self.done]
        if todo:
            results = (self.pool.map(_errors_job, todo) if self.pool
                       else map(_errors_job, todo))
            self.done.update(results)
        return [self.done[c] for c in configs]

    def get(self, config: frozenset[str]) -> np.ndarray:
        return self.get_many([config])[0]


def eliminate(cache: Cache, mechanisms: list[str], sel: np.ndarray, vqf: np.ndarray,
              kinds: list[str], margin: float, log=None) -> frozenset[str]:
    """Backward elimination on the recordings `sel`: the set of mechanisms removed."""
    kinds_sel = [k for k, s in zip(kinds, sel) if s]

    def score(config: frozenset[str]) -> float:
        return objective(cache.get(config)[sel], vqf[sel], kinds_sel)

    removed: frozenset[str] = frozenset()
    current = score(removed)
    while True:
        left = [m for m in mechanisms if m not in removed]
        if not left:
            return removed
        configs = [removed | {m} for m in left]
        cache.get_many(configs)
        values = [score(c) for c in configs]
        best = int(np.argmin(values))
        if values[best] > current + margin:
            return removed
        if log:
            log(f"    off: {left[best]:<28} objective {current:.3f} -> {values[best]:.3f}")
        removed, current = configs[best], values[best]


def held_sets(recs: list[Recording]) -> dict[str, np.ndarray]:
    """The held-out sets the figures are reported on."""
    person = np.array([person_of(r) for r in recs])
    kinds = np.array([r.kind for r in recs])
    out = {p: (kinds == "tyrex") & (person == p) for p in sorted(set(person[kinds == "tyrex"]))}
    out["BROAD"] = kinds == "broad"
    return {k: v for k, v in out.items() if v.any()}


def figures(err: np.ndarray, vqf: np.ndarray, sel: np.ndarray) -> tuple[float, float, int]:
    ratio = err[sel] / vqf[sel]
    return float(err[sel].mean() / vqf[sel].mean()), float(ratio.max()), int(np.sum(ratio > 2.0))


def one_at_a_time(cache: Cache, mechanisms: list[str], recs: list[Recording],
                  vqf: np.ndarray) -> None:
    sets = held_sets(recs)
    kinds = [r.kind for r in recs]
    head = "".join(f"{name[:22]:>24}" for name in sets)
    print(f"\n{'switched off':<28}{head}{'objective':>11}")
    print(f"{'':<28}" + "".join(f"{'mean  worst >2x':>24}" for _ in sets))
    rows = [("(nothing: the preset)", frozenset())] + [(m, frozenset({m})) for m in mechanisms]
    errs = cache.get_many([c for _, c in rows])
    base_obj = objective(errs[0], vqf, kinds)
    for (label, _), e in zip(rows, errs):
        cells = "".join(f"{'%.2fx %5.2fx %3d' % figures(e, vqf, s):>24}" for s in sets.values())
        obj = objective(e, vqf, kinds)
        mark = "" if label.startswith("(") else ("  worse without" if obj > base_obj else
                                                 "  no worse without")
        print(f"{label:<28}{cells}{obj:>11.3f}{mark}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="default", help="the preset whose mechanisms are tested")
    ap.add_argument("--settings", default="", help="a settings file instead of --preset")
    ap.add_argument("--margin", type=float, default=0.005,
                    help="a mechanism is removed when the objective without it is at most this "
                         "much above (default %(default)s: prefer fewer mechanisms)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--one-at-a-time-only", action="store_true")
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: four recordings, three mechanisms")
    args = ap.parse_args()
    try:
        import vqf  # noqa: F401
    except ImportError as error:
        print(f"needs the bench extra ({error}); `make bench` installs it")
        return 0
    base = (ekf.EKFSettings.load(args.settings) if args.settings
            else ekf.PRESETS[args.preset])
    only = (["01_undisturbed", "24_disturbed", "Guillaume_Nexus5_NoDist_Texting",
             "Jakob_Nexus5_NoDist_AR"] if args.quick else None)
    recs = load_all(("broad", "tyrex"), only)
    if not recs:
        print("no shared data (../shared/data/broad, tyrex): nothing to measure")
        return 0
    mechanisms = present(base)
    if args.quick:
        mechanisms = mechanisms[:3]
    vqf_err = np.array([r.score(*run_vqf(r)).total_rmse_deg for r in recs])
    kinds = [r.kind for r in recs]
    print(f"{len(recs)} recordings; {len(mechanisms)} mechanisms on in the preset: "
          f"{', '.join(mechanisms)}")
    cache = Cache(recs, base, args.jobs)
    one_at_a_time(cache, mechanisms, recs, vqf_err)
    if args.one_at_a_time_only:
        return 0

    print("\ndecided inside the folds (backward elimination on each fold's training side):")
    folds = FOLD_SETS["user"]
    held: dict[str, np.ndarray] = {}
    kept_by_fold: dict[str, list[str]] = {}
    for fold, inside in folds.items():
        test = np.array([inside(r) for r in recs])
        if not test.any() or test.all():
            continue
        print(f"  fold {fold}: trained on {int((~test).sum())}, held out {int(test.sum())}")
        removed = eliminate(cache, mechanisms, ~test, vqf_err, kinds, args.margin, print)
        kept_by_fold[fold] = [m for m in mechanisms if m not in removed]
        print(f"    kept: {', '.join(kept_by_fold[fold]) or 'none'}")
        e = cache.get(removed)
        family = held.setdefault(_family(fold), np.full(len(recs), np.nan))
        family[test] = e[test]
    print("\nheld out (each recording filtered with what its fold's training side kept):")
    base_err = cache.get(frozenset())
    for family, h in held.items():
        label = f"{family} out"
        for name, sel in held_sets(recs).items():
            sel = sel & np.isfinite(h)
            if sel.any():
                m, w, n = figures(h, vqf_err, sel)
                bm, bw, bn = figures(base_err, vqf_err, sel)
                print(f"  {label:<12}{name:<12} {m:.2f}x VQF 9D, worst {w:.2f}x, {n} beyond 2x"
                      f"   (the preset as given: {bm:.2f}x, worst {bw:.2f}x, {bn} beyond 2x)")
    print("\non every recording:")
    removed_all = eliminate(cache, mechanisms, np.ones(len(recs), bool), vqf_err, kinds,
                            args.margin, print)
    kept = [m for m in mechanisms if m not in removed_all]
    print(f"  kept: {', '.join(kept) or 'none'}")
    votes = {m: sum(m in k for k in kept_by_fold.values()) for m in mechanisms}
    print("  kept by the folds: " + ", ".join(f"{m} {v}/{len(kept_by_fold)}"
                                                 for m, v in votes.items()))
    if cache.pool:
        cache.pool.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
