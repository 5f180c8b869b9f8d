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
"""

from __future__ import annotations

import threading
import time
import urllib.parse
from typing import Any

from app.stream.events import Chunk, SourceEvent
from app.stream.phone_apps import ItemQueue, PhoneSample, count_name, lines_of
from app.stream.phyphox_api import (SENSOR_WORDS, ExperimentConfig, Gone, PhyphoxAddress,
                                    PhyphoxClient, PhyphoxError, get_query, missing_text,
                                    parse_address, read_config, sensor_batch)
from app.stream.sources import LIVE_PHONE, Source

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
