"""The phone through phyphox's remote interface (iOS and Android): this PC polls the phone.

With *Allow remote access* on, phyphox runs an HTTP server on the phone (phyphox-docs,
``docs/remote-interface/openapi.yaml``). :class:`PhyphoxSource` is its client:

- ``GET /config`` says which buffers the running experiment's sensors write
  (``inputs[].outputs``); the accelerometer (with g), gyroscope, magnetometer and attitude
  become ACC, GYR, MAG and ORI lines (:data:`SENSOR_TAGS`). Any of them missing is said in one
  line naming it; the rest streams.
- ``GET /get`` is polled with time thresholds: ``acc_time=T&accX=T%7Cacc_time`` returns only
  what is newer than T (the ``|`` percent-encoded); the first poll of a session asks for the
  ``full`` buffers, so a measurement started before this PC connected arrives whole. One
  request at a time, the next at least ``MIN_GAP_S`` after the previous reply (the server is
  single-threaded and slow).
- ``status.session`` changing means the user switched experiments: the buffers are read
  again and the stream starts afresh (a new connection for the engine). ``status.measuring``
  false: the measurement is started once per session (``/control?cmd=start``); stopped
  later on the phone, it is said so and waited for.
- ``null`` values (NaN or infinite on the phone) are skipped and counted.
- The phone not answering: said once, retried with back-off (at most ``retry_max_s``); what
  phyphox held meanwhile is fetched when it answers again (the thresholds are kept).
- A cleared measurement (the experiment time starts again at 0) is noticed when no new data
  comes while measuring: the newest time on the phone is then older than the threshold.

Time stamps: phyphox's experiment time in seconds (since the measurement first started,
pauses skipped) becomes integer milliseconds. The conversions are in docs/phones.md.

The remote interface's pieces (the address the user types, the running experiment's sensors,
the ``/get`` query with its thresholds, a reply's samples, one HTTP connection to the phone)
come first in this module; the poller and the source are made of them.
"""

from __future__ import annotations

import http.client
import json
import math
import socket
import threading
import time
import urllib.parse
from dataclasses import dataclass
from typing import Any

from app.stream.events import Chunk, SourceEvent
from app.stream.phone_apps import ItemQueue, PhoneSample, count_name, finite, lines_of
from app.stream.sources import LIVE_PHONE, Source


# -- phyphox's remote interface ----------------------------------------------------------------
#
# The pieces the poller is made of: the address the user types, the running experiment's
# sensors (``/config``), the ``/get`` query with its thresholds, a reply's samples, and one HTTP
# connection to the phone (phyphox-docs, ``docs/remote-interface/openapi.yaml``).

#: phyphox sensor type -> (Sensor Fusion tag, the outputs whose values make its line).
SENSOR_TAGS: dict[str, tuple[str, tuple[str, ...]]] = {
    "accelerometer": ("ACC", ("x", "y", "z")),
    "gyroscope": ("GYR", ("x", "y", "z")),
    "magnetic_field": ("MAG", ("x", "y", "z")),
    "attitude": ("ORI", ("abs", "x", "y", "z")),
}
#: What the user reads for a sensor phyphox does not send.
SENSOR_WORDS = {"accelerometer": "accelerometer", "gyroscope": "gyroscope",
                "magnetic_field": "magnetometer", "attitude": "attitude (the phone's "
                                                              "orientation)"}
DEFAULT_PORT = 80            # iOS's default; Android shows its port (8080, ...) in the URL
MAX_REPLY_BYTES = 256 << 20


class PhyphoxError(Exception):
    """phyphox answered, but not as its API says (a status other than 200, not JSON)."""


@dataclass(frozen=True)
class PhyphoxAddress:
    host: str
    port: int

    @property
    def text(self) -> str:
        return f"{self.host}:{self.port}"

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}"


def parse_address(text: str) -> PhyphoxAddress:
    """The address phyphox shows ("http://192.168.1.5:8080", "192.168.1.5:8080",
    "192.168.1.5" -> port 80, iOS's default) -> host and port; ValueError naming the problem."""
    raw = str(text).strip()
    if not raw:
        raise ValueError("give the address phyphox shows, e.g. http://192.168.1.5:8080")
    if "://" not in raw:
        raw = "http://" + raw
    try:
        parts = urllib.parse.urlsplit(raw)
        port = parts.port
    except ValueError as error:
        raise ValueError(f"not an address: {text!r} ({error})") from None
    if parts.scheme.lower() != "http":
        raise ValueError(f"phyphox speaks plain http, not {parts.scheme}: {text!r}")
    if not parts.hostname:
        raise ValueError(f"no host in {text!r} (e.g. http://192.168.1.5:8080)")
    return PhyphoxAddress(parts.hostname, port if port is not None else DEFAULT_PORT)


@dataclass(frozen=True)
class PhyphoxSensor:
    """A sensor of the running experiment: its type, the tag it becomes and its buffers (the
    time buffer first, then those of the line's values)."""

    type: str
    tag: str
    buffers: tuple[str, ...]

    @property
    def time_buffer(self) -> str:
        return self.buffers[0]


@dataclass(frozen=True)
class ExperimentConfig:
    title: str
    sensors: tuple[PhyphoxSensor, ...]
    missing: tuple[str, ...]           # sensor types (or "type component") not there


def read_config(config: Any) -> ExperimentConfig:
    """The sensors a ``/config`` reply's ``inputs`` give (the first input of each type)."""
    if not isinstance(config, dict):
        raise PhyphoxError("/config did not answer a JSON object")
    title = str(config.get("localTitle") or config.get("title") or "?")
    found: dict[str, PhyphoxSensor] = {}
    incomplete: list[str] = []
    for item in config.get("inputs") or []:
        if not isinstance(item, dict):
            continue
        source = item.get("source")
        if source not in SENSOR_TAGS or source in found:
            continue
        outputs: dict[str, str] = {}
        for entry in item.get("outputs") or []:
            if isinstance(entry, dict):
                outputs.update({str(k): str(v) for k, v in entry.items()})
        tag, components = SENSOR_TAGS[source]
        lacking = [c for c in ("t", *components) if c not in outputs]
        if lacking:
            incomplete.append(f"{SENSOR_WORDS[source]} {', '.join(lacking)}")
            continue
        found[source] = PhyphoxSensor(source, tag, tuple(outputs[c] for c in ("t", *components)))
    missing = tuple(SENSOR_WORDS[s] for s in SENSOR_TAGS if s not in found
                    and not any(i.startswith(SENSOR_WORDS[s]) for i in incomplete))
    return ExperimentConfig(title, tuple(found[s] for s in SENSOR_TAGS if s in found),
                            missing + tuple(incomplete))


def missing_text(config: ExperimentConfig) -> str:
    """One line: what the running experiment lacks and what to do about it."""
    return (f'the phyphox experiment "{config.title}" has no {", ".join(config.missing)}: '
            "load Orientation Lab's experiment into phyphox (File > Connect a phone... shows "
            "its QR code; `orientation-lab phyphox-experiment` writes the file)")


def threshold_text(value: float) -> str:
    """A threshold as it goes into the query: the shortest text of the float phyphox sent."""
    return repr(float(value))


def get_query(sensors: tuple[PhyphoxSensor, ...], thresholds: dict[str, float | None]) -> str:
    """The ``/get`` path and query: ``full`` buffers for a sensor without a threshold yet,
    else ``time=T&value=T|time`` with the ``|`` percent-encoded (``%7C``)."""
    parts = []
    for sensor in sensors:
        threshold = thresholds.get(sensor.type)
        time_name = urllib.parse.quote(sensor.time_buffer, safe="")
        if threshold is None:
            parts += [f"{urllib.parse.quote(name, safe='')}=full" for name in sensor.buffers]
            continue
        text = urllib.parse.quote(threshold_text(threshold), safe="")
        parts.append(f"{time_name}={text}")
        parts += [f"{urllib.parse.quote(name, safe='')}={text}%7C{time_name}"
                  for name in sensor.buffers[1:]]
    return "/get?" + "&".join(parts)


@dataclass
class SensorBatch:
    samples: list[PhoneSample]
    last_time: float | None        # the newest time taken (the next threshold), None: none
    nulls: int                     # samples skipped for a null (or non-finite) value
    before_start: int              # samples at negative experiment time (skipped)
    missing: bool                  # a buffer was not in the reply


def sensor_batch(sensor: PhyphoxSensor, buffers: dict[str, Any]) -> SensorBatch:
    """The samples of one sensor in a ``/get`` reply's ``buffer`` object. Its buffers are read
    up to the shortest of them (a reply taken while the phone appended: the rest comes with
    the next poll, whose threshold is the last time taken here)."""
    arrays = []
    for name in sensor.buffers:
        entry = buffers.get(name)
        values = entry.get("buffer") if isinstance(entry, dict) else None
        if not isinstance(values, list):
            return SensorBatch([], None, 0, 0, True)
        arrays.append(values)
    count = min(len(values) for values in arrays)
    samples: list[PhoneSample] = []
    last_time = None
    nulls = before = 0
    times = arrays[0]
    columns = arrays[1:]
    for i in range(count):
        t = times[i]
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
            nulls += 1
            continue
        last_time = float(t)
        values = finite(column[i] for column in columns)
        if values is None:
            nulls += 1
            continue
        t_ms = round(t * 1000.0)
        if t_ms < 0:
            before += 1
            continue
        samples.append(PhoneSample(t_ms, sensor.tag, values))
    return SensorBatch(samples, last_time, nulls, before, False)


class Gone(Exception):
    """The phone did not answer (refused, timed out, connection broken)."""


class PhyphoxClient:
    """One HTTP connection to phyphox, one request at a time (reused while the phone keeps
    it open). :attr:`requests` counts them; :attr:`in_flight_max` is the most ever open at
    once (always 1: the poller never overlaps requests)."""

    def __init__(self, address: PhyphoxAddress, timeout_s: float = 3.0) -> None:
        self.address = address
        self.timeout_s = float(timeout_s)
        self.requests = 0
        self.in_flight = 0
        self.in_flight_max = 0
        self._connection: http.client.HTTPConnection | None = None
        self._reused = False

    def close(self) -> None:
        if self._connection is not None:
            self._connection.close()
            self._connection = None

    def _request(self, path: str) -> tuple[int, bytes]:
        self._reused = self._connection is not None
        if self._connection is None:
            self._connection = http.client.HTTPConnection(self.address.host, self.address.port,
                                                          timeout=self.timeout_s)
        self.requests += 1
        self._connection.request("GET", path, headers={"Accept": "application/json"})
        response = self._connection.getresponse()
        body = response.read(MAX_REPLY_BYTES + 1)
        if response.will_close:
            self.close()
        return response.status, body

    def get(self, path: str) -> Any:
        """GET path -> the JSON reply; _Gone when the phone does not answer, PhyphoxError
        when it answers something else."""
        self.in_flight += 1
        self.in_flight_max = max(self.in_flight_max, self.in_flight)
        try:
            try:
                status, body = self._request(path)
            except (ConnectionError, http.client.BadStatusLine):
                if not self._reused:
                    raise
                # the phone closed a kept-alive connection while it was idle: once more on a
                # new one (a request that never reached it)
                self.close()
                status, body = self._request(path)
        except (OSError, http.client.HTTPException) as error:
            self.close()
            raise Gone(_reason(error)) from None
        finally:
            self.in_flight -= 1
        if len(body) > MAX_REPLY_BYTES:
            self.close()
            raise PhyphoxError(f"{path.split('?')[0]}: a reply over "
                               f"{MAX_REPLY_BYTES >> 20} MiB")
        try:
            reply = json.loads(body)
        except ValueError:
            raise PhyphoxError(f"{path.split('?')[0]} answered {status} with something that "
                               "is not JSON (is this phyphox?)") from None
        if status != 200:
            detail = reply.get("error") if isinstance(reply, dict) else None
            raise PhyphoxError(f"{path.split('?')[0]} answered {status}"
                               + (f": {detail}" if detail else ""))
        return reply


def _reason(error: BaseException) -> str:
    if isinstance(error, socket.timeout | TimeoutError):
        return "no answer in time"
    if isinstance(error, ConnectionRefusedError):
        return "connection refused"
    text = getattr(error, "strerror", None) or str(error) or type(error).__name__
    return str(text)


# -- the poller and the source -----------------------------------------------------------------


POLL_S = 0.025               # a poll starts at most this often
MIN_GAP_S = 0.010            # ... and at least this long after the previous reply
IDLE_POLL_S = 0.25           # while the measurement is stopped or nothing can be read
STALL_S = 2.0                # no new data this long while measuring: was the data cleared?


class PhyphoxPoller:
    """The polling thread's state and work (see the module docstring); it puts Chunks of
    Sensor Fusion lines and SourceEvents into `items`."""

    def __init__(self, address: PhyphoxAddress, items: ItemQueue, timeout_s: float = 3.0,
                 poll_s: float = POLL_S, retry_max_s: float = 2.0,
                 start_measurement: bool = True, stall_s: float = STALL_S,
                 clock=time.monotonic) -> None:
        self.address = address
        self.stall_s = float(stall_s)
        self.items = items
        self.client = PhyphoxClient(address, timeout_s)
        self.poll_s = float(poll_s)
        self.retry_max_s = float(retry_max_s)
        self.start_measurement = bool(start_measurement)
        self.clock = clock
        self.state = "waiting"        # "waiting" | "connected" | "disconnected" | "stopped"
        self.connection = 0
        self.config: ExperimentConfig | None = None
        self.session: str | None = None
        self.measuring: bool | None = None
        self.thresholds: dict[str, float | None] = {}
        self.polls = 0
        self.samples = 0
        self.nulls = 0
        self.before_start = 0
        self.clears = 0
        self.sessions = 0
        self.problem = ""
        self.problems: dict[str, int] = {}
        self.gone_since: float | None = None
        self.retry_s = 0.0
        self._said = ""
        self._last_data = clock()

    # -- one step of the loop: returns how long to wait before the next ------------------------

    def step(self) -> float:
        try:
            if self.session is None:
                self._open_session()
            wait = self._poll()
        except Gone as gone:
            return self._gone(str(gone))
        except PhyphoxError as error:
            self._say(f"phyphox at {self.address.text}: {error}")
            return 1.0
        self.gone_since = None
        self.retry_s = 0.0
        return wait

    def _say(self, text: str) -> None:
        """An "error" event the first time a problem is seen (not again until another one)."""
        self.problem = text
        if text != self._said:
            self._said = text
            count_name(self.problems, text.split(":")[0])
            self.items.event("error", self.connection, self.address.text, text)

    def _status(self, reply: Any) -> dict[str, Any]:
        status = reply.get("status") if isinstance(reply, dict) else None
        if not isinstance(status, dict) or "session" not in status:
            raise PhyphoxError("/get answered without a status.session (is this phyphox?)")
        return status

    def _open_session(self) -> None:
        config = read_config(self.client.get("/config"))
        status = self._status(self.client.get("/get"))
        self.config = config
        self.session = str(status.get("session"))
        self.measuring = bool(status.get("measuring"))
        self.thresholds = {sensor.type: None for sensor in config.sensors}
        self.sessions += 1
        self._connected(f'phyphox experiment "{config.title}"'
                        + (f" (session {self.session})" if self.sessions > 1 else ""))
        if config.missing:
            self._say(missing_text(config))
        if not self.measuring and self.start_measurement and config.sensors:
            reply = self.client.get("/control?cmd=start")
            if isinstance(reply, dict) and reply.get("result") is True:
                self.measuring = True
            else:
                self._say("phyphox did not start the measurement: press the start button "
                          "in phyphox")

    def _connected(self, detail: str) -> None:
        self.connection += 1
        self.state = "connected"
        self._said = ""
        self._last_data = self.clock()
        self.items.event("connected", self.connection, self.address.text, detail)

    def _poll(self) -> float:
        config = self.config
        assert config is not None
        if not self.items.room():
            return IDLE_POLL_S                # the engine is behind: the data waits on the phone
        started = self.clock()
        reply = self.client.get(get_query(config.sensors, self.thresholds)
                                if config.sensors else "/get")
        self.polls += 1
        status = self._status(reply)
        if str(status.get("session")) != self.session:
            self.session = None               # another experiment: read its buffers again
            return 0.0
        if self.state != "connected":
            away = "" if self.gone_since is None else \
                f" after {self.clock() - self.gone_since:.1f} s"
            self._connected(f"phyphox at {self.address.text} answers again{away}; what it "
                            "held meanwhile follows")
        measuring = bool(status.get("measuring"))
        if self.measuring and not measuring:
            self._say("the measurement was stopped on the phone: press start in phyphox to "
                      "go on")
        elif measuring and not self.measuring:
            self._said = ""
            self.problem = ""
        self.measuring = measuring
        buffers = reply.get("buffer") if isinstance(reply.get("buffer"), dict) else {}
        samples: list[PhoneSample] = []
        gone_buffers = []
        for sensor in config.sensors:
            batch = sensor_batch(sensor, buffers)
            if batch.missing:
                gone_buffers.append(SENSOR_WORDS[sensor.type])
                continue
            samples += batch.samples
            self.nulls += batch.nulls
            self.before_start += batch.before_start
            if batch.last_time is not None:
                self.thresholds[sensor.type] = batch.last_time
        if gone_buffers:
            self._say(f"phyphox did not return the buffers of the {', '.join(gone_buffers)}")
        if samples:
            self.samples += len(samples)
            self._last_data = self.clock()
            self.items.chunk(self.connection, lines_of(samples))
        elif measuring and self.clock() - self._last_data > self.stall_s:
            self._check_cleared()
        if not measuring or not config.sensors:
            return IDLE_POLL_S
        return max(MIN_GAP_S, self.poll_s - (self.clock() - started))

    def _check_cleared(self) -> None:
        """Nothing new for a while although measuring: when the newest time on the phone is
        older than what was taken, the data was cleared (its time starts again at 0)."""
        self._last_data = self.clock()
        config = self.config
        if config is None or not config.sensors:
            return
        sensor = config.sensors[0]
        threshold = self.thresholds.get(sensor.type)
        if threshold is None:
            return
        reply = self.client.get("/get?" + urllib.parse.quote(sensor.time_buffer, safe=""))
        entry = reply.get("buffer", {}).get(sensor.time_buffer) if isinstance(reply, dict) \
            else None
        values = entry.get("buffer") if isinstance(entry, dict) else None
        newest = values[-1] if isinstance(values, list) and values else None
        if isinstance(newest, (int, float)) and newest < threshold:
            self.clears += 1
            self.thresholds = {s.type: None for s in config.sensors}
            self._connected("the data on the phone was cleared: starting again")

    def _gone(self, reason: str) -> float:
        self.client.close()
        now = self.clock()
        self.retry_s = min(self.retry_max_s, max(0.25, self.retry_s * 2))
        if self.state == "connected":
            self.gone_since = now
            self.state = "disconnected"
            self.items.event("disconnected", self.connection, self.address.text,
                             f"phyphox at {self.address.text} not answering ({reason}); "
                             f"retrying every {self.retry_max_s:g} s at most, and what it "
                             "holds meanwhile is fetched when it answers")
        elif self.state == "waiting":
            self._say(f"no answer from phyphox at {self.address.url} ({reason}): is remote "
                      "access on in phyphox, and the address the one it shows? retrying")
        return self.retry_s


class PhyphoxThread:
    """Runs a :class:`PhyphoxPoller` in a daemon thread until stopped."""

    def __init__(self, poller: PhyphoxPoller) -> None:
        self.poller = poller
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="phyphox", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
            self._thread = None
        self.poller.client.close()
        self.poller.state = "stopped"

    def _run(self) -> None:
        failures = 0
        while not self._stop.is_set():
            try:
                wait = self.poller.step()
                failures = 0
            except Exception as error:   # never die silently: report, the consumer shows it
                failures += 1
                self.poller.items.event("error", detail=f"phyphox poller failed: {error!r}")
                if failures >= 20:
                    return
                wait = 0.5
            if wait > 0:
                self._stop.wait(wait)


class PhyphoxSource(Source):
    """The phone through phyphox's remote interface at `url` (see the module docstring).

    :meth:`start` never waits for the phone: until it answers the state is "waiting" and an
    "error" event says why it does not (the window and `serve` show it)."""

    kind = "phyphox"
    capabilities = LIVE_PHONE

    def __init__(self, url: str, timeout_s: float = 3.0, poll_s: float = POLL_S,
                 retry_max_s: float = 2.0, start_measurement: bool = True,
                 stall_s: float = STALL_S, max_queued_bytes: int = 16 << 20) -> None:
        self.address = parse_address(url)
        self.items = ItemQueue(max_queued_bytes)
        self.poller = PhyphoxPoller(self.address, self.items, timeout_s, poll_s, retry_max_s,
                                    start_measurement, stall_s)
        self._thread = PhyphoxThread(self.poller)
        self.name = f"phyphox at {self.address.text}"

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._thread.stop()

    @property
    def port(self) -> int | None:
        return None

    def read(self, timeout: float = 0.05) -> list[Chunk | SourceEvent]:
        return self.items.get(timeout)

    def connect_hint(self) -> str:
        return (f"polling phyphox at {self.address.url} (in phyphox: Allow remote access; "
                "the measurement is started from here)")

    def info(self) -> dict[str, Any]:
        poller = self.poller
        config = poller.config
        return {"connection_state": "waiting" if poller.state == "stopped" else poller.state,
                "peer": self.address.text, "port": None, "listen_addresses": [],
                "replay": None, "connect_hint": self.connect_hint(),
                "phyphox": {"url": self.address.url,
                            "experiment": config.title if config else None,
                            "missing": list(config.missing) if config else [],
                            "measuring": poller.measuring, "session": poller.session,
                            "sessions": poller.sessions, "polls": poller.polls,
                            "requests": poller.client.requests,
                            "requests_in_flight_max": poller.client.in_flight_max,
                            "samples": poller.samples, "null_values": poller.nulls,
                            "before_start": poller.before_start, "clears": poller.clears,
                            "problem": poller.problem}}
