"""The shared recordings as the benchmarks use them: arrays, truth, score intervals, groups.

* BROAD (``../shared/data/broad``): the log's ORI is the optical truth; scored over the trial's
  ``score_intervals_ms``. Group: the trial's kind (undisturbed/disturbed) and motion.
* Tyrex Nexus 5 (``../shared/data/tyrex``): the log's ORI is the phone's own estimate; the truth
  is ``NAME.truth.txt`` (optical, 60 Hz), scored over ``NAME.json``'s intervals. Group: motion.
* Real phone logs (``../shared/data/realphone``) that carry ORI: the phone's own estimate is the
  only reference, scored after the first 3 s.

Every estimate is compared with the reference **at the reference's time stamps**: the estimate
is slerp-interpolated there (``ekf.metrics.interpolate_quat``), as the tyrex metric says.
Peers that need synchronous input get the rows where the gyroscope has a sample, with the latest
accelerometer and magnetometer readings held, and the mean sample period of those rows.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import ekf
from ekf.metrics import interpolate_quat, intervals_mask
from app.stream.logfile import read_log

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("ORIENTATION_LAB_SHARED", REPO.parent / "shared")) / "data"


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


@dataclass
class Recording:
    """One recording: filter rows (t_s, gyr, acc, mag; NaN where a sensor has no sample), the
    reference (t_ms, quaternions) with its score mask, and the phone's own ORI when it has one."""

    name: str
    kind: str                      # "broad", "tyrex" or "phone"
    group: str                     # for leave-one-group-out cross-validation
    disturbed: bool
    t_s: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    ref_t_ms: np.ndarray
    ref_q: np.ndarray
    ref_mask: np.ndarray
    phone_t_ms: np.ndarray | None = None
    phone_q: np.ndarray | None = None
    skip_s: float = 0.0
    _sync: tuple | None = field(default=None, repr=False)

    @property
    def sync(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
        """(t_s, gyr, acc held, mag held, Ts) on the gyroscope's rows, for synchronous peers."""
        if self._sync is None:
            g_rows = ~np.isnan(self.gyr).any(axis=1)
            t = self.t_s[g_rows]
            acc, mag = hold(self.acc)[g_rows], hold(self.mag)[g_rows]
            Ts = float(t[-1] - t[0]) / (len(t) - 1)
            self._sync = (t, np.ascontiguousarray(self.gyr[g_rows]), np.ascontiguousarray(acc),
                          np.ascontiguousarray(mag), Ts)
        return self._sync

    def score(self, t_est_s: np.ndarray, q_est: np.ndarray) -> ekf.metrics.ErrorSummary:
        """RMSE of the estimate, interpolated to the reference's times, over the score mask."""
        q = interpolate_quat(np.asarray(t_est_s, float) * 1000.0, q_est, self.ref_t_ms)
        mask = self.ref_mask & (self.ref_t_ms >= 1000.0 * (self.t_s[0] + self.skip_s))
        return ekf.summarize(q, self.ref_q, mask)

    def score_phone(self) -> ekf.metrics.ErrorSummary | None:
        """The phone's own estimate against the reference (None: no phone ORI, or it is the
        reference)."""
        if self.phone_q is None:
            return None
        return self.score(self.phone_t_ms / 1000.0, self.phone_q)


def _rows(path: Path):
    a = read_log(path).to_arrays()
    rows = ~(np.isnan(a.gyr).all(1) & np.isnan(a.acc).all(1) & np.isnan(a.mag).all(1))
    ori = ~np.isnan(a.ori).any(axis=1)
    return (a.t_ms[rows] / 1000.0, a.gyr[rows], a.acc[rows], a.mag[rows],
            a.t_ms[ori].astype(float), a.ori[ori])


def _intervals(path: Path):
    return json.loads(path.read_text())["score_intervals_ms"] if path.is_file() else None


def load_broad(path: Path) -> Recording:
    t, g, a, m, ot, oq = _rows(path)
    name = path.stem
    iv = _intervals(path.with_suffix(".json"))
    parts = name.split("_")
    disturbed = parts[1] == "disturbed"
    group = "broad-" + "_".join(parts[1:3])
    return Recording(name, "broad", group, disturbed, t, g, a, m, ot, oq, intervals_mask(ot, iv))


def load_tyrex(path: Path, kind: str = "tyrex") -> Recording:
    """A Nexus 5 log ``NAME.txt`` scored against ``NAME.truth.txt`` over ``NAME.json``'s
    intervals; with kind "tyrex-raw", ``path`` is its ``NAME.uncalibrated.txt`` twin (raw
    gyroscope and magnetometer: hundreds of uT of hard iron), scored the same way and never
    among the recordings that choose the defaults."""
    t, g, a, m, pt, pq = _rows(path)
    name = path.name[: -len(".uncalibrated.txt")] if kind == "tyrex-raw" else path.stem
    truth = read_log(path.with_name(name + ".truth.txt")).to_arrays()
    has = ~np.isnan(truth.ori).any(axis=1)
    rt, rq = truth.t_ms[has].astype(float), truth.ori[has]
    meta = json.loads(path.with_name(name + ".json").read_text())
    motion = meta.get("motion", name.split("_")[-1]).lower()
    label = name + "+raw" if kind == "tyrex-raw" else name
    return Recording(label, kind, kind + "-" + motion, bool(meta.get("magnetic_disturbance")),
                     t, g, a, m, rt, rq, intervals_mask(rt, meta["score_intervals_ms"]), pt, pq)


def load_tyrex_raw(path: Path) -> Recording:
    return load_tyrex(path, "tyrex-raw")


def load_phone(path: Path) -> Recording:
    t, g, a, m, ot, oq = _rows(path)
    return Recording(path.stem, "phone", "phone", "disturbance" in path.stem, t, g, a, m, ot, oq,
                     np.ones(len(ot), bool), skip_s=3.0)


def broad_paths() -> list[Path]:
    return sorted((SHARED / "broad").glob("*.txt"))


def tyrex_paths() -> list[Path]:
    d = SHARED / "tyrex"
    return sorted(p for p in d.glob("*.txt")
                  if not p.name.endswith((".truth.txt", ".uncalibrated.txt")))


def tyrex_raw_paths() -> list[Path]:
    return sorted((SHARED / "tyrex").glob("*.uncalibrated.txt"))


def phone_paths() -> list[Path]:
    out = []
    for p in sorted((SHARED / "realphone").glob("*.txt")):
        with open(p, "rb") as f:
            if b"\tORI\t" in f.read():
                out.append(p)
    return out


def load_all(kinds: tuple[str, ...] = ("broad", "tyrex", "phone"),
             only: list[str] | None = None) -> list[Recording]:
    """Every shared recording of the given kinds (names containing one of `only`, if given)."""
    loaders = {"broad": (broad_paths, load_broad), "tyrex": (tyrex_paths, load_tyrex),
               "tyrex-raw": (tyrex_raw_paths, load_tyrex_raw), "phone": (phone_paths, load_phone)}
    out = []
    for kind in kinds:
        paths, load = loaders[kind]
        if not (SHARED / {"phone": "realphone", "tyrex-raw": "tyrex"}.get(kind, kind)).is_dir():
            continue
        for p in paths():
            if only and not any(o in p.stem for o in only):
                continue
            out.append(load(p))
    return out


# ---- the estimators the benchmarks compare ----------------------------------------------------
def run_ours(rec: Recording, settings: ekf.EKFSettings | str = "default"):
    r = ekf.filter_batch(rec.t_s, rec.gyr, rec.acc, rec.mag, settings=settings)
    return rec.t_s, r.quat


def run_vqf(rec: Recording, nine: bool = True, offline: bool = False):
    import vqf
    t, g, a, m, Ts = rec.sync
    if offline:
        out = vqf.offlineVQF(g, a, m if nine else None, Ts, None)
        return t, out["quat9D" if nine else "quat6D"]
    out = vqf.VQF(Ts).updateBatch(g, a, m if nine else None)
    return t, out["quat9D" if nine else "quat6D"]
