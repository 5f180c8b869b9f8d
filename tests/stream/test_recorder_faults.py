"""Recording under faults: a full disk, a removed folder, size and free-space limits stop the
recording with a one-line reason; the stream and the estimates go on (issue 10, item 4)."""

from __future__ import annotations

import errno
import json
import multiprocessing
import os
import shutil
import stat
import subprocess
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from waiting import wait_until as _wait

from app.engine.offline.filtering import EstimatesWriter
from app.engine.live.worker import Engine
from app.stream.emulator import PhoneEmulator
from app.stream.recorder import Recorder, holds_session
from app.stream.sources import TcpSource


def _lines(n: int, t0: int = 1000) -> bytes:
    return "".join(f"{t0 + 10 * k}\tGYR\t0.01\t0.0\t0.0\n{t0 + 10 * k}\tACC\t0.0\t0.0\t9.81\n"
                   for k in range(n)).encode()


class _FullDisk:
    """A raw file whose writes fail as on a full disk; flush and close fail too."""

    def __init__(self, partial_into: Path | None = None) -> None:
        self.partial_into = partial_into

    def write(self, data: bytes) -> int:
        if self.partial_into is not None:      # half of it reached the disk first
            with open(self.partial_into, "ab") as stream:
                stream.write(data[:len(data) // 2])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def flush(self) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def close(self) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def tell(self) -> int:
        return 0


def test_enospc_from_write_flush_and_close_stops_the_recording_without_raising(tmp_path):
    recorder = Recorder(tmp_path / "s")
    recorder.write_block(b"1\tACC\t0\t0\t9.8\n", 1)
    recorder.tick()
    recorder._raw.flush()
    recorder._raw.close()
    recorder._raw = _FullDisk()
    recorder.write_block(b"2\tACC\t0\t0\t9.8\n", 1)            # must not raise
    assert recorder.closed and "No space left on device" in recorder.error
    assert recorder.lines_written == 1
    recorder.write_line(b"3\tACC\t0\t0\t9.8\n")                 # ignored
    recorder.tick()
    recorder.flush()
    recorder.close()                                            # close errors are kept too
    assert recorder.lines_written == 1
    assert "No space left" in (tmp_path / "s" / "session.json").read_text()


def test_a_write_that_fails_half_way_leaves_only_whole_lines(tmp_path):
    recorder = Recorder(tmp_path / "s")
    recorder.write_block(b"1\tACC\t0.0\t0.0\t9.8\n", 1)
    recorder._raw.flush()
    recorder._raw.close()
    raw = tmp_path / "s" / "raw.txt"
    recorder._raw = _FullDisk(partial_into=raw)
    recorder.write_block(b"2\tACC\t0.25\t0.5\t9.8125\n3\tACC\t0.0\t0.0\t9.8\n", 2)
    assert recorder.error is not None
    assert raw.read_bytes() == b"1\tACC\t0.0\t0.0\t9.8\n"      # "2\tACC\t0.25\t0.5\t9" cut


DEV_FULL = os.path.exists("/dev/full") and stat.S_ISCHR(os.stat("/dev/full").st_mode)


@pytest.mark.skipif(not DEV_FULL, reason="needs the /dev/full device")
def test_dev_full_through_the_tcp_server_stream_and_estimates_go_on(tmp_path):
    folder = tmp_path / "s"
    recorder = Recorder(folder)
    recorder._raw.close()
    recorder._raw = open("/dev/full", "ab")                    # every flush: ENOSPC
    estimates = EstimatesWriter(tmp_path / "estimates.csv")
    engine = Engine(TcpSource("127.0.0.1", 0), comparisons=False, record_rows=True,
                    recorder=recorder, estimates=estimates)
    with engine:
        with PhoneEmulator("127.0.0.1", engine.source.port) as phone:
            phone.send(_lines(100))
            _wait(lambda: recorder.error is not None)
            phone.send(_lines(100, t0=2000))
        health = _wait(lambda: (h := engine.snapshot_now().health).lines_total == 400
                       and h.connection_state == "disconnected" and h)
    assert "No space left on device" in health.recording
    assert health.recording.startswith("recording stopped")
    assert any("recording stopped" in warning for warning in health.warnings)
    assert engine.failures.maxlen and not engine.failures      # no engine error
    rows = np.concatenate([r.t_ms for r in engine.rows_log])
    assert rows[-1] == 2990 and len(rows) == 200              # estimates went on


def test_a_removed_folder_stops_the_recording(tmp_path):
    folder = tmp_path / "s"
    recorder = Recorder(folder)
    recorder.write_block(_lines(10), 20)
    shutil.rmtree(folder)

    def stopped() -> bool:
        recorder.write_block(_lines(10), 20)
        recorder.tick()
        return recorder.error is not None
    _wait(stopped, 10, what="the recording to stop", poll_s=0.05)
    assert recorder.closed and ("No such file or directory" in recorder.error
                              or "was removed" in recorder.error)
    recorder.close()


def test_size_limit_stops_at_a_line_boundary(tmp_path):
    recorder = Recorder(tmp_path / "s", max_bytes=1000)
    line = b"1000\tACC\t0.0\t0.0\t9.81\n"                          # 22 bytes
    for _ in range(100):
        recorder.write_line(line)
    recorder.close()
    raw = (tmp_path / "s" / "raw.txt").read_bytes()
    assert raw == line * (1000 // len(line))
    assert recorder.error == "raw.txt reached the size limit of 1 KB"


def test_free_space_limit_stops_before_the_disk_is_full(tmp_path):
    now = [0.0]
    recorder = Recorder(tmp_path / "s", min_free_bytes=1, clock=lambda: now[0])
    recorder.write_line(b"1\tACC\t0\t0\t9.8\n")
    recorder.min_free_bytes = shutil.disk_usage(tmp_path).free + (1 << 30)
    now[0] = 2.0
    recorder.tick()                                   # the free-space check, once a second
    assert recorder.closed and recorder.error.startswith("less than ")
    recorder.write_line(b"2\tACC\t0\t0\t9.8\n")
    assert (tmp_path / "s" / "raw.txt").read_bytes() == b"1\tACC\t0\t0\t9.8\n"
    session = json.loads((tmp_path / "s" / "session.json").read_text())
    assert session["stopped_because"] == recorder.error and session["raw_lines"] == 1


def test_a_recording_refused_for_free_space_leaves_nothing_behind(tmp_path):
    """Was: a recording refused at its start (too little free space) left a stub session (an
    empty raw.txt and session.json), the next recording went to DIR-2 and `filter DIR` said
    "empty file". Now nothing is made, not even the parents it would have made."""
    free = shutil.disk_usage(tmp_path).free
    folder = tmp_path / "new" / "rec"
    with pytest.raises(OSError, match=r"cannot record into .*rec: less than \d+ MB free on "
                                      r"the disk \(\d+ MB left\)"):
        Recorder(folder, min_free_bytes=free + (1 << 30))
    assert list(tmp_path.iterdir()) == []
    assert _folder_of(folder) == folder                   # the next one gets the folder


def _folder_of(directory: Path) -> Path:
    recorder = Recorder(directory)
    recorder.close()
    return recorder.directory


def test_a_second_recording_gets_a_new_session_folder(tmp_path):
    first = tmp_path / "rec"
    assert not holds_session(first)
    assert _folder_of(first) == first
    assert holds_session(first)
    assert _folder_of(first) == tmp_path / "rec-2"           # it claims the next free one
    only_json = tmp_path / "rec-3"
    only_json.mkdir()
    (only_json / "session.json").write_text("{}")           # a session without raw.txt
    assert _folder_of(first) == tmp_path / "rec-4"


def _claim(base: Path, barrier, line: bytes) -> str:
    """One recorder of a race: waits for the others, records one line into `base` (or where
    it went)."""
    barrier.wait()
    recorder = Recorder(base, min_free_bytes=0)
    recorder.write_line(line)
    recorder.close()
    return str(recorder.directory)


def _claim_in_process(base: str, barrier, number: int, results) -> None:
    results.put(_claim(Path(base), barrier, b"%d\tACC\t0\t0\t9.8\n" % number))


def _check_claims(base: Path, folders: list[str], count: int) -> None:
    assert len(set(folders)) == count                      # one folder each
    lines = sorted((Path(folder) / "raw.txt").read_bytes() for folder in folders)
    assert all(raw.count(b"\n") == 1 for raw in lines)     # nobody shares a raw.txt
    assert sorted(p.name for p in base.parent.iterdir()) == sorted(
        [base.name] + [f"{base.name}-{k}" for k in range(2, count + 1)])


def test_recorders_racing_for_one_folder_each_claim_their_own(tmp_path):
    """Was: two recorders started at the same moment could both take the same folder (13 of
    300 synchronised attempts; once both wrote one raw.txt). Now raw.txt is created
    exclusively: each gets its own folder, DIR, DIR-2, ..., DIR-N."""
    count = 24
    base = tmp_path / "race" / "rec"
    barrier = threading.Barrier(count)
    with ThreadPoolExecutor(count) as pool:
        folders = list(pool.map(lambda k: _claim(base, barrier, b"%d\tACC\t0\t0\t9.8\n" % k),
                                range(count)))
    _check_claims(base, folders, count)


@pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(),
                    reason="needs fork")
def test_recorder_processes_racing_for_one_folder_each_claim_their_own(tmp_path):
    count = 8
    base = tmp_path / "race" / "rec"
    context = multiprocessing.get_context("fork")
    barrier = context.Barrier(count)
    results = context.Queue()
    processes = [context.Process(target=_claim_in_process, args=(str(base), barrier, k, results))
                 for k in range(count)]
    for process in processes:
        process.start()
    try:
        folders = [results.get(timeout=60) for _ in range(count)]
    finally:
        for process in processes:
            process.join(timeout=60)
    assert all(process.exitcode == 0 for process in processes)
    _check_claims(base, folders, count)


def _finished_on_disk(folder: Path, reason: str) -> dict:
    """session.json of a recording stopped by `reason`: its counts are those of raw.txt, and
    nothing else is left in the folder."""
    session = json.loads((folder / "session.json").read_text())
    raw = (folder / "raw.txt").read_bytes()
    assert reason in session["stopped_because"] and session["stopped_utc"]
    assert (session["raw_lines"], session["raw_bytes"]) == (raw.count(b"\n"), len(raw))
    assert raw.endswith(b"\n")
    assert sorted(p.name for p in folder.iterdir()) == ["raw.txt", "session.json"]
    return session


@pytest.fixture
def small_disk(tmp_path):
    """A 512 KiB tmpfs (root only: mounted for the test)."""
    if os.geteuid() != 0 or not shutil.which("mount"):
        pytest.skip("mounting a small tmpfs needs root")
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=512k", "tmpfs", str(disk)],
                             capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs: {mounted.stderr.decode().strip()}")
    yield disk
    subprocess.run(["umount", str(disk)], check=True)


def test_a_full_disk_leaves_a_finished_session(small_disk):
    """Was: after a full disk session.json was stale (no stop reason, the count of an earlier
    rewrite) and an empty session.json.tmp stayed. Now the reserve kept beside it makes room
    for the last rewrite: the stop reason and the counts of the whole lines raw.txt holds."""
    folder = small_disk / "rec"
    recorder = Recorder(folder, min_free_bytes=0)
    recorder.add_event("marker", 1000, id=1, label="before the disk filled")
    block = _lines(50)
    while not recorder.closed:                 # the engine's pattern: blocks, then a flush
        recorder.write_block(block, 100)
        recorder.flush()
    recorder.close()
    session = _finished_on_disk(folder, "No space left on device")
    assert session["raw_lines"] > 1000 and session["timeline"][0]["label"]


class _NoRoomForJson:
    """session.json's temporary file cannot be written out (fsync: ENOSPC) while the reserve
    takes the disk's last bytes."""

    def __init__(self, monkeypatch, folder: Path) -> None:
        self.full = False
        original = os.fsync

        def fsync(fd) -> None:
            if self.full and (folder / "session.json.reserve").exists():
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            original(fd)
        monkeypatch.setattr(os, "fsync", fsync)


def test_the_last_rewrite_of_session_json_uses_the_reserve(tmp_path, monkeypatch):
    """The same without a small disk: raw.txt's writes fail half-way, session.json's rewrite
    fails while the reserve is there; the finished session says why and counts what raw.txt
    holds."""
    folder = tmp_path / "s"
    disk = _NoRoomForJson(monkeypatch, folder)
    recorder = Recorder(folder)
    assert (folder / "session.json.reserve").stat().st_size >= 64 << 10
    recorder.write_block(_lines(10), 20)
    recorder.flush()
    recorder._raw.close()
    recorder._raw = _FullDisk(partial_into=folder / "raw.txt")
    disk.full = True
    recorder.write_block(_lines(10, t0=2000), 20)             # half of it reaches the disk
    recorder.close()
    session = _finished_on_disk(folder, "No space left on device")
    assert session["raw_lines"] == 20 + 10                     # 10 whole lines of the half


def test_the_last_rewrite_of_session_json_is_tried_again_when_space_is_back(tmp_path,
                                                                            monkeypatch):
    folder = tmp_path / "s"
    disk = _NoRoomForJson(monkeypatch, folder)
    now = [0.0]
    recorder = Recorder(folder, clock=lambda: now[0])
    recorder.write_block(_lines(5), 10)
    (folder / "session.json.reserve").unlink()
    (folder / "session.json.reserve").mkdir()                  # cannot be released
    disk.full = True
    recorder._raw.close()
    recorder._raw = _FullDisk()
    recorder.write_block(_lines(5), 10)
    assert recorder.closed
    assert "stopped_because" not in json.loads((folder / "session.json").read_text())
    assert not (folder / "session.json.tmp").exists()
    (folder / "session.json.reserve").rmdir()                  # space again
    now[0] = 5.0
    recorder.tick()
    assert "No space left" in json.loads((folder / "session.json").read_text())[
        "stopped_because"]
