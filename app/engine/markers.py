"""Markers: points in a session the user drops with M (an optional label typed afterwards).

They are kept where the session is: the recording in progress gets each one in its timeline
(with its sample position), the replayed session's session.json is rewritten with them,
atomically. A phone's own log has no session.json: its markers stay until it closes.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from app.engine.session import Marker, utc_now


class Markers:
    """The markers of the session shown, oldest first."""

    def __init__(self) -> None:
        self.items: list[Marker] = []

    def replace(self, markers: list[Marker]) -> None:
        self.items = list(markers)

    def add(self, label: str, t_ms: int | None, t0_ms: int | None, recording: Any,
            replay: Any, fed: int) -> str:
        """A new marker at the latest sample; returns the status line (saved where)."""
        t_s = None if t_ms is None or t0_ms is None else (t_ms - t0_ms) / 1000.0
        number = max((m.id for m in self.items), default=0) + 1
        marker = Marker(number, t_ms, t_s, str(label or ""), utc_now())
        self.items.append(marker)
        where = "–" if t_s is None else f"{t_s:.1f} s"
        return f"marker {marker.title} at {where}{self._save(marker, True, recording, replay, fed)}"

    def set_label(self, number: int, label: str, recording: Any, replay: Any) -> str | None:
        for index, marker in enumerate(self.items):
            if marker.id == number:
                self.items[index] = dataclasses.replace(marker, label=str(label or ""))
                return self._save(self.items[index], False, recording, replay, 0) or None
        return None

    def _save(self, marker: Marker, new: bool, recording: Any, replay: Any, fed: int) -> str:
        """Into the recording and the replayed session; a note for the status line."""
        note = ""
        recording = recording if recording is not None and recording.active else None
        if recording is not None:
            if new:
                recording.add_marker(marker, fed)
            else:
                recording.update_marker(marker)
        if replay is not None:
            replay.markers = list(self.items)
            if replay.session is None and recording is None:
                note = " (a phone's log has no session.json: not saved)"
            problem = replay.save_markers()
            if problem:
                note = f" ({problem})"
        elif recording is None:
            note = " (not recording: not saved)"
        return note
