"""Replay sources, recorder, LAN addresses."""

from __future__ import annotations

import json
import time

from waiting import wait_until

from app.stream.tcp_server import lan_ipv4_addresses, parse_ip_addr_output
from app.stream.recorder import Recorder
from app.stream.lines import pacing_times
from app.stream.sources import LineReplaySource, LogFileSource
from app.stream.events import Chunk, SourceEvent
from app.stream.events import ReplayControl


def _drain(source, seconds: float = 5.0):
    chunks, events = [], []

    def finished() -> bool:
        for item in source.read(0.01):
            (chunks if isinstance(item, Chunk) else events).append(item)
        return bool(events) and events[-1].kind == "finished"
    wait_until(finished, seconds, what="the replay's finished event", poll_s=0.0)
    return chunks, events


def test_pacing_follows_each_tag_clock():
    lines = [b"164956521\tACC\t0\t0\t9\n", b"33884521\tGYR\t0\t0\t0\n",
             b"164956531\tACC\t0\t0\t9\n", b"33884531\tGYR\t0\t0\t0\n", b"bad\n",
             b"1585038883072\tRSSWIFI\ta\tb\t1\t2\n", b"164956541\tACC\t0\t0\t9\n"]
    assert pacing_times(lines) == [0.0, 0.0, 0.01, 0.01, 0.01, 0.01, 0.02]


def test_fast_replay_hands_over_the_file_verbatim(tmp_path):
    data = b"".join(f"{1000 + k}\tACC\t0\t0\t9.8\r\n".encode() for k in range(10_000))
    path = tmp_path / "log.txt"
    path.write_bytes(data)
    source = LogFileSource(path, speed=0)
    source.start()
    chunks, events = _drain(source)
    source.stop()
    assert b"".join(c.data for c in chunks) == data
    assert [e.kind for e in events] == ["connected", "finished"]


def test_pause_step_seek_and_loop():
    lines = [f"{1000 + 10 * k}\tACC\t0\t0\t9.8\n".encode() for k in range(100)]
    source = LineReplaySource(lines, "test", speed=1.0, paused=True)
    source.start()
    assert [type(i) for i in source.read(0.01)] == [SourceEvent]     # connected, nothing else
    source.control(ReplayControl(step=3))
    assert [len(i.data.splitlines()) for i in source.read(0.01)] == [3]
    source.control(ReplayControl(seek_s=0.5))
    items = source.read(0.01)
    assert items[0].kind == "seek"
    assert len(items[1].data.splitlines()) == 50          # re-sync: lines up to the target at once
    assert source.info()["replay"]["position_s"] == 0.5
    source.control(ReplayControl(paused=False, speed=0, loop=True))
    items = source.read(0.01)
    assert len(items[0].data.splitlines()) == 50 and items[1].kind == "loop"
    assert source.info()["replay"]["loop"] is True


def test_real_speed_replay_takes_log_time():
    lines = [f"{1000 + 10 * k}\tACC\t0\t0\t9.8\n".encode() for k in range(21)]
    source = LineReplaySource(lines, "test", speed=1.0)
    source.start()
    started = time.perf_counter()
    chunks, events = _drain(source)
    elapsed = time.perf_counter() - started
    assert sum(len(c.data.splitlines()) for c in chunks) == 21
    assert 0.15 < elapsed < 2.0 and events[-1].kind == "finished"


def test_recorder_writes_raw_and_session_json(tmp_path):
    now = [100.0]
    recorder = Recorder(tmp_path / "session", settings={"g": 9.81}, info={"source": "tcp"},
                        clock=lambda: now[0])
    recorder.write_line(b"1\tACC\t1\t2\t3\r\n")
    recorder.add_event("sensor", 1, sensor="mag", enabled=False)
    recorder.set_stats({"lines": 1})
    now[0] += 0.45
    recorder.tick()                                    # flushed within half a second
    assert (tmp_path / "session" / "raw.txt").read_bytes() == b"1\tACC\t1\t2\t3\r\n"
    recorder.close()
    recorder.close()
    session = json.loads((tmp_path / "session" / "session.json").read_text())
    assert session["app_version"] and session["started_utc"] and session["stopped_utc"]
    assert session["settings"] == {"g": 9.81} and session["stats"] == {"lines": 1}
    assert session["timeline"][0]["sensor"] == "mag" and session["raw_lines"] == 1
    assert not (tmp_path / "session" / "session.json.tmp").exists()


def test_lan_addresses():
    addresses = lan_ipv4_addresses()
    assert addresses and all(a.count(".") == 3 for a in addresses)
    text = ("1: lo    inet 127.0.0.1/8 scope host lo\\       valid_lft forever\n"
            "2: eth0    inet 192.168.1.23/24 brd 192.168.1.255 scope global eth0\n")
    assert parse_ip_addr_output(text) == ["127.0.0.1", "192.168.1.23"]
