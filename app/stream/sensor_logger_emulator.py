"""A phone running Sensor Logger with HTTP Push on, for tests and demos: a log pushed as
Sensor Logger's batches (`orientation-lab send LOG --as sensor-logger --url URL`).

Every ``period_s`` (of the log's time, scaled by ``speed``) the samples due are POSTed as one
message in the documented shape (awesome-sensor-logger ``PUSHING.md``): ``messageId``
counting up, ``sessionId``, ``deviceId``, ``payload`` entries ``{"name", "time" (UTC epoch
ns), "values"}``. The log's ACC, GYR, MAG and ORI become, by ``platform``:

- "android": ``totalacceleration`` (ACC as it is), ``accelerometer`` and ``gravity`` (ACC
  split into motion and gravity), ``gyroscope``, ``magnetometer``, ``orientation``;
- "ios": ``accelerometer`` without gravity and ``gravity`` (no totalacceleration, as on an
  iPhone), the others as above; with ``standardised`` False (the app's default) acceleration
  and gravity change sign and the orientation is given in a frame with x north, y west, z up.

The gravity is ACC low-pass filtered (the split is the emulator's own; its sum is ACC to
rounding). ``roll``, ``pitch``, ``yaw`` are filled in from the quaternion (Z-X'-Y'' angles);
the receiver reads the quaternion. A batch that cannot be delivered (the PC unreachable, or
:meth:`vanish`) is kept and sent with the next one, in order.
"""

from __future__ import annotations

import http.client
import json
import math
import threading
import time
import urllib.parse
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from ekf import quaternion as quat

from app.stream.lines import pacing_times, read_lines
from app.stream.phone_apps import nwu_from_enu
from app.stream.protocol import ParseError, parse_line

PLATFORMS = ("android", "ios")
GRAVITY_SMOOTHING = 0.05       # the emulator's low-pass of ACC for the gravity stream


def parse_push_url(text: str) -> tuple[str, int, str]:
    """"http://HOST:PORT/PATH" (or "HOST:PORT") -> (host, port, path); ValueError."""
    raw = str(text).strip()
    if "://" not in raw:
        raw = "http://" + raw
    try:
        parts = urllib.parse.urlsplit(raw)
        port = parts.port
    except ValueError as error:
        raise ValueError(f"not a URL: {text!r} ({error})") from None
    if parts.scheme != "http" or not parts.hostname:
        raise ValueError(f"expected http://HOST:PORT/, got {text!r}")
    path = parts.path or "/"
    if parts.query:
        path += "?" + parts.query
    return parts.hostname, port or 80, path


def euler_zxy(q_wxyz: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of R = Rz(yaw) Rx(pitch) Ry(roll), rad."""
    m = quat.to_matrix(quat.normalize(q_wxyz))
    pitch = math.asin(max(-1.0, min(1.0, float(m[2, 1]))))
    yaw = math.atan2(-float(m[0, 1]), float(m[1, 1]))
    roll = math.atan2(-float(m[2, 0]), float(m[2, 2]))
    return roll, pitch, yaw


class SensorLoggerPhone:
    """Pushes a log to `url` as Sensor Logger does (see the module docstring)."""

    def __init__(self, url: str, period_s: float = 1.0, platform: str = "android",
                 standardised: bool = False, device_id: str | None = None,
                 session_id: str | None = None, time_offset_ms: int | None = None,
                 timeout_s: float = 5.0, gone: tuple[float, float] | None = None) -> None:
        if platform not in PLATFORMS:
            raise ValueError(f"platform: one of {', '.join(PLATFORMS)}, got {platform!r}")
        self.host, self.port, self.path = parse_push_url(url)
        self.period_s = float(period_s)
        self.platform = platform
        self.standardised = bool(standardised)
        self.device_id = device_id or uuid.uuid4().hex
        self.session_id = session_id or uuid.uuid4().hex
        self.time_offset_ms = time_offset_ms
        self.timeout_s = float(timeout_s)
        self.gone = gone             # (AT, SECONDS): the network gone at AT s of the log
        self.message_id = 0
        self.statuses: dict[int, int] = {}
        self.messages_shown: list[str] = []    # what Sensor Logger would show (499 texts)
        self.samples_pushed = 0
        self.failed_attempts = 0
        self.started_at: float | None = None   # time.monotonic() when the log's time 0 was
        self._pending: list[dict[str, Any]] = []
        self._shift_ns = 0
        self._hold_until = 0.0
        self._connection: http.client.HTTPConnection | None = None

    # -- entries ------------------------------------------------------------------------------------

    def entries(self, lines: list[bytes]) -> tuple[list[list[dict[str, Any]]], list[float]]:
        """For each line, the payload entries it becomes (none for other tags), and each
        line's pacing time [s]."""
        pace = pacing_times(lines)
        offset = self.time_offset_ms
        sign = 1.0 if self.platform == "android" or self.standardised else -1.0
        gravity: np.ndarray | None = None
        out: list[list[dict[str, Any]]] = []
        for raw in lines:
            try:
                sample = parse_line(raw.decode("utf-8", "replace"))
            except ParseError:
                out.append([])
                continue
            if offset is None:
                offset = int(time.time() * 1000) - sample.t_ms
                self.time_offset_ms = offset
            ns = (sample.t_ms + offset) * 1_000_000
            values = sample.values
            entries: list[dict[str, Any]] = []
            if sample.tag == "ACC":
                acc = np.array(values)
                gravity = acc.copy() if gravity is None else \
                    gravity + GRAVITY_SMOOTHING * (acc - gravity)
                motion = acc - gravity
                if self.platform == "android":
                    entries.append(_xyz("totalacceleration", ns, values))
                entries.append(_xyz("accelerometer", ns, tuple(sign * motion)))
                entries.append(_xyz("gravity", ns, tuple(sign * gravity)))
            elif sample.tag == "GYR":
                entries.append(_xyz("gyroscope", ns, values))
            elif sample.tag == "MAG":
                entries.append(_xyz("magnetometer", ns, values))
            elif sample.tag == "ORI":
                q = np.array(values)
                if self.platform == "ios" and not self.standardised:
                    q = np.array(nwu_from_enu(q))
                roll, pitch, yaw = euler_zxy(q)
                entries.append({"name": "orientation", "time": ns,
                                "values": {"qx": float(q[1]), "qy": float(q[2]),
                                           "qz": float(q[3]), "qw": float(q[0]), "roll": roll,
                                           "pitch": pitch, "yaw": yaw}})
            out.append(entries)
        return out, list(pace)

    # -- pushing ------------------------------------------------------------------------------------

    def message(self, payload: list[dict[str, Any]]) -> dict[str, Any]:
        if self._shift_ns:
            payload = [dict(entry, time=entry["time"] + self._shift_ns) for entry in payload]
        message = {"messageId": self.message_id, "sessionId": self.session_id,
                   "deviceId": self.device_id, "payload": payload}
        self.message_id += 1
        return message

    def post(self, body: bytes) -> tuple[int, str]:
        """POST a body; (status, text). OSError when the PC cannot be reached."""
        if self._connection is None:
            self._connection = http.client.HTTPConnection(self.host, self.port,
                                                          timeout=self.timeout_s)
        try:
            self._connection.request("POST", self.path, body=body,
                                     headers={"Content-Type": "application/json"})
            response = self._connection.getresponse()
            text = response.read().decode("utf-8", "replace")
            if response.will_close:
                self.close()
        except (OSError, http.client.HTTPException) as error:
            self.close()
            raise OSError(str(error) or type(error).__name__) from None
        self.statuses[response.status] = self.statuses.get(response.status, 0) + 1
        if response.status == 499 and text.strip() and text.strip() not in self.messages_shown:
            self.messages_shown.append(text.strip())
        return response.status, text

    def close(self) -> None:
        if self._connection is not None:
            self._connection.close()
            self._connection = None

    def vanish(self, seconds: float) -> None:
        """The phone loses the network for `seconds`: its batches wait and go out after."""
        self._hold_until = time.monotonic() + seconds

    def _flush(self, payload: list[dict[str, Any]]) -> None:
        """Queue a message for the payload and send what is queued (kept on failure)."""
        if payload:
            self._pending.append(self.message(payload))
        if time.monotonic() < self._hold_until:
            return
        while self._pending:
            message = self._pending[0]
            try:
                status, _ = self.post(json.dumps(message).encode("utf-8"))
            except OSError:
                self.failed_attempts += 1
                return
            self._pending.pop(0)
            if status == 200:
                self.samples_pushed += len(message["payload"])

    def stream_lines(self, lines: list[bytes], speed: float = 1.0, loop: bool = False,
                     stop: threading.Event | None = None) -> int:
        """Push the lines' samples with their timing / speed (0: as fast as possible), a
        batch every period_s of log time; returns the payload entries pushed with a 200."""
        while True:
            clock_now = self.time_offset_ms is None
            if clock_now:
                self.time_offset_ms = 0
            entries, pace = self.entries(lines)
            start = time.perf_counter()
            self.started_at = time.monotonic()
            if clock_now:
                # the phone stamps its samples when it takes them: the log's first now
                first = next((int(line.split(b"\t", 1)[0]) for line in lines
                              if line.split(b"\t", 1)[0].isdigit()), 0)
                self.time_offset_ms = int(time.time() * 1000) - first
                self._shift_ns = self.time_offset_ms * 1_000_000
            batch: list[dict[str, Any]] = []
            batch_end = self.period_s
            for index, due in enumerate(pace):
                if stop is not None and stop.is_set():
                    break
                if due > batch_end:
                    if self.gone is not None and batch_end >= self.gone[0]:
                        self.vanish(self.gone[1] / (speed or 1.0))
                        self.gone = None
                    if speed > 0:
                        wait = start + batch_end / speed - time.perf_counter()
                        if wait > 0:
                            if stop is not None:
                                stop.wait(wait)
                            else:
                                time.sleep(wait)
                    self._flush(batch)
                    batch = []
                    while due > batch_end:
                        batch_end += self.period_s
                batch += entries[index]
            self._flush(batch)
            deadline = time.monotonic() + max(self.timeout_s, self._hold_until - time.monotonic())
            while self._pending and time.monotonic() < deadline and not (stop and stop.is_set()):
                time.sleep(0.05)
                self._flush([])
            if not loop or (stop is not None and stop.is_set()):
                self.close()
                return self.samples_pushed
            # the next pass goes on in time, as a phone's clock does
            self.time_offset_ms = (self.time_offset_ms or 0) + int(pace[-1] * 1000) + 1000
            self._shift_ns = 0


def _xyz(name: str, ns: int, values) -> dict[str, Any]:
    x, y, z = (float(v) for v in values)
    return {"name": name, "time": ns, "values": {"x": x, "y": y, "z": z}}


def push_log(path: str | Path, url: str, speed: float = 1.0, **options: Any) -> int:
    """Push a log file to url like Sensor Logger; returns the entries pushed."""
    return SensorLoggerPhone(url, **options).stream_lines(read_lines(path), speed)
