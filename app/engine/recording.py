"""A recording in progress: the engine's side of a session folder.

:class:`SessionRecording` ties a :class:`~app.stream.recorder.Recorder` (raw.txt, flushed at
least twice a second, and session.json, rewritten atomically) and an
:class:`~app.engine.estimates.EstimatesWriter` (estimates.csv: the rows the user saw) to the
engine: the parser's sinks write every line that parses, the timeline entries carry their
sample positions, a recording that starts while a stream runs keeps the engine's state then
(session.json's start_state, see :mod:`app.engine.session`).

Faults never stop the stream: a recording refused at its start (a folder that cannot be made,
too little free space) raises ConfigError and leaves no folder behind (the window shows it, the
engine goes on); a write error later stops the recording with a one-line reason
(:attr:`error`).
"""

from __future__ import annotations

import dataclasses
import platform
import socket
from pathlib import Path
from typing import Any

import ekf
from app import __version__
from app.engine.config import ConfigError
from app.engine.estimates import EstimatesWriter
from app.engine.session import SESSION_FORMAT, Marker, calibration_of, encode_state
from app.stream.recorder import DEFAULT_MAX_BYTES, DEFAULT_MIN_FREE_BYTES, Recorder


def host_info() -> dict[str, str]:
    return {"name": socket.gethostname(), "platform": platform.platform(),
            "python": platform.python_version(), "app_version": __version__}


def setup_info(runner: Any) -> dict[str, Any]:
    """The set-up a session starts with (session.json): settings, calibration, estimator,
    sensors, comparisons."""
    settings = runner.settings or ekf.PRESETS["default"]
    return {"format": SESSION_FORMAT, "settings": settings.to_dict(),
            "calibration": calibration_of(settings), "estimator": runner.estimator_name,
            "sensors": dict(runner.sensors_enabled),
            "comparisons": {"enabled": bool(runner.comparisons),
                            "estimator": runner.comparison_estimator},
            "host": host_info()}


class SessionRecording:
    """Record into `folder` (made if needed; DIR-2, DIR-3, ... when it holds a session:
    :attr:`folder` is where it went). fed_at_start: the engine's sample count now (timeline
    positions count from it); start_state: the engine's state when a stream is already running
    (None: the recording starts with the stream)."""

    def __init__(self, folder: str | Path, runner: Any, fed_at_start: int = 0,
                 start_state: dict[str, Any] | None = None, source: str = "",
                 peer: str | None = None, max_bytes: int = DEFAULT_MAX_BYTES,
                 min_free_bytes: int = DEFAULT_MIN_FREE_BYTES,
                 recorder: Recorder | None = None,
                 estimates: EstimatesWriter | None = None) -> None:
        self.folder = Path(folder)
        info = {**setup_info(runner), "source": source, "phone": peer,
                "start_state": None if start_state is None else encode_state(start_state)}
        if recorder is None:
            try:
                recorder = Recorder(self.folder, runner.settings or ekf.PRESETS["default"],
                                    info=info, max_bytes=max_bytes,
                                    min_free_bytes=min_free_bytes)
            except OSError as error:
                raise ConfigError(str(error)) from None
        else:
            for key, value in info.items():
                recorder.session.setdefault(key, value)
            recorder.session.setdefault("phone", peer)
        self.recorder = recorder
        self.folder = recorder.directory
        if estimates is None:
            try:
                estimates = EstimatesWriter(self.folder / "estimates.csv")
            except OSError as error:
                recorder.discard()
                raise ConfigError(f"cannot write {self.folder / 'estimates.csv'}: "
                                  f"{error.strerror or error}") from None
        self.estimates: EstimatesWriter | None = estimates
        self.fed_at_start = int(fed_at_start)
        # the earliest time of the first output after the start (set by the engine): the
        # origin a replay of the session counts its time from
        self.t0_ms: int | None = None

    # -- state ---------------------------------------------------------------------------------

    @property
    def error(self) -> str | None:
        return self.recorder.error

    @property
    def active(self) -> bool:
        return not self.recorder.closed

    def status(self) -> dict[str, Any]:
        """What the window shows: folder, elapsed_s, bytes, lines, error, active."""
        recorder = self.recorder
        return {"folder": str(self.folder), "elapsed_s": recorder.elapsed_s,
                "bytes": recorder.bytes_written, "lines": recorder.lines_written,
                "error": recorder.error, "active": not recorder.closed}

    # -- timeline ------------------------------------------------------------------------------

    def add_event(self, kind: str, t_ms: int | None, fed: int, **data: Any) -> None:
        self.recorder.add_event(kind, t_ms, sample=max(0, fed - self.fed_at_start), **data)

    def set_settings(self, settings: Any, profile: dict[str, Any] | None, fed: int) -> None:
        """New settings (the timeline entry is the engine's): before the first sample the
        recording starts with them (session.json "settings"); a calibration profile they came
        from is kept under "calibration" with the values it set."""
        recorder = self.recorder
        if fed == self.fed_at_start:
            recorder.set_settings(settings.to_dict())
        if profile is not None:
            recorder.set_calibration({**calibration_of(settings), "profile": profile})

    def set_peer(self, peer: str | None) -> None:
        with self.recorder._lock:
            self.recorder.session["phone"] = peer
            self.recorder._dirty = True

    def add_marker(self, marker: Marker, fed: int) -> None:
        """A marker into the timeline, its t_s counted from the recording's own start (the
        time a replay of it shows; the live plots count from the stream's)."""
        if marker.t_ms is not None:
            start = self.t0_ms if self.t0_ms is not None else marker.t_ms
            marker = dataclasses.replace(marker, t_s=(marker.t_ms - start) / 1000.0)
        event = marker.to_event(max(0, fed - self.fed_at_start))
        self.recorder.add_event("marker", marker.t_ms, **{k: v for k, v in event.items()
                                                         if k not in ("kind", "t_ms", "utc")})

    def update_marker(self, marker: Marker) -> None:
        """A marker's new label."""
        recorder = self.recorder
        with recorder._lock:
            for event in recorder.session["timeline"]:
                if event.get("kind") == "marker" and event.get("id") == marker.id:
                    event["label"] = marker.label
            recorder._dirty = True

    # -- output --------------------------------------------------------------------------------

    def write_rows(self, rows: Any) -> str | None:
        """Rows to estimates.csv; returns a warning when the file stopped."""
        writer = self.estimates
        if writer is None:
            return None
        writer.write(rows)
        if writer.error is not None:
            self.estimates = None
            return f"estimates.csv stopped: {writer.error}"
        return None

    def tick(self) -> None:
        self.recorder.tick()
        if self.estimates is not None:
            self.estimates.flush()

    def close(self, stats: dict[str, Any] | None = None) -> None:
        if stats is not None and not self.recorder.closed:
            self.recorder.set_stats(stats)
        if self.estimates is not None:
            self.estimates.close()
            self.estimates = None
        self.recorder.close()
