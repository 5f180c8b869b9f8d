"""Innovations for the consistency view: our EKF's (on request) and the user's filter's.

Our EKF runs compiled over whole chunks and keeps only the NIS of its latest update, so the
per-update innovation vector and its covariance S are not in its outputs; the compiled batch
path is not touched for them. Instead, while the consistency view is open
(:class:`~app.engine.commands.SetConsistencyEnabled`), :class:`InnovationProbe` runs a *twin*:
before each chunk it copies the main EKF's state (``snapshot()``, the one format every EKF
shares), then feeds the same rows one sensor at a time and, before each accelerometer and
magnetometer update, reads the prior (q, P) from the public ``quat``/``cov`` and computes the
course's innovation of that reading (eqs. 7 and 8)::

    nu = y - Q(q)^T v0,   S = H P H^T + R,   H = [dQ/dq_i^T v0]_i,   v0 = g0 or m0

and after the update the gate's decision (the flags). For the ``course`` preset this is exactly
the filter's own innovation (its NIS equals the filter's diagnostic NIS). For the default
preset, whose accelerometer update sees a low-passed reading and whose magnetometer update is
heading-only, it is the consistency of each raw reading with the prediction under the plain
course models. The twin restarts from the main state every chunk, so it never drifts and every
command applied to the main estimator applies to it.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

import ekf
import ekf.quaternion as quat
from app.engine.snapshot import INNOVATION_SENSORS, INNOVATION_SOURCES

OWN, YOURS = (INNOVATION_SOURCES.index(name) for name in ("OWN", "YOURS"))
SENSOR_CODE = {name: code for code, name in enumerate(INNOVATION_SENSORS)}
MAX_PENDING = 100_000       # records kept for the next publish at most (oldest dropped)


def course_innovation(q: np.ndarray, P: np.ndarray, y: np.ndarray, R: np.ndarray,
                      v0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """nu = y - Q(q)^T v0 and S = H P H^T + R for the model y = Q(q)^T v0 + e (P: q's 4x4)."""
    H = np.column_stack([dQ.T @ v0 for dQ in quat.dQ_dq(q)])
    return y - quat.to_matrix(q).T @ v0, H @ P @ H.T + R


class InnovationBuffer:
    """Innovation records waiting for the next publish, packed into PlotChunk's fields."""

    def __init__(self, max_records: int = MAX_PENDING) -> None:
        self.records: deque[tuple] = deque(maxlen=max_records)

    def add(self, t: float, source: int, sensor: str, nu: np.ndarray, S: np.ndarray,
            accepted: bool) -> None:
        self.records.append((t, source, SENSOR_CODE[sensor], nu, S, accepted))

    def __len__(self) -> int:
        return len(self.records)

    def take(self) -> dict[str, np.ndarray]:
        """t_innovation, innovation_source, innovation_sensor, innovation (n, 3) and
        innovation_cov (n, 3, 3) NaN-padded, innovation_accepted; empties when none."""
        records = list(self.records)
        self.records.clear()
        n = len(records)
        nu = np.full((n, 3), np.nan)
        S = np.full((n, 3, 3), np.nan)
        for i, record in enumerate(records):
            k = len(record[3])
            nu[i, :k] = record[3]
            S[i, :k, :k] = record[4]
        return {"t_innovation": np.array([r[0] for r in records], dtype=float),
                "innovation_source": np.array([r[1] for r in records], dtype=np.int8),
                "innovation_sensor": np.array([r[2] for r in records], dtype=np.int8),
                "innovation": nu, "innovation_cov": S,
                "innovation_accepted": np.array([r[5] for r in records], dtype=bool)}


class InnovationProbe:
    """Our EKF's innovations, from a twin restarted from the main EKF's state every chunk."""

    def __init__(self, buffer: InnovationBuffer) -> None:
        self.buffer = buffer
        self._twin: ekf.Estimator | None = None

    def capture(self, main: ekf.Estimator) -> dict | None:
        """The main estimator's state before a chunk (None: it is no EKF, nothing to show)."""
        if main.name not in ("ekf", "course") or main.cov is None:
            return None
        return main.snapshot()

    def _twin_for(self, snapshot: dict) -> ekf.Estimator:
        twin = self._twin
        if twin is None or twin.settings is not snapshot["settings"]:
            twin = self._twin = ekf.make_estimator("ekf", snapshot["settings"])
        twin.restore(snapshot)
        return twin

    def replay(self, snapshot: dict, t_s: np.ndarray, gyr: np.ndarray, acc: np.ndarray,
               mag: np.ndarray) -> None:
        """Feed the rows the main estimator just ran to the twin; record each acc/mag update."""
        twin = self._twin_for(snapshot)
        s = twin.settings
        g0 = np.array([0.0, 0.0, s.g])
        Ra = np.asarray(s.acc_noise_cov, float)
        Rm = np.asarray(s.mag_noise_cov, float)
        m0 = np.array(snapshot["state"]["m0"], float) if snapshot["state"]["m0_valid"] else None
        has = [~np.isnan(x).any(axis=1) for x in (gyr, acc, mag)]
        for k in range(len(t_s)):
            t = float(t_s[k])
            if has[0][k]:
                twin.update_gyr(t, gyr[k])
            if has[1][k]:
                self._update(twin, t, "acc", acc[k], Ra, g0)
            if has[2][k]:
                if m0 is None and math.isfinite(twin.diagnostics.mag_reference_dip_deg):
                    state = twin.snapshot()["state"]     # m0 was just learned
                    m0 = np.array(state["m0"], float) if state["m0_valid"] else None
                self._update(twin, t, "mag", mag[k], Rm, m0)
            if not (has[0][k] or has[1][k] or has[2][k]):
                twin.step(t)

    def _update(self, twin: ekf.Estimator, t: float, sensor: str, y: np.ndarray, R: np.ndarray,
                v0: np.ndarray | None) -> None:
        twin.step(t)                                # the time update to t: the prior
        record = None
        if twin.initialised and v0 is not None:
            record = course_innovation(twin.quat, twin.cov[:4, :4], y, R, v0)
        if sensor == "acc":
            twin.update_acc(t, y)
            accepted = not twin.flags.acc_rejected
        else:
            twin.update_mag(t, y)
            accepted = not twin.flags.mag_rejected
        if record is not None and twin.enabled[sensor]:
            self.buffer.add(t, OWN, sensor, record[0], record[1], accepted)
