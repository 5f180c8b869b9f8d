"""Recording under faults: a full disk, a removed folder, size and free-space limits stop the
recording with a one-line reason; the stream and the estimates go on (issue 10, item 4)."""

from __future__ import annotations

import errno
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from waiting import wait_until as _wait

from app.engine.estimates import EstimatesWriter
from app.engine.worker import Engine
from app.stream.emulator import PhoneEmulator
from app.stream.recorder import Recorder, holds_session, new_session_folder
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


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
def test_dev_full_through_the_tcp_server_stream_and_estimates_go_on(tmp_path):
    folder = tmp_path / "s"
    folder.mkdir()
    (folder / "raw.txt").symlink_to("/dev/full")               # every flush: ENOSPC
    recorder = Recorder(folder)
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
    free = shutil.disk_usage(tmp_path).free
    recorder = Recorder(tmp_path / "s", min_free_bytes=free + (1 << 30))
    assert recorder.closed and recorder.error.startswith("less than ")
    recorder.write_line(b"1\tACC\t0\t0\t9.8\n")
    assert (tmp_path / "s" / "raw.txt").read_bytes() == b""


def test_a_second_recording_gets_a_new_session_folder(tmp_path):
    first = tmp_path / "rec"
    assert new_session_folder(first) == first
    Recorder(first).close()
    assert holds_session(first)
    second = new_session_folder(first)
    assert second == tmp_path / "rec-2"
    Recorder(second).close()
    assert new_session_folder(first) == tmp_path / "rec-3"
