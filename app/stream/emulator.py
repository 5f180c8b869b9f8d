"""Phones emulated, for `orientation-lab send`, tests, demos and benchmarks: each streams a log
the way its app does.

- :class:`PhoneEmulator` (:func:`send_log`): the Sensor Fusion app, a TCP client of the
  server (`orientation-lab send LOG`).
- :class:`PhyphoxPhone`: phyphox, serving the log through its remote interface
  (`orientation-lab send LOG --as phyphox --port P`).
- :class:`SensorLoggerPhone` (:func:`push_log`): Sensor Logger with HTTP Push on, posting the
  log as its batches (`orientation-lab send LOG --as sensor-logger --url URL`).
"""

from __future__ import annotations

import http.client
import json
import math
import select
import socket
import threading
import time
import urllib.parse
import uuid
import xml.etree.ElementTree as ElementTree
import zlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, HTTPServer
from pathlib import Path
from typing import Any

import numpy as np

from ekf import quaternion as quat

from app.stream.lines import Pacer, line_blocks, line_starts, pacing_times, read_lines
from app.stream.phone_apps import nwu_from_enu
from app.stream.phyphox import SENSOR_TAGS
from app.stream.phyphox_experiment import experiment_xml
from app.stream.protocol import ParseError, parse_line


# -- the Sensor Fusion app over TCP ------------------------------------------------------------
#
# Connects to the server like the Sensor Fusion app and streams a log.
#
# Lines go out verbatim, in file order, with the log's own timing
# (:func:`~app.stream.lines.pacing_times`) scaled by ``speed`` (0: as fast as possible); a file is
# read and sent block by block, so memory does not grow with its size. Used by `orientation-lab
# send`, tests and benchmarks.

_BLOCK_BYTES = 1 << 18


class PhoneEmulator:
    """A TCP client that behaves like the phone: connect, send lines, close. Context manager."""

    def __init__(self, host: str = "127.0.0.1", port: int = 3400, timeout: float = 5.0) -> None:
        self.host = host
        self.port = port
        self.timeout = timeout
        self.sock: socket.socket | None = None
        self.bytes_sent = 0
        self.lines_sent = 0

    def connect(self) -> PhoneEmulator:
        self.sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return self

    def send(self, data: bytes) -> None:
        if self.sock is None:
            raise OSError("not connected")
        self.sock.sendall(data)
        self.bytes_sent += len(data)

    def close(self) -> None:
        if self.sock is not None:
            try:
                self.sock.shutdown(socket.SHUT_WR)
            except OSError:
                pass
            self.sock.close()
            self.sock = None

    def __enter__(self) -> PhoneEmulator:
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.close()

    def stream_lines(self, lines: list[bytes], speed: float = 1.0, loop: bool = False,
                     stop: threading.Event | None = None) -> int:
        """Send `lines` (each with its LF) with their original timing / speed (0: at once).
        Returns the number of lines sent; ends early when `stop` is set."""
        data = b"".join(lines)
        return self.stream_blocks(lambda: [data], speed, loop, stop)

    def stream_blocks(self, blocks: Callable[[], Iterable[bytes]], speed: float = 1.0,
                      loop: bool = False, stop: threading.Event | None = None) -> int:
        """Send the lines of ``blocks()`` (blocks of whole lines, :func:`~app.stream.lines.
        line_blocks`; called again for each pass of a loop) with their original timing / speed
        (0: at once), holding one block at a time. Returns the number of lines sent; ends early
        when `stop` is set."""
        sent = 0
        while True:
            pacer = Pacer()
            start_wall = time.perf_counter()
            for block in blocks():
                if speed <= 0 or not block.endswith(b"\n"):
                    for first in range(0, len(block), _BLOCK_BYTES):
                        piece = block[first:first + _BLOCK_BYTES]
                        self.send(piece)
                        sent += piece.count(b"\n")
                        if stop is not None and stop.is_set():
                            return self._sent(sent)
                    continue
                starts = line_starts(block)
                pace = pacer.times(block, starts)
                index = 0
                while index < len(pace):
                    if stop is not None and stop.is_set():
                        return self._sent(sent)
                    now = (time.perf_counter() - start_wall) * speed
                    end = int(np.searchsorted(pace, now, side="right"))
                    if end > index:
                        self.send(block[starts[index]:starts[end]])
                        sent += end - index
                        index = end
                    else:
                        time.sleep(min(0.05, (pace[index] - now) / speed))
            if not loop or (stop is not None and stop.is_set()):
                return self._sent(sent)

    def _sent(self, count: int) -> int:
        self.lines_sent = count
        return count


def send_log(path: str | Path, host: str = "127.0.0.1", port: int = 3400, speed: float = 1.0,
             loop: bool = False, stop: threading.Event | None = None) -> int:
    """Connect like the phone and stream a log file (read block by block, never whole);
    returns the number of lines sent."""
    with PhoneEmulator(host, port) as phone:
        return phone.stream_blocks(lambda: line_blocks(path), speed, loop, stop)


# -- phyphox's remote interface ----------------------------------------------------------------
#
# A phone running phyphox, for tests and demos: a log served through phyphox's remote
# interface (`orientation-lab send LOG --as phyphox --port P`).
#
# It answers what phyphox-docs ``docs/remote-interface/openapi.yaml`` specifies, from one
# thread (phyphox's server is single-threaded): ``/config`` (the experiment's buffers and
# inputs), ``/get`` (a buffer per query parameter: empty for the last value, ``full``, a
# threshold ``T`` or ``T|ref``; ``null`` for NaN; an unknown buffer skipped, a bad threshold
# 400), ``/control`` (``start``, ``stop``, ``clear``), ``/meta``, ``/time``; GET or POST with the
# parameters in the query, a JSON or a form body (the body wins).
#
# The log's ACC, GYR, MAG and ORI samples fill the experiment's sensor buffers as the
# measurement runs, with the log's own timing scaled by ``speed``; the experiment time starts
# at 0 with the log's first sample (or at ``start_ms`` of the log's time: 0 serves the log's own
# times) and stops while the measurement is stopped. ``digits``
# rounds what is served to that many significant digits as the phone does (about 8; the
# threshold is then nudged up by one unit in the last place); None serves every value exactly.
# :meth:`vanish` makes the phone unreachable for a while (the measurement goes on),
# :meth:`switch_session` is the user loading another experiment.

MAX_BODY_BYTES = 1 << 20


@dataclass
class _Column:
    """A buffer's values over the whole log (float64; NaN where a sample has none)."""

    sensor: str          # phyphox sensor type
    values: np.ndarray
    size: int            # the container's size (0: unlimited)


def _experiment(xml_text: str) -> tuple[str, list[tuple[str, int]], list[tuple[str, list]]]:
    """(title, [(buffer, size)], [(sensor type, [(component, buffer)])]) of a .phyphox file."""
    root = ElementTree.fromstring(xml_text)
    title = (root.findtext("title") or "").strip()
    buffers = [((c.text or "").strip(), int(c.get("size", "1")))
               for c in root.iter("container")]
    inputs = []
    for sensor in root.iter("sensor"):
        outputs = [(o.get("component", "x"), (o.text or "").strip()) for o in sensor.iter("output")]
        inputs.append((sensor.get("type", ""), outputs))
    return title, buffers, inputs


def _log_samples(lines: list[bytes]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """tag -> (times ms, values) of the log's ACC, GYR, MAG and ORI samples, in file order
    (each tag's own times increase in a phone's log; a sample going back is left out, as
    phyphox's time buffers only grow)."""
    wanted = {tag for tag, _ in SENSOR_TAGS.values()}
    found: dict[str, tuple[list[int], list[tuple[float, ...]]]] = {t: ([], []) for t in wanted}
    for raw in lines:
        try:
            sample = parse_line(raw.decode("utf-8", "replace"))
        except ParseError:
            continue
        if sample.tag not in wanted:
            continue
        times, values = found[sample.tag]
        if times and sample.t_ms <= times[-1]:
            continue
        times.append(sample.t_ms)
        values.append(sample.values)
    return {tag: (np.array(t, np.int64), np.array(v, float).reshape(len(t), -1))
            for tag, (t, v) in found.items() if t}


class PhyphoxPhone:
    """The phone side of phyphox's remote interface, serving a log (see the module docstring).

    Context manager; :attr:`port` after :meth:`start`. ``nan_samples`` {tag: indices} serves
    those samples of the tag as null values (a sensor's NaN). :attr:`overlapping_requests`
    counts requests during which another connection was already waiting (a client polling
    in parallel); :attr:`requests` counts all."""

    def __init__(self, lines: list[bytes], host: str = "127.0.0.1", port: int = 0,
                 speed: float = 1.0, xml: str | None = None, digits: int | None = None,
                 measuring: bool = False, nan_samples: dict[str, set[int]] | None = None,
                 start_ms: int | None = None, clock=time.monotonic) -> None:
        self.host = host
        self.requested_port = port
        self.port: int | None = None
        self.speed = float(speed) if speed > 0 else 1e9
        self.digits = digits
        self.clock = clock
        self.session = uuid.uuid4().hex[:8]
        self.xml = xml if xml is not None else experiment_xml()
        self.title, self.containers, self.inputs = _experiment(self.xml)
        samples = _log_samples(lines)
        starts = [int(t[0]) for t, _ in samples.values()]
        self.t0_ms = min(starts) if starts else 0
        # the log time at experiment time 0 (default: its first sample)
        self.start_ms = self.t0_ms if start_ms is None else int(start_ms)
        self.samples = samples
        self.columns: dict[str, _Column] = {}
        self.times_s: dict[str, np.ndarray] = {}          # sensor type -> log time [s]
        self.time_buffers = {buffer for _, outputs in self.inputs for c, buffer in outputs
                             if c == "t"}
        self._build_columns(nan_samples or {})
        ends = [float(t[-1] - self.t0_ms) / 1000.0 for t, _ in samples.values()]
        self.duration_s = max(ends) if ends else 0.0
        self.measuring = False
        self._elapsed_s = 0.0              # log seconds measured before the current run
        self._running_since: float | None = None
        self._cleared_at_s: float | None = None   # log seconds at the last clear
        self.events: list[dict[str, Any]] = []
        self.requests = 0
        self.overlapping_requests = 0
        self.requests_by_path: dict[str, int] = {}
        self.served_to_end = False
        self._complete: set[str] = set()
        self._lock = threading.Lock()
        self._server: HTTPServer | None = None
        self._thread: threading.Thread | None = None
        self.closing = False
        self._vanish_timer: threading.Timer | None = None
        if measuring:
            self.start_measurement()

    # -- the experiment's data -------------------------------------------------------------------

    def _build_columns(self, nan_samples: dict[str, set[int]]) -> None:
        sizes = dict(self.containers)
        for sensor, outputs in self.inputs:
            declared = SENSOR_TAGS.get(sensor)
            if declared is None:
                continue
            tag, components = declared
            data = self.samples.get(tag)
            if data is None:
                t = np.zeros(0, np.int64)
                values = np.zeros((0, len(components)))
            else:
                t, values = data
                values = values.copy()
                for index in nan_samples.get(tag, ()):
                    if 0 <= index < len(values):
                        values[index, 0] = np.nan
            self.times_s[sensor] = (t - self.t0_ms) / 1000.0
            for component, buffer in outputs:
                if component == "t":
                    column = self.times_s[sensor].copy()
                elif component in components:
                    column = values[:, components.index(component)]
                else:
                    continue
                self.columns[buffer] = _Column(sensor, column, sizes.get(buffer, 1))

    def position_s(self) -> float:
        """Log seconds measured so far (the experiment time plus what was cleared)."""
        running = 0.0 if self._running_since is None else \
            (self.clock() - self._running_since) * self.speed
        return self._elapsed_s + running

    def sample_wall_time(self, log_s: float) -> float | None:
        """When (on the clock) the sample at `log_s` entered the buffers, while the
        measurement has run without a stop since; None when not measuring."""
        if self._running_since is None:
            return None
        return self._running_since + (log_s - self._elapsed_s) / self.speed

    def start_measurement(self) -> None:
        with self._lock:
            if not self.measuring:
                self.measuring = True
                self._running_since = self.clock()
                self.events.append(self._event("START"))

    def stop_measurement(self) -> None:
        with self._lock:
            if self.measuring:
                self._elapsed_s = self.position_s()
                self._running_since = None
                self.measuring = False
                self.events.append(self._event("PAUSE"))

    def clear(self) -> None:
        """phyphox's clear: the measurement stops, the buffers empty, time starts at 0 again."""
        self.stop_measurement()
        with self._lock:
            self._cleared_at_s = self._elapsed_s
            self.events = []

    def switch_session(self) -> None:
        """The user loaded another experiment (the same one again): a new session."""
        self.clear()
        with self._lock:
            self.session = uuid.uuid4().hex[:8]

    def _event(self, kind: str) -> dict[str, Any]:
        return {"event": kind, "experimentTime": self.position_s() - self._origin_s(),
                "systemTime": time.time()}

    def _served(self, buffer: str) -> np.ndarray:
        """The buffer's contents now."""
        column = self.columns[buffer]
        times = self.times_s[column.sensor]
        low = 0 if self._cleared_at_s is None else \
            int(np.searchsorted(times, self._cleared_at_s, side="right"))
        high = int(np.searchsorted(times, self.position_s(), side="right"))
        if column.size > 0:
            low = max(low, high - column.size)
        values = column.values[low:high]
        if buffer in self.time_buffers:
            values = values - self._origin_s()
        if self.digits:
            values = np.array([float(f"{v:.{self.digits}g}") for v in values])
        return values

    def _origin_s(self) -> float:
        """Experiment time 0, in seconds after the log's first sample."""
        if self._cleared_at_s is not None:
            return self._cleared_at_s
        return (self.start_ms - self.t0_ms) / 1000.0

    def _delivered(self, time_buffer: str, data: np.ndarray, first: int) -> None:
        """Notes a time buffer whose last sample of the log the client now has."""
        if len(data) and first <= len(data) and self.position_s() >= self.duration_s:
            self._complete.add(time_buffer)
            wanted = {b for b in self.time_buffers if len(self.columns[b].values)}
            self.served_to_end = wanted <= self._complete

    def _nudged(self, threshold: float) -> float:
        if not self.digits or threshold == 0 or not math.isfinite(threshold):
            return threshold
        unit = 10.0 ** (math.floor(math.log10(abs(threshold))) - self.digits + 1)
        return threshold + unit

    # -- the API ----------------------------------------------------------------------------------

    def get(self, params: dict[str, str]) -> tuple[int, Any]:
        """/get: (status, reply)."""
        out: dict[str, Any] = {}
        for name, value in params.items():
            if name not in self.columns:
                continue                          # an unknown buffer is skipped
            data = self._served(name)
            if value == "":
                mode, data = "single", data[-1:]
            elif value == "full":
                mode = "full"
                if name in self.time_buffers:
                    self._delivered(name, data, 0)
            else:
                text, _, reference = value.partition("|")
                try:
                    threshold = float(text)
                except ValueError:
                    return 400, {"error": f"threshold of {name} is not a number: {text!r}"}
                if reference and reference not in self.columns:
                    return 400, {"error": f"threshold of {name}: no buffer {reference!r}"}
                ref = self._served(reference or name)
                above = np.nonzero(ref > self._nudged(threshold))[0]
                first = int(above[0]) if len(above) else len(ref)
                mode, data = "partial", data[first:]
                if (reference or name) in self.time_buffers:
                    self._delivered(reference or name, ref, first)
            out[name] = {"size": self.columns[name].size, "updateMode": mode,
                         "buffer": [None if not math.isfinite(v) else float(v) for v in data]}
        return 200, {"buffer": out, "status": self.status()}

    def status(self) -> dict[str, Any]:
        return {"session": self.session, "measuring": self.measuring, "timedRun": False,
                "countDown": 0}

    def control(self, params: dict[str, str]) -> dict[str, Any]:
        command = params.get("cmd", "")
        if command == "start":
            self.start_measurement()
        elif command == "stop":
            self.stop_measurement()
        elif command == "clear":
            self.clear()
        else:
            return {"result": False}
        return {"result": True}

    def config(self) -> dict[str, Any]:
        return {"crc32": format(zlib.crc32(self.xml.encode("utf-8")), "x"),
                "title": self.title, "localTitle": self.title, "category": "Orientation Lab",
                "localCategory": "Orientation Lab",
                "buffers": [{"name": name, "size": size} for name, size in self.containers],
                "inputs": [{"source": sensor,
                            "outputs": [{component: buffer} for component, buffer in outputs]}
                           for sensor, outputs in self.inputs],
                "export": []}

    def meta(self) -> dict[str, Any]:
        return {"version": "emulated", "build": None, "fileFormat": "1.14",
                "deviceModel": "Orientation Lab phone emulator", "deviceBrand": None}

    def answer(self, method: str, path: str, params: dict[str, str]) -> tuple[int, Any]:
        """(status, JSON reply) for a request; counts it."""
        with self._lock:
            self.requests += 1
            self.requests_by_path[path] = self.requests_by_path.get(path, 0) + 1
        if path == "/get":
            return self.get(params)
        if path == "/control":
            return 200, self.control(params)
        if path == "/config":
            return 200, self.config()
        if path == "/meta":
            return 200, self.meta()
        if path == "/time":
            return 200, list(self.events)
        return 404, {"error": f"no such endpoint: {path}"}

    # -- serving ------------------------------------------------------------------------------------

    def start(self) -> PhyphoxPhone:
        """Listen (OSError if the port is taken) and serve from one background thread."""
        phone = self

        class Handler(_Handler):
            pass

        Handler.phone = phone
        self.closing = False
        server = HTTPServer((self.host, self.requested_port if self.port is None
                             else self.port), Handler)
        self._server = server
        self.port = server.server_address[1]
        self._thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval":
                                                                             0.05},
                                        name="phyphox-phone", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the socket. Idempotent."""
        if self._vanish_timer is not None:
            self._vanish_timer.cancel()
            self._vanish_timer = None
        server, self._server = self._server, None
        self.closing = True                 # a kept-alive connection ends after its request
        if server is not None:
            server.shutdown()
            server.server_close()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def vanish(self, seconds: float) -> None:
        """The phone leaves the network for `seconds`: connections are refused, the
        measurement goes on; then it serves again on the same port."""
        self.stop()
        self._vanish_timer = threading.Timer(seconds, self._come_back)
        self._vanish_timer.daemon = True
        self._vanish_timer.start()

    def _come_back(self) -> None:
        self._vanish_timer = None
        self.start()

    @property
    def serving(self) -> bool:
        return self._server is not None

    def serve_forever(self, stop: threading.Event | None = None,
                      gone: tuple[float, float] | None = None) -> None:
        """Serve in this thread's stead until `stop` is set (or the log was served to its end
        and then 1 s passed, when `stop` is None). gone (AT, SECONDS): the phone leaves the
        network when its measurement reaches AT seconds of the log, for SECONDS."""
        done_at = None
        while stop is None or not stop.is_set():
            if gone is not None and self.position_s() >= gone[0]:
                self.vanish(gone[1])
                gone = None
            if stop is None and self.served_to_end:
                done_at = done_at or self.clock()
                if self.clock() - done_at > 1.0:
                    return
            time.sleep(0.05)

    def __enter__(self) -> PhyphoxPhone:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


class _Handler(BaseHTTPRequestHandler):
    """One request at a time (the server is an HTTPServer: no threads)."""

    phone: PhyphoxPhone
    protocol_version = "HTTP/1.1"
    timeout = 1.0
    disable_nagle_algorithm = True      # headers and body go out at once (no 40 ms wait)                       # an idle kept-alive connection is closed after this

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (the base's name)
        return

    def _params(self) -> dict[str, str] | None:
        parts = urllib.parse.urlsplit(self.path)
        params = dict(urllib.parse.parse_qsl(parts.query, keep_blank_values=True))
        if self.command != "POST":
            return params
        length = int(self.headers.get("Content-Length") or 0)
        if length > MAX_BODY_BYTES:
            return None
        body = self.rfile.read(length) if length else b""
        kind = (self.headers.get("Content-Type") or "").split(";")[0].strip()
        if body and kind == "application/json":
            data = json.loads(body)
            if not isinstance(data, dict):
                raise ValueError("not a JSON object")
            params.update({str(k): v if isinstance(v, str) else json.dumps(v)
                           for k, v in data.items()})
        elif body:
            params.update(dict(urllib.parse.parse_qsl(body.decode("utf-8", "replace"),
                                                      keep_blank_values=True)))
        return params

    def _reply(self, status: int, data: Any) -> None:
        body = json.dumps(data, allow_nan=False).encode("utf-8")
        self.send_response(status)
        if self.close_connection:
            self.send_header("Connection", "close")
        self.send_header("Content-Type", "application/json")
        self.send_header("Access-Control-Allow-Origin", "*")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def _handle(self) -> None:
        server_socket = self.server.socket
        try:
            waiting, _, _ = select.select([server_socket], [], [], 0)
        except (OSError, ValueError):
            waiting = []
        if waiting:
            self.phone.overlapping_requests += 1
        try:
            params = self._params()
        except ValueError:
            self._reply(400, {"error": "the request body is not valid JSON"})
            return
        if params is None:
            self._reply(413, {"error": "request body too large"})
            return
        path = urllib.parse.urlsplit(self.path).path
        if path == "/":
            body = b"<!DOCTYPE html><title>phyphox (emulated)</title><p>phyphox emulator</p>"
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
            return
        status, reply = self.phone.answer(self.command, path, params)
        if self.phone.closing:
            self.close_connection = True
        self._reply(status, reply)

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        self._handle()

    def do_POST(self) -> None:  # noqa: N802 (http.server's name)
        self._handle()


# -- Sensor Logger's HTTP Push -----------------------------------------------------------------
#
# A phone running Sensor Logger with HTTP Push on, for tests and demos: a log pushed as
# Sensor Logger's batches (`orientation-lab send LOG --as sensor-logger --url URL`).
#
# Every ``period_s`` (of the log's time, scaled by ``speed``) the samples due are POSTed as one
# message in the documented shape (awesome-sensor-logger ``PUSHING.md``): ``messageId``
# counting up, ``sessionId``, ``deviceId``, ``payload`` entries ``{"name", "time" (UTC epoch
# ns), "values"}``. The log's ACC, GYR, MAG and ORI become, by ``platform``:
#
# - "android": ``totalacceleration`` (ACC as it is), ``accelerometer`` and ``gravity`` (ACC
#   split into motion and gravity), ``gyroscope``, ``magnetometer``, ``orientation``;
# - "ios": ``accelerometer`` without gravity and ``gravity`` (no totalacceleration, as on an
#   iPhone), the others as above; with ``standardised`` False (the app's default) acceleration
#   and gravity change sign and the orientation is given in a frame with x north, y west, z up.
#
# The gravity is ACC low-pass filtered (the split is the emulator's own; its sum is ACC to
# rounding). ``roll``, ``pitch``, ``yaw`` are filled in from the quaternion (Z-X'-Y'' angles);
# the receiver reads the quaternion. A batch that cannot be delivered (the PC unreachable, or
# :meth:`vanish`) is kept and sent with the next one, in order.

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
