"""Accuracy of Orientation Lab's estimators beside the public state of the art, same data, same metric.

For every BROAD trial in ../shared/data/broad (optical ground truth, scored over its
`score_intervals_ms`) and every real phone log that carries ORI (the phone's own estimate,
scored after the first 3 s), print total / heading / inclination RMSE in degrees for:
Orientation Lab (default and course presets), VQF 9D and 6D, x-io Fusion (README settings),
Madgwick (ahrs, beta 0.12) and the ahrs EKF. All are fed the same parsed samples.

    make bench            # or: .venv/bin/python benchmarks/accuracy.py [--quick] [--only NAME,...]

Peers run on the rows where the gyroscope has a sample, with the latest accelerometer and
magnetometer readings held (they need synchronous input); Orientation Lab gets the
asynchronous samples as they are. Sample period for the peers: the mean period of those rows.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import ekf  # noqa: E402
from ekf import quaternion as Q  # noqa: E402
from ekf.metrics import intervals_mask  # noqa: E402
from app.stream.logfile import read_log  # noqa: E402

SHARED = REPO.parent / "shared" / "data"
NED_TO_ENU = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])   # world NED -> ENU
NWU_TO_ENU = Q.from_axis_angle([0, 0, 1], np.pi / 2)            # world NWU -> ENU (north = +y)


def hold(a: np.ndarray) -> np.ndarray:
    """Forward-fill NaN rows with the previous valid row (first rows: the first valid row)."""
    a = a.copy()
    valid = ~np.isnan(a).any(axis=1)
    if not valid.any():
        return a
    idx = np.where(valid, np.arange(len(a)), 0)
    np.maximum.accumulate(idx, out=idx)
    first = np.flatnonzero(valid)[0]
    idx[:first] = first
    return a[idx]


class Trial:
    def __init__(self, path: Path, intervals, skip_s: float):
        self.name = path.stem
        log = read_log(path)
        a = log.to_arrays()
        self.t_ms = a.t_ms
        rows = ~(np.isnan(a.gyr).all(1) & np.isnan(a.acc).all(1) & np.isnan(a.mag).all(1))
        self.rows = rows
        self.gyr, self.acc, self.mag, self.ori = a.gyr, a.acc, a.mag, a.ori
        self.intervals = intervals
        self.skip_s = skip_s
        g_rows = ~np.isnan(a.gyr).any(axis=1)
        self.sync_t = a.t_ms[g_rows]
        self.sync_gyr = np.ascontiguousarray(a.gyr[g_rows])
        self.sync_acc = np.ascontiguousarray(hold(a.acc)[g_rows])
        self.sync_mag = np.ascontiguousarray(hold(a.mag)[g_rows])
        self.Ts = float(self.sync_t[-1] - self.sync_t[0]) / (len(self.sync_t) - 1) / 1000.0

    def score(self, t_est: np.ndarray, q_est: np.ndarray):
        has = ~np.isnan(self.ori).any(axis=1)
        t_ref, q_ref = self.t_ms[has], self.ori[has]
        idx = np.searchsorted(t_est, t_ref, side="right") - 1
        ok = idx >= 0
        q = np.full_like(q_ref, np.nan)
        q[ok] = q_est[idx[ok]]
        mask = intervals_mask(t_ref, self.intervals) & (t_ref >= t_est[0] + 1000 * self.skip_s)
        return ekf.summarize(q, q_ref, mask)


# ---- estimators -----------------------------------------------------------------------------

def run_ours(trial: Trial, preset: str):
    r = ekf.filter_batch(trial.t_ms[trial.rows] / 1000.0, trial.gyr[trial.rows],
                         trial.acc[trial.rows], trial.mag[trial.rows], settings=ekf.PRESETS[preset])
    return trial.t_ms[trial.rows], r.quat


def run_vqf(trial: Trial, nine: bool):
    from vqf import offlineVQF
    out = offlineVQF(trial.sync_gyr, trial.sync_acc, trial.sync_mag if nine else None, trial.Ts, None)
    return trial.sync_t, out["quat9D" if nine else "quat6D"]


def run_fusion(trial: Trial):
    import imufusion
    ahrs = imufusion.Ahrs()
    rate = int(round(1.0 / trial.Ts))
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
    ahrs.set_sample_period(trial.Ts)
    q = np.empty((len(trial.sync_t), 4))
    gyr_dps = np.rad2deg(trial.sync_gyr)
    acc_g = trial.sync_acc / 9.81
    for k in range(len(q)):
        ahrs.update(gyr_dps[k], acc_g[k], trial.sync_mag[k])
        q[k] = ahrs.get_quaternion()
    return trial.sync_t, Q.normalize(q)


def run_madgwick(trial: Trial):
    from ahrs.filters import Madgwick
    f = Madgwick(gyr=trial.sync_gyr, acc=trial.sync_acc, mag=trial.sync_mag,
                 frequency=1.0 / trial.Ts, gain=0.12)
    # ahrs' Madgwick (MARG) works in North-West-Up: turn its world into ENU.
    return trial.sync_t, Q.normalize(Q.multiply(NWU_TO_ENU, f.Q))


def run_ahrs_ekf(trial: Trial):
    from ahrs.filters import EKF
    # ahrs' EKF in its NED mode expects the accelerometer along gravity (the negated specific
    # force the phone reports); its quaternion is sensor -> NED, turned here into ENU. (Its ENU
    # mode did not give a consistent frame on BROAD.)
    f = EKF(gyr=trial.sync_gyr, acc=-trial.sync_acc, mag=trial.sync_mag,
            frequency=1.0 / trial.Ts, frame="NED")
    return trial.sync_t, Q.normalize(Q.multiply(NED_TO_ENU, f.Q))


ESTIMATORS = {
    "ours-default": lambda tr: run_ours(tr, "default"),
    "ours-course": lambda tr: run_ours(tr, "course"),
    "vqf-9d": lambda tr: run_vqf(tr, True),
    "vqf-6d": lambda tr: run_vqf(tr, False),
    "fusion": run_fusion,
    "madgwick": run_madgwick,
    "ahrs-ekf": run_ahrs_ekf,
}


def trials(quick: bool):
    out = []
    broad = SHARED / "broad"
    for txt in sorted(broad.glob("*.txt")):
        js = txt.with_suffix(".json")
        iv = json.loads(js.read_text())["score_intervals_ms"] if js.is_file() else None
        out.append(("broad", txt, iv, 0.0))
    for txt in sorted((SHARED / "realphone").glob("*.txt")):
        with open(txt, "rb") as f:
            if b"\tORI\t" in f.read():
                out.append(("phone", txt, None, 3.0))
    if quick:
        out = out[:2] + [x for x in out if x[0] == "phone"][:1]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="two BROAD trials and one phone log")
    ap.add_argument("--only", help="comma-separated estimators (default all): " + ", ".join(ESTIMATORS))
    args = ap.parse_args()
    if not SHARED.is_dir():
        print(f"no shared data at {SHARED}: nothing to measure")
        return 0
    names = args.only.split(",") if args.only else list(ESTIMATORS)
    results: dict[str, dict[str, tuple]] = {}
    ekf.filter_batch(np.arange(3) * 0.01, np.zeros((3, 3)), np.tile([0, 0, 9.81], (3, 1)),
                     np.tile([0, 20, -40.0], (3, 1)))   # compile the fast path outside the timing
    for kind, path, iv, skip in trials(args.quick):
        tr = Trial(path, iv, skip)
        results[tr.name] = {}
        for name in names:
            t0 = time.perf_counter()
            try:
                t_est, q_est = ESTIMATORS[name](tr)
            except ImportError as e:
                print(f"  {name}: not installed ({e}); `make bench` installs the peers", file=sys.stderr)
                continue
            s = tr.score(np.asarray(t_est), np.asarray(q_est))
            results[tr.name][name] = (s.total_rmse_deg, s.heading_rmse_deg, s.inclination_rmse_deg,
                                      time.perf_counter() - t0, kind)
        row = "  ".join(f"{n}={v[0]:.2f}" for n, v in results[tr.name].items())
        print(f"{tr.name}: {row}", flush=True)

    for metric, col in (("total", 0), ("heading", 1), ("inclination", 2)):
        print(f"\nRMSE {metric} [deg] (BROAD: score intervals vs optical truth; phone: vs phone ORI after 3 s)")
        print(f"{'trial':<44}" + "".join(f"{n:>14}" for n in names))
        for kind in ("broad", "phone"):
            vals = {n: [] for n in names}
            for trial, res in results.items():
                if not res or next(iter(res.values()))[4] != kind:
                    continue
                print(f"{trial[:44]:<44}" + "".join(
                    f"{res[n][col]:>14.2f}" if n in res else f"{'-':>14}" for n in names))
                for n in names:
                    if n in res:
                        vals[n].append(res[n][col])
            if any(vals.values()):
                print(f"{'mean ' + kind:<44}" + "".join(
                    f"{np.mean(vals[n]):>14.2f}" if vals[n] else f"{'-':>14}" for n in names))
    broad = [r for r in results.values() if r and next(iter(r.values()))[4] == "broad"]
    if broad and "ours-default" in names and "vqf-9d" in names:
        ours = np.array([r["ours-default"][0] for r in broad])
        vqf = np.array([r["vqf-9d"][0] for r in broad])
        print(f"\nBROAD mean total: ours-default {ours.mean():.2f} deg vs VQF 9D {vqf.mean():.2f} deg "
              f"(ratio {ours.mean() / vqf.mean():.2f}); worst trial ratio {np.max(ours / vqf):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
