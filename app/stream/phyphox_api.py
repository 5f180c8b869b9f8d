"""phyphox's remote interface, the pieces the poller is made of: the address the user types,
the running experiment's sensors (``/config``), the ``/get`` query with its thresholds, a
reply's samples, and one HTTP connection to the phone (phyphox-docs,
``docs/remote-interface/openapi.yaml``). :mod:`app.stream.phyphox` polls with them."""

from __future__ import annotations

import http.client
import json
import math
import socket
import urllib.parse
from dataclasses import dataclass
from typing import Any

from app.stream.phone_apps import PhoneSample, finite


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
