"""What the engine hands the GUI (or `serve`) once per display frame.

The commands going the other way are in :mod:`app.engine.commands`. Plain data only (numpy arrays, dataclasses): no Qt, no sockets, so both the engine thread
and the widgets can import it, and tests can build snapshots by hand.

Frames and units: quaternions are w-first, sensor -> ENU, w >= 0. Times are the phone's
clock in milliseconds (after clock alignment). Angles in degrees unless the name says rad.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

import ekf



@dataclass
class FilterStatus:
    """The main estimator's lights and their reasons: its flags and diagnostics as the estimator
    declares them (ekf.Flags, ekf.Diagnostics; units in their README tables), which sensors are
    switched in, the estimator's name and whether it has started (from its first readings)."""

    sensors_enabled: dict[str, bool] = field(
        default_factory=lambda: {"gyr": True, "acc": True, "mag": True})
    flags: ekf.Flags = field(default_factory=ekf.Flags)
    diagnostics: ekf.Diagnostics = field(default_factory=ekf.Diagnostics)
    estimator: str = "ekf"
    initialised: bool = False


@dataclass
class Comparison:
    """One sensor combination run side by side on the same stream (task 12, live), compared with
    PHONE at PHONE's time stamps: RMSE and latest error of the total angle, heading and
    inclination [deg], over `samples` ORI samples (NaN before the first)."""

    name: str                     # "gyr+acc+mag", "gyr+acc", ...
    quat: np.ndarray | None
    rmse_deg: tuple[float, float, float] = (float("nan"),) * 3
    latest_deg: tuple[float, float, float] = (float("nan"),) * 3
    samples: int = 0


@dataclass
class StreamHealth:
    connection_state: str = "waiting"        # "waiting" | "connected" | "disconnected" | "replaying" | "finished"
    peer: str | None = None                  # "192.168.1.23:51234" when connected
    listen_addresses: list[str] = field(default_factory=list)  # the PC's LAN IPv4 addresses
    port: int | None = None
    rates_hz: dict[str, float] = field(default_factory=dict)   # per tag
    lines_per_s: float = 0.0
    lines_total: int = 0
    damaged: int = 0
    unknown: int = 0
    too_long: int = 0
    out_of_order: int = 0
    clock_quirks: list[str] = field(default_factory=list)     # human-readable, e.g. "ACC clock +131072000 ms (aligned)"
    warnings: list[str] = field(default_factory=list)         # rate-limited messages for the status bar
    damaged_reasons: dict[str, int] = field(default_factory=dict)   # e.g. {"ACC out of range": 2}
    sessions: int = 0                        # new sessions (a clock that did not continue)
    reorder_window_ms: int = 100             # the time orderer's window now (adapts to lags)
    lags_ms: dict[str, int] = field(default_factory=dict)     # learned lag per tag
    waiting_peers: list[str] = field(default_factory=list)    # connections waiting to stream
    connections_closed: dict[str, int] = field(default_factory=dict)  # reason -> count
    allowed: list[str] = field(default_factory=list)          # who may connect (empty: anyone)
    recording: str | None = None             # "recording into DIR (1.2 MB)" / "recording stopped: ..."


def lag_text(health: StreamHealth) -> str:
    """"reorder window 197 ms (MAG 150 ms behind)": the window and the tags that widen it."""
    lags = ", ".join(f"{tag} {lag} ms behind" for tag, lag in sorted(health.lags_ms.items())
                     if lag + lag // 4 + 10 > 100)
    return f"reorder window {health.reorder_window_ms} ms" + (f" ({lags})" if lags else "")


@dataclass
class PlotChunk:
    """New samples since the previous snapshot (each array may be empty).

    t_* are seconds since the session's start (Snapshot.t0_ms on the phone's clock), float64.
    Rejected masks are per sample. Euler angles [deg] are z-y-x (yaw, pitch, roll:
    R = Rz(yaw) Ry(pitch) Rx(roll)), wrapped: yaw and roll in [-180, 180], pitch in [-90, 90].
    OWN's are at our estimate times (t_est), PHONE's at its own sample times (t_ori); the
    errors of OWN against PHONE at PHONE's times (t_err), our estimate slerped to them.
    """

    t_acc: np.ndarray = field(default_factory=lambda: np.empty(0))
    acc: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    acc_rejected: np.ndarray = field(default_factory=lambda: np.empty(0, bool))
    t_gyr: np.ndarray = field(default_factory=lambda: np.empty(0))
    gyr: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    t_mag: np.ndarray = field(default_factory=lambda: np.empty(0))
    mag: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    mag_rejected: np.ndarray = field(default_factory=lambda: np.empty(0, bool))
    t_est: np.ndarray = field(default_factory=lambda: np.empty(0))
    own_euler_deg: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    t_ori: np.ndarray = field(default_factory=lambda: np.empty(0))
    phone_euler_deg: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    t_err: np.ndarray = field(default_factory=lambda: np.empty(0))
    error_deg: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))  # total, heading, inclination


@dataclass(frozen=True)
class EngineFailure:
    """An exception inside the engine: what the window shows and `serve` prints.

    number counts failures from 1; message is one line with the exception and where it was
    raised (file, line, function); details the whole traceback (the "copy details" text);
    when the UTC time; fatal: the engine stopped after it (too many failures in a row)."""

    number: int
    message: str
    details: str
    when: str
    fatal: bool = False


@dataclass
class Snapshot:
    seq: int = 0
    t_ms: int | None = None                   # latest phone time processed
    own_quat: np.ndarray | None = None        # (4,)
    own_cov: np.ndarray | None = None         # covariance of the quaternion state (4,4)
    phone_quat: np.ndarray | None = None      # (4,) latest ORI
    status: FilterStatus = field(default_factory=FilterStatus)
    comparisons: list[Comparison] = field(default_factory=list)
    comparison_estimator: str = "ekf"         # the estimator the comparisons run
    t0_ms: int | None = None                  # the session's start on the phone's clock
    plot: PlotChunk = field(default_factory=PlotChunk)
    health: StreamHealth = field(default_factory=StreamHealth)
    # when replaying: position_s, duration_s, speed, paused, loop, finished, name, line, lines,
    # following_timeline, has_timeline, session_file, indexed, index_progress, index_seconds
    replay: dict[str, Any] | None = None
    failures: list[EngineFailure] = field(default_factory=list)   # the latest, oldest first
    # the markers of the session shown (app.engine.session.Marker), oldest first
    markers: tuple = ()
    # a recording in progress (or the last one): folder, elapsed_s, bytes, lines, error, active
    recording: dict[str, Any] | None = None
    # a replay's whole session for the plots, once indexed (app.engine.session_index.SessionPlot;
    # shared, never changed once handed out)
    session_plot: Any = None
