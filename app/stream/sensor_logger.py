"""The phone through Sensor Logger's HTTP Push (iOS and Android): the phone POSTs to this PC.

With *HTTP Push* on, Sensor Logger POSTs a JSON batch every batch period to the URL the user
typed (awesome-sensor-logger ``PUSHING.md``): ``{"messageId": 0, "sessionId": "...",
"deviceId": "...", "payload": [{"name": "accelerometer", "time": <UTC epoch ns>, "values":
{"x": ..., "y": ..., "z": ...}}, ...]}``. :class:`SensorLoggerSource` listens on
``[HOST:]PORT`` and takes a POST to any path (the URL to type is ``http://PC:PORT/``).

Bounded, whatever comes: a body over ``max_body_bytes`` (413), JSON that does not parse or is
not a push (400), sensors this program does not use (counted by name), a second device while
one streams (499 with a message, which Sensor Logger shows on that phone; the first phone
keeps the stream until it has been silent ``takeover_after_s``): each is answered, counted and
never a crash. A body must arrive within ``body_timeout_s``; at most ``max_clients`` requests
are served at once.

:class:`SensorLoggerConverter` turns a batch into Sensor Fusion samples (docs/phones.md has
the sources): ``totalacceleration`` (Android: with gravity) or ``accelerometer`` + ``gravity``
(iOS: the accelerometer without gravity) -> ACC with gravity in m/s^2 with Android's signs;
``gyroscope`` -> GYR (rad/s, the same on both); ``magnetometer`` -> MAG (uT); ``orientation``
(``qw qx qy qz``) -> ORI in East-North-Up. iOS with *Standardise Units & Frames* off (the
app's default) sends acceleration and gravity with the opposite sign and its orientation in a
frame with x north, z up: which one a phone sends is told from its gravity and orientation
(:func:`~app.stream.phone_apps.gravity_sign`), or set with ``frames``. Time stamps: the phone's
epoch nanoseconds become epoch milliseconds.

The conversion (:class:`SensorLoggerConverter`) comes first in this module; the receiver and
the source follow.
"""

from __future__ import annotations

import bisect
import ipaddress
import json
import socket
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from app.stream.events import Chunk, SourceEvent
from app.stream.phone_apps import (ItemQueue, PhoneSample, count_name, enu_from_nwu, finite,
                                  gravity_sign, lines_of)
from app.stream.sources import LIVE_PHONE, Source
from app.stream.tcp_server import lan_ipv4_addresses, parse_networks


# -- push batches to samples -------------------------------------------------------------------
#
# One phone's recording at a time. The documented facts (awesome-sensor-logger ``UNITS.md``,
# ``COORDINATES.md``, ``CROSSPLATFORM.md``; docs/phones.md cites each): ``totalacceleration`` (Android) is the
# acceleration with gravity in m/s^2; ``accelerometer`` is without gravity on both platforms and
# ``gravity`` is the gravity vector, m/s^2; on iOS with *Standardise Units & Frames* off both have
# the opposite sign of Android's (flat on a table gravity points -z), the orientation's yaw is
# measured from x pointing north; gyroscope (rad/s) and magnetometer (uT) are the same on both.
# Time is UTC epoch nanoseconds.

FRAMES = ("auto", "standardised", "not-standardised")
XYZ = ("x", "y", "z")
QUATERNION = ("qw", "qx", "qy", "qz")
DIRECT = {"totalacceleration": ("ACC", XYZ), "gyroscope": ("GYR", XYZ),
          "magnetometer": ("MAG", XYZ)}
#: Sensors of the phone this program does not use (counted apart from unknown names).
NOT_USED = frozenset({
    "accelerometeruncalibrated", "gyroscopeuncalibrated", "magnetometeruncalibrated",
    "location", "barometer", "battery", "batterytemp", "brightness", "microphone",
    "pedometer", "compass", "network", "light", "annotation", "activity", "heartrate",
    "wristmotion", "headphone", "camera", "bluetooth", "bluetoothmetadata", "wifi",
    "gameorientation", "geomagneticorientation", "watchlocation", "watchbarometer",
    "watchmagnetometer", "watchcompass", "watchmicrophone"})
#: An accelerometer sample takes the gravity sample closest in time, at most this far.
GRAVITY_MATCH_NS = 100_000_000
#: Without an orientation stream the frame cannot be told: after this much phone time the
#: app's default (not standardised) is assumed.
DECIDE_WITHIN_NS = 2_000_000_000


class SensorLoggerConverter:
    """One phone's recording: batches -> Sensor Fusion samples (see the module docstring).

    frames: "auto" (tell from the data), "standardised" (Android's conventions: Android, or
    iOS with Standardise Units & Frames on) or "not-standardised" (iOS's own)."""

    def __init__(self, frames: str = "auto") -> None:
        if frames not in FRAMES:
            raise ValueError(f"frames: one of {', '.join(FRAMES)}, got {frames!r}")
        self.frames = frames
        self.sign: int | None = {"standardised": 1, "not-standardised": -1}.get(frames)
        self.android = False          # totalacceleration seen: the ACC comes from it
        self.decision = "" if self.sign is None else f"{frames} (set)"
        self.ignored: dict[str, int] = {}
        self.unknown: dict[str, int] = {}
        self.malformed = 0
        self.null_values = 0
        self.without_gravity = 0
        self.problems: list[str] = []    # new problems for the user, taken by the endpoint
        self._gravity: list[tuple[int, tuple[float, ...]]] = []   # the latest gravity samples
        self._held: dict[str, list[tuple[int, tuple[float, ...]]]] = {}
        self._held_since: int | None = None

    def convert(self, payload: list[Any]) -> list[PhoneSample]:
        grouped: dict[str, list[tuple[int, tuple[float, ...]]]] = {}
        for entry in payload:
            parsed = self._entry(entry)
            if parsed is not None:
                grouped.setdefault(parsed[0], []).append(parsed[1:])   # type: ignore[arg-type]
        if "totalacceleration" in grouped:
            self.android = True
        samples: list[PhoneSample] = []
        for name, (tag, _) in DIRECT.items():
            samples += [PhoneSample(t // 1_000_000, tag, v) for t, v in grouped.get(name, ())]
        ios = {name: grouped.get(name, []) for name in ("accelerometer", "gravity",
                                                        "orientation")}
        if self.android:
            samples += [PhoneSample(t // 1_000_000, "ORI", v) for t, v in ios["orientation"]]
            return samples
        return samples + self._ios(ios)

    def _entry(self, entry: Any) -> tuple[str, int, tuple[float, ...]] | None:
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
            self.malformed += 1
            return None
        name = entry["name"].lower()
        keys = DIRECT[name][1] if name in DIRECT else QUATERNION if name == "orientation" \
            else XYZ if name in ("accelerometer", "gravity") else None
        if keys is None:
            count_name(self.ignored if name in NOT_USED else self.unknown, name)
            return None
        t = entry.get("time")
        values = entry.get("values")
        if isinstance(t, bool) or not isinstance(t, (int, float)) or t < 0 \
                or not isinstance(values, dict):
            self.malformed += 1
            return None
        numbers = finite(values.get(key) for key in keys)
        if numbers is None:
            self.null_values += 1
            return None
        return name, int(t), numbers

    def _ios(self, batch: dict[str, list[tuple[int, tuple[float, ...]]]]) \
            -> list[PhoneSample]:
        """ACC from accelerometer + gravity, ORI from orientation, once the frame is known."""
        if self.sign is None:
            for name, items in batch.items():
                self._held.setdefault(name, []).extend(items)
            held = self._held
            self._decide(held)
            if self.sign is None:
                firsts = [items[0][0] for items in held.values() if items]
                lasts = [items[-1][0] for items in held.values() if items]
                if not firsts or max(lasts) - min(firsts) < DECIDE_WITHIN_NS:
                    return []
                self.sign = -1
                self.decision = "not-standardised (assumed: no orientation stream to tell)"
                self.problems.append(
                    "Sensor Logger sends no orientation, so whether Standardise Units & Frames "
                    "is on cannot be told: assuming it is off (the app's default); if OWN "
                    "shows the phone upside down, turn on the Orientation sensor")
            batch, self._held = held, {}
        sign = self.sign
        gravity = self._gravity + sorted(batch.get("gravity", []))
        samples = [PhoneSample(t // 1_000_000, "ORI", self._ori(q))
                   for t, q in batch.get("orientation", [])]
        if batch.get("accelerometer") and not gravity:
            self.without_gravity += len(batch["accelerometer"])
            self.problems.append("Sensor Logger sends the accelerometer without gravity and no "
                                 "Gravity stream: turn on Gravity (or Total Acceleration)")
        elif gravity:
            times = [t for t, _ in gravity]
            for t, a in batch.get("accelerometer", []):
                g = _nearest(gravity, times, t)
                if g is None:
                    self.without_gravity += 1
                    continue
                samples.append(PhoneSample(t // 1_000_000, "ACC",
                                           tuple(sign * (ai + gi) for ai, gi in zip(a, g))))
        self._gravity = gravity[-1:]
        return samples

    def _ori(self, q: tuple[float, ...]) -> tuple[float, ...]:
        return q if self.sign == 1 else enu_from_nwu(q)

    def _decide(self, held: dict[str, list[tuple[int, tuple[float, ...]]]]) -> None:
        """The sign of gravity (and so the frames) from gravity and orientation samples of
        the same times, when there are such pairs."""
        orientation = sorted(held.get("orientation", []))
        if not orientation:
            return
        times = [t for t, _ in orientation]
        votes = 0
        for t, g in held.get("gravity", []):
            q = _nearest(orientation, times, t, max_ns=20_000_000)
            if q is not None:
                votes += gravity_sign(g, q)
        if votes:
            self.sign = 1 if votes > 0 else -1
            self.decision = ("standardised (gravity points up, as on Android)" if votes > 0
                             else "not-standardised (iOS's own frames: gravity points down)")


def _nearest(items: list[tuple[int, tuple[float, ...]]], times: list[int], t: int,
             max_ns: int = GRAVITY_MATCH_NS) -> tuple[float, ...] | None:
    """The values of the item closest in time to t (at most max_ns away), else None."""
    index = bisect.bisect_left(times, t)
    best = None
    for j in (index - 1, index):
        if 0 <= j < len(times) and abs(times[j] - t) <= max_ns:
            if best is None or abs(times[j] - t) < abs(times[best] - t):
                best = j
    return None if best is None else items[best][1]


# -- the HTTP Push receiver and the source -----------------------------------------------------


DEFAULT_PORT = 8000
NOTE_INTERVAL_S = 1.0
#: A body over the limit but at most this large is read and dropped before the 413, so the
#: sender sees the answer; a larger one is answered at once and its connection closed.
DRAIN_BYTES = 64 << 20


class _Stream:
    """The device that streams now."""

    def __init__(self, device: str, session: str, peer: str, connection: int, frames: str,
                 now: float) -> None:
        self.device = device
        self.session = session
        self.peer = peer
        self.connection = connection
        self.converter = SensorLoggerConverter(frames)
        self.last_push = now
        self.last_message: int | None = None
        self.active = True


class SensorLoggerEndpoint:
    """The HTTP endpoint (a threaded server, bounded as the module docstring says): pushes in,
    Chunks of Sensor Fusion lines and SourceEvents out into `items`."""

    def __init__(self, items: ItemQueue, host: str = "0.0.0.0", port: int = DEFAULT_PORT,
                 frames: str = "auto", max_body_bytes: int = 8 << 20,
                 takeover_after_s: float = 3.0, idle_after_s: float = 5.0,
                 body_timeout_s: float = 10.0, max_clients: int = 8, allow=(),
                 clock=time.monotonic) -> None:
        if frames not in FRAMES:
            raise ValueError(f"frames: one of {', '.join(FRAMES)}, got {frames!r}")
        self.items = items
        self.host = host
        self.requested_port = port
        self.port: int | None = None
        self.frames = frames
        self.max_body_bytes = int(max_body_bytes)
        self.takeover_after_s = float(takeover_after_s)
        self.idle_after_s = float(idle_after_s)
        self.body_timeout_s = float(body_timeout_s)
        self.max_clients = int(max_clients)
        self.allowed = parse_networks(allow)
        self.clock = clock
        self.state = "stopped"
        self.stream: _Stream | None = None
        self.connections = 0
        self.counts: dict[str, int] = {"batches": 0, "samples": 0, "bad JSON": 0,
                                       "not a push": 0, "too large": 0, "second device": 0,
                                       "busy": 0, "too many clients": 0, "batch out of order": 0,
                                       "other requests": 0, "not allowed": 0}
        self.second_devices: dict[str, int] = {}
        self._lock = threading.Lock()
        self._note_times: dict[str, float] = {}
        self._server: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None

    # -- lifecycle ------------------------------------------------------------------------------

    def start(self) -> None:
        """Bind and listen (OSError if the port is taken), then serve in daemon threads."""
        if self._server is not None:
            return
        endpoint = self

        class Handler(_PushHandler):
            pass

        Handler.endpoint = endpoint
        Handler.timeout = self.body_timeout_s
        server = PushServer((self.host, self.requested_port), Handler, endpoint, self.max_clients)
        self._server = server
        self.port = server.server_address[1]
        self.state = "waiting"
        self.items.event("listening", detail=f"{self.host}:{self.port}")
        self._thread = threading.Thread(target=server.serve_forever,
                                        kwargs={"poll_interval": 0.2},
                                        name="sensor-logger", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.shutdown()
            server.server_close()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        self.state = "stopped"

    # -- requests -------------------------------------------------------------------------------

    def count(self, what: str) -> int:
        with self._lock:
            self.counts[what] = self.counts.get(what, 0) + 1
            return self.counts[what]

    def note(self, kind: str, detail: str, peer: str | None = None) -> None:
        """An event of `kind`, at most one a second per kind."""
        now = self.clock()
        if now - self._note_times.get(kind, -1e9) >= NOTE_INTERVAL_S:
            self._note_times[kind] = now
            self.items.event(kind, 0, peer, detail)

    def allows(self, address: str) -> bool:
        """Whether `address` may push (``allow``: addresses or networks; empty: anyone)."""
        if not self.allowed:
            return True
        try:
            ip = ipaddress.ip_address(address)
        except ValueError:
            return False
        return any(ip in network for network in self.allowed)

    def push(self, body: bytes, peer: str) -> tuple[int, str]:
        """One POSTed body: (HTTP status, text to answer)."""
        try:
            message = json.loads(body)
        except ValueError as error:
            count = self.count("bad JSON")
            self.note("closed", f"a push from {peer} was not JSON ({count} so far)", peer)
            return 400, f"Orientation Lab: the body is not JSON ({error})"
        if not isinstance(message, dict) or not isinstance(message.get("payload"), list):
            count = self.count("not a push")
            self.note("closed", f"a POST from {peer} was not a Sensor Logger push ({count} so "
                                "far)", peer)
            return 400, "Orientation Lab: not a Sensor Logger push (no payload list)"
        device = str(message.get("deviceId") or peer.rsplit(":", 1)[0])
        session = str(message.get("sessionId") or "")
        with self._lock:
            now = self.clock()
            stream = self.stream
            if stream is not None and stream.device != device \
                    and now - stream.last_push < self.takeover_after_s:
                self.counts["second device"] += 1
                self.second_devices[device[:40]] = self.second_devices.get(device[:40], 0) + 1
                busy_with = stream.peer
            else:
                busy_with = None
                if stream is None or stream.device != device or stream.session != session:
                    stream = self._new_stream(stream, device, session, peer, now)
                stream.last_push = now
        if busy_with is not None:
            self.note("closed", f"a second phone at {peer} pushes while the one at {busy_with} "
                                "streams: it is answered 499 and its data is not used", peer)
            return 499, ("Orientation Lab is receiving another phone now; stop that one's "
                         "recording first (this phone's data is not used)")
        return self._take(stream, message)

    def _new_stream(self, previous: _Stream | None, device: str, session: str, peer: str,
                    now: float) -> _Stream:
        self.connections += 1
        if previous is not None and previous.device == device:
            detail = "Sensor Logger: a new recording on the phone"
        elif previous is None or not previous.active:
            detail = "Sensor Logger"
        else:
            detail = (f"Sensor Logger: took over from {previous.peer} (silent for "
                      f"{now - previous.last_push:.1f} s)")
        stream = _Stream(device, session, peer, self.connections, self.frames, now)
        self.stream = stream
        self.state = "connected"
        self.items.event("connected", stream.connection, peer, detail)
        return stream

    def _take(self, stream: _Stream, message: dict[str, Any]) -> tuple[int, str]:
        number = message.get("messageId")
        if isinstance(number, int) and not isinstance(number, bool):
            if stream.last_message is not None and number < stream.last_message:
                self.count("batch out of order")
            stream.last_message = number if stream.last_message is None \
                else max(stream.last_message, number)
        converter = stream.converter
        samples = converter.convert(message["payload"])
        for problem in converter.problems:
            self.note("error", problem, stream.peer)
        converter.problems.clear()
        if not self.items.wait_for_room(self.body_timeout_s):
            self.count("busy")
            return 503, "Orientation Lab is busy; the batch was not taken"
        with self._lock:
            self.counts["batches"] += 1
            self.counts["samples"] += len(samples)
            if not stream.active:
                stream.active = True
                self.state = "connected"
                self.items.event("connected", stream.connection, stream.peer,
                                 "Sensor Logger pushes again")
        self.items.chunk(stream.connection, lines_of(samples))
        return 200, "ok"

    def housekeeping(self) -> None:
        """A stream silent for idle_after_s has stopped (the recording ended on the phone)."""
        with self._lock:
            stream = self.stream
            if stream is None or not stream.active:
                return
            silent = self.clock() - stream.last_push
            if silent < self.idle_after_s:
                return
            stream.active = False
            self.state = "disconnected"
        self.items.event("disconnected", stream.connection, stream.peer,
                         f"Sensor Logger stopped pushing (nothing for {silent:.0f} s)")

    def info(self) -> dict[str, Any]:
        with self._lock:
            stream = self.stream
            converter = stream.converter if stream is not None else None
            return {"counts": dict(self.counts),
                    "second_devices": dict(self.second_devices),
                    "device": stream.device if stream else None,
                    "frames": converter.decision if converter else "",
                    "ignored_sensors": dict(converter.ignored) if converter else {},
                    "unknown_sensors": dict(converter.unknown) if converter else {},
                    "malformed_entries": converter.malformed if converter else 0,
                    "null_values": converter.null_values if converter else 0,
                    "without_gravity": converter.without_gravity if converter else 0}


class PushServer(ThreadingHTTPServer):
    """The HTTP server behind the endpoint: a bounded number of clients, each in its thread."""
    daemon_threads = True
    request_queue_size = 64

    def __init__(self, address, handler, endpoint: SensorLoggerEndpoint,
                 max_clients: int) -> None:
        self.endpoint = endpoint
        self._slots = threading.BoundedSemaphore(max_clients)
        super().__init__(address, handler)

    def process_request(self, request, client_address) -> None:
        if not self._slots.acquire(blocking=False):
            self.endpoint.count("too many clients")
            self.shutdown_request(request)
            return
        super().process_request(request, client_address)

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()

    def service_actions(self) -> None:
        self.endpoint.housekeeping()

    def handle_error(self, request, client_address) -> None:
        """Count a request that failed (a client gone before its answer) instead of printing a
        traceback on the user's terminal; the server serves on."""
        error = sys.exc_info()[1]
        self.endpoint.count("closed early" if isinstance(error, OSError) else "failed requests")


class _BodyError(Exception):
    def __init__(self, status: int, text: str) -> None:
        super().__init__(text)
        self.status = status
        self.text = text


class _PushHandler(BaseHTTPRequestHandler):
    endpoint: SensorLoggerEndpoint
    protocol_version = "HTTP/1.1"
    disable_nagle_algorithm = True      # headers and body go out at once (no 40 ms wait)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (the base's name)
        return

    def _answer(self, status: int, text: str, close: bool = False) -> None:
        body = (text + "\n").encode("utf-8")
        self.send_response(status)
        self.send_header("Content-Type", "text/plain; charset=utf-8")
        self.send_header("Content-Length", str(len(body)))
        if close:
            self.send_header("Connection", "close")
            self.close_connection = True
        self.end_headers()
        self.wfile.write(body)

    def _read(self, size: int, deadline: float) -> bytes:
        pieces = []
        while size > 0:
            if time.monotonic() > deadline:
                raise _BodyError(408, "Orientation Lab: the body did not arrive in time")
            piece = self.rfile.read1(min(size, 65536))
            if not piece:
                raise _BodyError(400, "Orientation Lab: the body ended early")
            pieces.append(piece)
            size -= len(piece)
        return b"".join(pieces)

    def _body(self) -> bytes:
        endpoint = self.endpoint
        limit = endpoint.max_body_bytes
        deadline = time.monotonic() + endpoint.body_timeout_s
        too_large = _BodyError(413, f"Orientation Lab: a batch over {limit >> 20} MiB is not "
                                    "taken (a shorter batch period, or no camera)")
        if "chunked" in (self.headers.get("Transfer-Encoding") or "").lower():
            data = b""
            while True:
                line = self.rfile.readline(100)
                try:
                    size = int(line.split(b";")[0].strip() or b"x", 16)
                except ValueError:
                    raise _BodyError(400, "Orientation Lab: bad chunked body") from None
                if size == 0:
                    self.rfile.readline(100)
                    return data
                if len(data) + size > limit:
                    raise too_large
                data += self._read(size, deadline)
                self.rfile.readline(100)
        length_text = self.headers.get("Content-Length")
        if length_text is None:
            raise _BodyError(411, "Orientation Lab: a push needs a Content-Length")
        try:
            length = int(length_text)
        except ValueError:
            raise _BodyError(400, "Orientation Lab: bad Content-Length") from None
        if length < 0:
            raise _BodyError(400, "Orientation Lab: bad Content-Length")
        if length > limit:
            if length <= DRAIN_BYTES:
                self._discard(length, deadline)      # so the phone reads the answer
            raise too_large
        return self._read(length, deadline)

    def _discard(self, size: int, deadline: float) -> None:
        try:
            while size > 0 and time.monotonic() < deadline:
                piece = self.rfile.read1(min(size, 65536))
                if not piece:
                    return
                size -= len(piece)
        except OSError:
            return

    def do_POST(self) -> None:  # noqa: N802 (http.server's name)
        peer = f"{self.client_address[0]}:{self.client_address[1]}"
        if not self.endpoint.allows(str(self.client_address[0])):
            count = self.endpoint.count("not allowed")
            self.endpoint.note("closed", f"a push from {peer} is not from an allowed address "
                                         f"({count} so far)", peer)
            self._answer(403, "Orientation Lab: this address may not push here", close=True)
            return
        try:
            body = self._body()
        except _BodyError as error:
            if error.status == 413:
                count = self.endpoint.count("too large")
                self.endpoint.note("closed", f"a push from {peer} was too large ({count} so "
                                             "far)", peer)
            self._answer(error.status, error.text, close=True)
            return
        except (OSError, socket.timeout):
            self.close_connection = True
            return
        status, text = self.endpoint.push(body, peer)
        self._answer(status, text)

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        self.endpoint.count("other requests")
        self._answer(200, "Orientation Lab takes Sensor Logger's HTTP Push here: POST to "
                          "this address (any path).")

    def _not_allowed(self) -> None:
        self.endpoint.count("other requests")
        self._answer(405, "Orientation Lab: POST a Sensor Logger push here", close=True)

    do_PUT = do_DELETE = do_PATCH = do_HEAD = _not_allowed  # noqa: N815 (http.server's names)


class SensorLoggerSource(Source):
    """Sensor Logger's HTTP Push received on host:port (see the module docstring)."""

    kind = "sensor-logger"
    capabilities = LIVE_PHONE

    def __init__(self, host: str = "0.0.0.0", port: int = DEFAULT_PORT, frames: str = "auto",
                 takeover_after_s: float = 3.0, max_body_bytes: int = 8 << 20,
                 idle_after_s: float = 5.0, max_queued_bytes: int = 16 << 20,
                 allow=()) -> None:
        self.items = ItemQueue(max_queued_bytes)
        self.endpoint = SensorLoggerEndpoint(self.items, host, port, frames, max_body_bytes,
                                             takeover_after_s, idle_after_s, allow=allow)
        self._addresses: list[str] = []
        self.name = "Sensor Logger"

    def start(self) -> None:
        self.endpoint.start()
        host = self.endpoint.host
        self._addresses = lan_ipv4_addresses() if host in ("0.0.0.0", "") else [host]

    def stop(self) -> None:
        self.endpoint.stop()

    @property
    def port(self) -> int | None:
        return self.endpoint.port

    def urls(self) -> list[str]:
        """What to type into Sensor Logger's Push URL, most likely first."""
        return [f"http://{address}:{self.endpoint.port}/" for address in self._addresses]

    def read(self, timeout: float = 0.05) -> list[Chunk | SourceEvent]:
        return self.items.get(timeout)

    def connect_hint(self) -> str:
        return (f"listening on port {self.port} for Sensor Logger; type one of these into its "
                f"HTTP Push URL: {', '.join(self.urls())}")

    def info(self) -> dict[str, Any]:
        endpoint = self.endpoint
        stream = endpoint.stream
        state = endpoint.state
        return {"connection_state": "waiting" if state == "stopped" else state,
                "peer": stream.peer if stream else None, "port": endpoint.port,
                "listen_addresses": list(self._addresses), "replay": None,
                "connect_to": self.urls(), "connect_hint": self.connect_hint(),
                "sensor_logger": {**endpoint.info(), "urls": self.urls()}}
