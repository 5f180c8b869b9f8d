"""Test doubles and snapshot builders for the widget tests (imported by conftest and tests).

The fake engine has the engine's interface (start/stop/poll/send): poll() hands out the queued
snapshots one per call and send() records the commands, so the window's behaviour is tested
without the engine's thread timing.
"""

from __future__ import annotations

from collections import deque

import numpy as np

import ekf
from app.engine.snapshot import (FilterStatus, PlotChunk, Snapshot, StreamHealth,
                                 UserFilterStatus)

_FLAGS = set(ekf.Flags.__dataclass_fields__)
_DIAGNOSTICS = set(ekf.Diagnostics.__dataclass_fields__)


def status_of(**fields) -> FilterStatus:
    """A FilterStatus from flat names: flags (acc_rejected, ...) and diagnostics (acc_norm, g,
    ...) go where they are declared; sensors_enabled and estimator as they are."""
    flags = {k: v for k, v in fields.items() if k in _FLAGS}
    diagnostics = {k: v for k, v in fields.items() if k in _DIAGNOSTICS}
    rest = {k: v for k, v in fields.items() if k not in _FLAGS | _DIAGNOSTICS}
    return FilterStatus(flags=ekf.Flags(**flags), diagnostics=ekf.Diagnostics(**diagnostics),
                        **rest)


class FakeEngine:
    def __init__(self) -> None:
        self.snapshots: deque[Snapshot] = deque()
        self.commands: list[object] = []
        self.started = False
        self.stop_calls = 0

    def start(self) -> None:
        self.started = True

    def stop(self) -> None:
        self.stop_calls += 1

    def poll(self) -> Snapshot | None:
        return self.snapshots.popleft() if self.snapshots else None

    def send(self, command: object) -> None:
        self.commands.append(command)

    def commands_of(self, kind: type) -> list:
        return [c for c in self.commands if isinstance(c, kind)]


def quat_about_z(degrees: float) -> np.ndarray:
    half = np.radians(degrees) / 2
    return np.array([np.cos(half), 0.0, 0.0, np.sin(half)])


def make_chunk(t0_s: float, count: int = 50, rate_hz: float = 100.0,
               acc_rejected_every: int = 0) -> PlotChunk:
    """`count` samples per sensor from t0_s at rate_hz, gentle sines, a 1g accelerometer;
    PHONE 1° off OWN in each angle, 3 ms later; the error 1.7° total, 1° heading."""
    t = t0_s + np.arange(count) / rate_hz
    phase = 2 * np.pi * 0.5 * t
    acc = np.column_stack([0.3 * np.sin(phase), 0.2 * np.cos(phase), 9.81 + 0 * t])
    gyr = np.column_stack([0.1 * np.sin(phase), 0.05 + 0 * t, 0.02 * np.cos(phase)])
    mag = np.column_stack([5 * np.sin(phase), 15 + 0 * t, -48 + 0 * t])
    acc_rejected = np.zeros(count, bool)
    if acc_rejected_every:
        acc_rejected[::acc_rejected_every] = True
    own = np.column_stack([30 * np.sin(phase), 5 + 0 * t, -3 + 0 * t])
    phone = own + 1.0
    error = np.column_stack([np.full(count, np.sqrt(3.0)), np.ones(count), np.full(count, 1.4)])
    return PlotChunk(t_acc=t, acc=acc, acc_rejected=acc_rejected, t_gyr=t, gyr=gyr,
                     t_mag=t, mag=mag, mag_rejected=np.zeros(count, bool),
                     t_est=t, own_euler_deg=own, t_ori=t + 0.003, phone_euler_deg=phone,
                     t_err=t + 0.003, error_deg=error)


_NO_VALUE = object()


def make_snapshot(seq: int, t_s: float, count: int = 50, phone_quat=_NO_VALUE,
                  **status_fields) -> Snapshot:
    """A snapshot at t_s with `count` plot samples; flat status fields (see status_of)."""
    status = status_of(**{**dict(acc_norm=9.83, g=9.81, acc_gate=0.5, mag_norm=50.4,
                                 mag_expected=50.5, mag_gate=5.0, initialised=True),
                          **status_fields})
    health = StreamHealth(connection_state="connected", peer="192.168.1.23:51234",
                          listen_addresses=["192.168.1.10"], port=3400,
                          rates_hz={"ACC": 100.0, "GYR": 100.0, "MAG": 50.0, "ORI": 100.0},
                          lines_per_s=350.0, lines_total=350 * seq, damaged=2, unknown=1,
                          out_of_order=3)
    return Snapshot(seq=seq, t_ms=int(round((t_s + count / 100.0) * 1000)), t0_ms=0,
                    own_quat=quat_about_z(10.0 * seq), own_cov=np.eye(4) * 1e-4,
                    phone_quat=(quat_about_z(10.0 * seq + 1.0) if phone_quat is _NO_VALUE
                                else phone_quat), status=status,
                    plot=make_chunk(t_s, count), health=health)


def user_status(**fields) -> UserFilterStatus:
    """YOURS running my_filter.py at 12° about up (fields override)."""
    base = dict(name="my_filter.py", path="/tmp/my_filter.py", state="running",
                quat=quat_about_z(12.0), cov=np.eye(4) * 1e-4, generation=1)
    return UserFilterStatus(**{**base, **fields})


def make_user_snapshot(seq: int, t_s: float, user: UserFilterStatus | None = None,
                       **fields) -> Snapshot:
    """make_snapshot with YOURS loaded: its Euler angles 2° off OWN's, its errors 1° larger."""
    snapshot = make_snapshot(seq, t_s, **fields)
    chunk = snapshot.plot
    chunk.t_user = chunk.t_est.copy()
    chunk.user_euler_deg = chunk.own_euler_deg + 2.0
    chunk.t_user_err = chunk.t_err.copy()
    chunk.user_error_deg = chunk.error_deg + 1.0
    snapshot.user = user if user is not None else user_status()
    return snapshot
