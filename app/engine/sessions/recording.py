"""Recording: a recording in progress (the engine's side of a session folder) and the engine's
recording lane (recordings started and stopped by command at any time).

:class:`SessionRecording` ties a :class:`~app.stream.recorder.Recorder` (raw.txt, flushed at
least twice a second, and session.json, rewritten atomically) and an
:class:`~app.engine.offline.filtering.EstimatesWriter` (estimates.csv: the rows the user saw) to
the engine: the parser's sinks write every line that parses, the timeline entries carry their
sample positions, a recording that starts while a stream runs keeps the engine's state then
(session.json's start_state, see :mod:`app.engine.sessions.session`).

:class:`RecordingLane` holds the recording in progress (or None) and the status of the last one.
While it records, the parser's raw sinks write every line that parses into its raw.txt (except
the lines a seek replays up to its target, which were not watched), the estimate rows go into
its estimates.csv and the timeline entries into its session.json.

Faults never stop the stream: a recording refused at its start (a folder that cannot be made,
too little free space) raises ConfigError and leaves no folder behind (the window shows it, the
engine goes on); a write error later (disk full, folder removed, size or free-space limit) stops
the recording with a one-line reason (:attr:`SessionRecording.error`) while the stream and the
estimates go on.
"""
from __future__ import annotations

import dataclasses
import logging
import platform
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import ekf
from app import __version__
from app.engine.commands import StartRecording
from app.engine.config import ConfigError, megabytes
from app.engine.offline.filtering import EstimatesWriter
from app.engine.processing.configuration import Change
from app.engine.processing.health import HealthTracker, stats_dict
from app.engine.processing.pipeline import Pipeline
from app.engine.sessions.session import (SESSION_FORMAT, Marker, calibration_of,
                                         default_session_folder, encode_state)
from app.engine.snapshot import StreamHealth
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
        self.recorder.set_phone(peer)

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
        self.recorder.relabel_marker(marker.id, marker.label)

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


log = logging.getLogger("orientation_lab.engine")


class RecordingLane:
    """The recording in progress (:attr:`current`) and the last one's folder and status.
    health: where the lane's one-line messages go."""

    def __init__(self, pipeline: Pipeline, health: HealthTracker) -> None:
        self.pipeline = pipeline
        self._health = health
        self.current: SessionRecording | None = None
        self.last_folder: Path | None = None
        self.last_status: dict[str, Any] | None = None
        self._reported = False           # the current recording's error was reported
        self._unwatched = False          # a seek's re-run: neither its lines nor its rows

    @property
    def active(self) -> bool:
        return self.current is not None and self.current.active

    def _say(self, text: str) -> None:
        self._health.warn("recording", text, force=True)

    # -- start and stop --------------------------------------------------------------------------

    def attach(self, recording: SessionRecording) -> None:
        """Record into `recording` from now on."""
        self.current = recording
        self._reported = False
        self.last_folder = recording.folder
        self.watch()

    def start(self, command: StartRecording, source_kind: str, peer: str | None,
              flush: Callable[[], None]) -> None:
        """StartRecording: a new session folder; flush() first hands the rows so far to their
        consumers (they belong to before the recording)."""
        if self.active:
            self._say(f"already recording into {self.current.folder}")
            return
        folder = Path(command.folder) if command.folder else None
        try:
            folder = folder or default_session_folder()
            max_bytes = DEFAULT_MAX_BYTES if command.max_mb is None else megabytes(command.max_mb)
            min_free = DEFAULT_MIN_FREE_BYTES if command.min_free_mb is None \
                else megabytes(command.min_free_mb)
            pipeline = self.pipeline
            running = pipeline.fed_total > 0 or pipeline.orderer.pending > 0
            flush()
            recording = SessionRecording(
                folder, pipeline.runner, fed_at_start=pipeline.fed_total,
                start_state=pipeline.start_state() if running else None,
                source=source_kind, peer=peer,
                max_bytes=max_bytes, min_free_bytes=min_free)
        except (ConfigError, OSError) as error:
            self._say(f"cannot record: {error}")
            self.last_status = {"folder": str(folder or ""), "elapsed_s": 0.0, "bytes": 0,
                                "lines": 0, "error": f"cannot record: {error}",
                                "active": False, "at": time.time()}
            return
        self.attach(recording)
        self.event("recording", folder=str(recording.folder))
        self._say(f"recording into {recording.folder}")

    def stop(self, flush: Callable[[], None], health: StreamHealth) -> bool:
        """StopRecording: flush() hands the rows up to now to estimates.csv, then the recording
        closes with the stream's `health`. False when nothing was recording."""
        if not self.active:
            self._say("not recording")
            return False
        folder = self.current.folder
        flush()
        self.close(health)
        self._say(f"recording saved in {folder}")
        return True

    def close(self, health: StreamHealth) -> None:
        """Close the recording (if any) with the stream's `health`; its status stays."""
        recording, self.current = self.current, None
        self.pipeline.set_raw_sinks(None, None)
        if recording is not None:
            self.last_status = {**recording.status(), "active": False}
            recording.close(stats_dict(health))

    # -- while recording -----------------------------------------------------------------------

    def watch(self) -> None:
        """The lines the parser takes go into raw.txt and the rows into estimates.csv (when
        recording)."""
        self._unwatched = False
        if self.active:
            recorder = self.current.recorder
            self.pipeline.set_raw_sinks(recorder.write_line, recorder.write_block)

    def unwatch(self) -> None:
        """The lines the parser takes now, and their rows, are not watched (a seek's re-run):
        not recorded."""
        self._unwatched = True
        self.pipeline.set_raw_sinks(None, None)

    def event(self, kind: str, **data: Any) -> None:
        """A timeline entry at the latest sample (when recording)."""
        if self.active:
            pipeline = self.pipeline
            self.current.add_event(kind, pipeline.runner.latest_t_ms, pipeline.fed_total, **data)

    def applied(self, change: Change, data: dict[str, Any]) -> None:
        """A change of the configuration applied now: its timeline entry (an alignment without
        PHONE's orientation changed nothing: none). New settings before the recording's first
        sample are its own (session.json "settings"); the calibration profile they came from is
        kept."""
        if not self.active or (change.kind == "align_heading"
                               and data.get("turned_deg") is None):
            return
        if change.kind == "settings":
            self.current.set_settings(change.settings, change.calibration,
                                      self.pipeline.fed_total)
        self.event(change.kind, **change.event_data(), **data)

    def output_starts(self, first_ms: int | None) -> None:
        """The first output of a recording sets its time origin, as a replay of it counts."""
        if self.active and self.current.t0_ms is None:
            self.current.t0_ms = first_ms

    def write_rows(self, rows: Any) -> None:
        if self.current is not None and not self._unwatched:
            warning = self.current.write_rows(rows)
            if warning:
                self._health.warn("estimates", warning, force=True)

    def set_peer(self, peer: str | None) -> None:
        if self.current is not None:
            self.current.set_peer(peer)

    def set_stats(self, health: StreamHealth) -> None:
        if self.active:
            self.current.recorder.set_stats(stats_dict(health))

    def tick(self) -> None:
        """Once a pass: flush what is due; a recording that stopped (write error, size or
        free-space limit) is reported once and its estimates.csv stops with it (the session
        ends there)."""
        recording = self.current
        if recording is None:
            return
        recording.tick()
        if recording.error is None or self._reported:
            return
        self._reported = True
        log.error("recording stopped: %s", recording.error)
        self._say(f"recording stopped: {recording.error} (the stream and the estimates go on)")
        if recording.estimates is not None:
            recording.estimates.close()
            recording.estimates = None

    # -- what the window shows -------------------------------------------------------------------

    def status(self) -> dict[str, Any] | None:
        """Snapshot.recording: the recording in progress, else the last one's status."""
        return self.current.status() if self.current is not None else self.last_status

    def text(self) -> str | None:
        """StreamHealth.recording: "recording into DIR (1.2 MB)" or why it stopped."""
        recording = self.current
        if recording is None:
            if self.last_status and self.last_status.get("error"):
                return f"recording stopped: {self.last_status['error']}"
            return None
        if recording.error is not None:
            return f"recording stopped: {recording.error}"
        return (f"recording into {recording.folder} "
                f"({recording.recorder.bytes_written / 2**20:.1f} MB)")
