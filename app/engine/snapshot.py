"""What the engine hands the GUI (or `serve`) once per display frame.

The commands going the other way are in :mod:`app.engine.commands`. Plain data only (numpy arrays, dataclasses): no Qt, no sockets, so both the engine thread
and the widgets can import it, and tests can build snapshots by hand.

Frames and units: quaternions are w-first, sensor -> ENU, w >= 0. Times are the phone's
clock in milliseconds (after clock alignment). Angles in degrees unless the name says rad.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import ekf
from app.engine.processing.configuration import ConfigurationView
from app.engine.errors import EngineFailure, UserProblem
from app.stream.forwarder import ForwardStatus


@dataclass
class FilterStatus:
    """The main estimator's lights and their reasons: its flags and diagnostics as the estimator
    declares them (ekf.Flags, ekf.Diagnostics; units in their tables in docs/filter.md), which
    sensors are switched in, the estimator's name and whether it has started (from its first
    readings); settings: the ekf.EKFSettings the filter runs with now (None from a test double)."""

    sensors_enabled: dict[str, bool] = field(
        default_factory=lambda: {"gyr": True, "acc": True, "mag": True})
    flags: ekf.Flags = field(default_factory=ekf.Flags)
    diagnostics: ekf.Diagnostics = field(default_factory=ekf.Diagnostics)
    estimator: str = "ekf"
    initialised: bool = False
    settings: Any = None


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
    forward: ForwardStatus | None = None     # --forward HOST:PORT: the copy of the phone's lines
    damaged_reasons: dict[str, int] = field(default_factory=dict)   # e.g. {"ACC out of range": 2}
    sessions: int = 0                        # new sessions (a clock that did not continue)
    reorder_window_ms: int = 100             # the time orderer's window now (adapts to lags)
    lags_ms: dict[str, int] = field(default_factory=dict)     # learned lag per tag
    waiting_peers: list[str] = field(default_factory=list)    # connections waiting to stream
    connections_closed: dict[str, int] = field(default_factory=dict)  # reason -> count
    allowed: list[str] = field(default_factory=list)          # who may connect (empty: anyone)
    recording: str | None = None             # "recording into DIR (1.2 MB)" / "recording stopped: ..."
    connect_to: list[str] = field(default_factory=list)   # what to type into the phone's app
    connect_hint: str = ""                   # how the phone reaches the source, one line


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
    # Your filter (YOURS): its Euler angles at our estimate times (NaN while it has none) and
    # its errors against PHONE at PHONE's times, as OWN's.
    t_user: np.ndarray = field(default_factory=lambda: np.empty(0))
    user_euler_deg: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    t_user_err: np.ndarray = field(default_factory=lambda: np.empty(0))
    user_error_deg: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    # Innovations for the consistency view, one entry per measurement update, on their own time
    # axis: which estimator (INNOVATION_SOURCES), which sensor (INNOVATION_SENSORS), the
    # innovation nu (NaN-padded to 3 components), its covariance S (NaN-padded to 3x3) and
    # whether the update was used (False: a gate rejected it).
    t_innovation: np.ndarray = field(default_factory=lambda: np.empty(0))
    innovation_source: np.ndarray = field(default_factory=lambda: np.empty(0, np.int8))
    innovation_sensor: np.ndarray = field(default_factory=lambda: np.empty(0, np.int8))
    innovation: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    innovation_cov: np.ndarray = field(default_factory=lambda: np.empty((0, 3, 3)))
    innovation_accepted: np.ndarray = field(default_factory=lambda: np.empty(0, bool))


#: innovation_source codes: our EKF (the main estimator) and your filter.
INNOVATION_SOURCES = ("OWN", "YOURS")
#: innovation_sensor codes.
INNOVATION_SENSORS = ("acc", "mag", "gyr")


@dataclass
class UserHistory:
    """YOURS over the session so far, recomputed after a reload by re-running the replay's log
    up to the current position with the new code: replaces the curves drawn before. t_ms (N,)
    our estimate times on the phone's clock, euler_deg (N, 3) wrapped; t_err_ms (M,) PHONE's
    times, error_deg (M, 3) total, heading, inclination against PHONE."""

    t_ms: np.ndarray
    euler_deg: np.ndarray
    t_err_ms: np.ndarray
    error_deg: np.ndarray


@dataclass
class UserFilterStatus:
    """Your filter ("YOURS", a Python file you wrote) as the engine runs it beside ours.

    state: "loading" (its process loads the file) | "running" | "paused" (a problem: fix the
    file and save it) | "catching up" (re-running after a reload or seek, in the background) |
    "failed to load". quat: its latest output
    (w >= 0, sensor -> ENU; the last good one while paused); cov: P's quaternion block when the
    filter returns P. The lights are None when the filter does not report them. missing_steps:
    course steps still raising NotImplementedError (skipped), e.g. "mu_g (my_filter.py:61)".
    time_per_sample_s: recent time in your step() per call; slow: it could not keep up with the
    stream and got only used_fraction of the samples (decimated) instead of holding up the
    engine. lag_s: how long its results take to come back from its process (95th percentile
    of the last seconds; YOURS lags OWN by that much); backlog_rows: rows handed to it and not
    answered yet. printed: the last lines it printed (printed_total: how many so far).
    generation counts loads and reloads; history is set after a re-run (see UserHistory)."""

    name: str = ""
    path: str = ""
    sha256: str = ""
    state: str = "failed to load"
    quat: np.ndarray | None = None
    cov: np.ndarray | None = None
    acc_disturbed: bool | None = None
    mag_disturbed: bool | None = None
    standstill: bool | None = None
    missing_steps: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    problem: UserProblem | None = None
    time_per_sample_s: float = float("nan")
    slow: bool = False
    used_fraction: float = 1.0
    steps: int = 0
    angle_to_phone_deg: float = float("nan")
    rmse_deg: float = float("nan")
    message: str = ""
    generation: int = 0
    history: UserHistory | None = None
    progress: float | None = None            # of a catch-up, 0..1
    lag_s: float = float("nan")
    backlog_rows: int = 0
    printed: list[str] = field(default_factory=list)
    printed_total: int = 0


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
    user: UserFilterStatus | None = None      # your filter (YOURS), when one is loaded
    # the markers of the session shown (app.engine.sessions.session.Marker), oldest first
    markers: tuple = ()
    preparing: bool = False                   # the engine compiles/loads its kernels (start)
    # a recording in progress (or the last one): folder, elapsed_s, bytes, lines, error, active
    recording: dict[str, Any] | None = None
    # a replay's whole session for the plots, once indexed (app.engine.sessions.index.SessionPlot;
    # shared, never changed once handed out)
    session_plot: Any = None
    # samples of each tag fed to the estimators in this session, {"gyr", "acc", "mag", "ori"}
    # (empty: not known, e.g. a test double): which sensors the stream delivers
    session_samples: dict[str, int] = field(default_factory=dict)
    # the filter's configuration over time (app.engine.processing.configuration): what the pass
    # applies, what of a replayed recording is yours (None: a test double)
    configuration: ConfigurationView | None = None


#: A sensor with no sample after this much phone time of the session is "not in this stream".
NO_SENSOR_AFTER_MS = 2000
SENSOR_NAMES = {"gyr": "gyroscope", "acc": "accelerometer", "mag": "magnetometer"}


def absent_sensors(snapshot: Snapshot) -> frozenset[str]:
    """The sensors ("gyr", "acc", "mag") the stream has not delivered although the session has
    run NO_SENSOR_AFTER_MS of phone time (other tags arriving): a log without a gyroscope gives
    {"gyr"}. Empty while the session is younger, and when the counts are not known."""
    counts = snapshot.session_samples
    if (not counts or snapshot.t_ms is None or snapshot.t0_ms is None
            or snapshot.t_ms - snapshot.t0_ms < NO_SENSOR_AFTER_MS):
        return frozenset()
    return frozenset(sensor for sensor in SENSOR_NAMES if not counts.get(sensor, 0))


def absent_text(sensor: str) -> str:
    """"no gyroscope in this stream"."""
    return f"no {SENSOR_NAMES.get(sensor, sensor)} in this stream"


class PlotBuffer:
    """PlotChunk pieces waiting for the next poll, bounded by a number of estimate rows."""

    def __init__(self, max_rows: int) -> None:
        self.max_rows = max_rows
        self.pieces: deque[PlotChunk] = deque()
        self.rows = 0

    def add(self, piece: PlotChunk) -> None:
        self.pieces.append(piece)
        self.rows += max(len(piece.t_est), len(piece.t_acc), len(piece.t_gyr))
        while self.rows > self.max_rows and len(self.pieces) > 1:
            old = self.pieces.popleft()
            self.rows -= max(len(old.t_est), len(old.t_acc), len(old.t_gyr))

    def take(self) -> PlotChunk:
        pieces = list(self.pieces)
        self.pieces.clear()
        self.rows = 0
        if not pieces:
            return PlotChunk()
        if len(pieces) == 1:
            return pieces[0]
        return PlotChunk(**{name: np.concatenate([getattr(p, name) for p in pieces])
                            for name in PlotChunk.__dataclass_fields__})
