"""read_log and LogFile: real logs, gz, errors, arrays, chunk by chunk."""

from __future__ import annotations

import gzip
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

from app.stream.lines import LogError
from app.stream.logfile import LogData, LogFile, read_log

EXPECTED_DAMAGED = {"sensorLog_20221024T182616_standstill.txt": 2}


def test_every_real_log_reads_with_damage_counted(realphone_dir):
    logs = sorted(realphone_dir.glob("*.txt"))
    assert len(logs) >= 7
    for path in logs:
        log = read_log(path)
        assert log.stats.damaged == EXPECTED_DAMAGED.get(path.name, 0), path.name
        assert log.stats.unknown == 0 and log.stats.too_long == 0
        lines = path.read_bytes().count(b"\n")
        assert log.stats.parse.lines == lines
        assert path.name in log.stats.summary()


def test_standstill_damage_and_out_of_order_block(realphone_dir):
    log = read_log(realphone_dir / "sensorLog_20221024T182616_standstill.txt")
    assert log.first_bad_line_number == 1191
    assert log.stats.out_of_order == 420     # the 0.9 s block written late: 187 ACC, 187 GYR, 46 MAG
    assert [e[0] for e in log.stats.parse.bad_examples] == [1191, 1866]
    assert {"RAWGYR", "RAWMAG", "GPS"} <= set(log.stats.parse.per_tag)
    summary = log.stats.summary()
    assert "2 damaged" in summary and "first bad line 1191" in summary and "420 out of order" in summary


def test_clock_offset_log_is_aligned(realphone_dir):
    log = read_log(realphone_dir / "sensorLog_20221020T074342.txt")
    assert log.stats.clock_quirks == ["GYR clock -131072000 ms vs ACC (aligned)",
                                      "MAG clock -131072000 ms vs ACC (aligned)"]
    arrays = log.to_arrays()
    assert 27.0 < log.duration_s < 28.0           # not 36 hours
    has_acc = ~np.isnan(arrays.acc[:, 0])
    both = has_acc & ~np.isnan(arrays.gyr[:, 0])
    assert both.sum() / has_acc.sum() > 0.9       # ACC and GYR share instants after alignment


def test_to_arrays_rows_and_duplicates(tmp_path):
    path = tmp_path / "log.txt"
    path.write_text("10\tACC\t1\t2\t3\n10\tGYR\t4\t5\t6\n10\tGYR\t7\t8\t9\n20\tMAG\t1\t1\t1\n"
                    "20\tORI\t1\t0\t0\t0\n30\tACC\t0\t0\t9.8\n35\tRSSWIFI\ta\tb\t1\t2\n")
    arrays = read_log(path).to_arrays()
    assert arrays.t_ms.tolist() == [10, 20, 30]
    assert arrays.gyr[0].tolist() == [7, 8, 9]            # last duplicate kept
    assert np.isnan(arrays.gyr[1:]).all()
    assert arrays.ori[1].tolist() == [1, 0, 0, 0] and np.isnan(arrays.ori[0]).all()
    assert arrays.t_s.tolist() == [0.01, 0.02, 0.03]


def test_gzip_and_final_line_without_newline(tmp_path):
    path = tmp_path / "log.txt.gz"
    with gzip.open(path, "wb") as stream:
        stream.write(b"10\tACC\t1\t2\t3\r\n20\tACC\t1\t2\t3")
    log = read_log(path)
    assert log.t_ms.tolist() == [10, 20]


@pytest.mark.parametrize("content, message", [
    (b"", "empty file"),
    (b"\x00\x01\x02binary\x00" * 100, "binary"),
    (b"hello world\nthis is not a log\n", "no line in the phone's format (line 1"),
])
def test_unusable_files_raise_log_error_naming_the_file(tmp_path, content, message):
    path = tmp_path / "bad.txt"
    path.write_bytes(content)
    with pytest.raises(LogError) as caught:
        read_log(path)
    assert str(path) in str(caught.value) and message in str(caught.value)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(LogError, match="no such file"):
        read_log(tmp_path / "missing.txt")
    with pytest.raises(LogError, match="directory"):
        read_log(tmp_path)


def test_a_log_with_nul_bytes_and_junk_in_places_is_read_with_those_lines_counted(
        tmp_path, realphone_dir):
    """Was: one NUL byte in the first 8 KiB refused the whole log as "binary data"."""
    from app.stream.lines import read_lines
    from app.stream.sources import LogFileSource
    clean = (realphone_dir / "tsrt14_lab2_rotation.txt").read_bytes()
    lines = clean.splitlines(keepends=True)
    junk = bytes(b for b in range(256) if b != 10)
    dirty = b"".join(lines[:10] + [b"\x00" * 2000 + b"\n", junk + b"\n",
                                   lines[10][:-1] + b"\x00\n"] + lines[11:])
    path = tmp_path / "dirty.txt"
    path.write_bytes(dirty)
    log = read_log(path)
    assert log.stats.damaged == 3 and log.stats.parse.damaged_reasons == {"binary data": 3}
    assert len(log) == len(read_log(realphone_dir / "tsrt14_lab2_rotation.txt")) - 1
    assert len(read_lines(path)) == len(lines) + 2          # the replay and `send` read it too
    LogFileSource(path)
    mostly_binary = tmp_path / "binary.txt"
    mostly_binary.write_bytes(bytes(range(256)) * 400 + clean)
    with pytest.raises(LogError, match="binary data"):
        read_log(mostly_binary)
    with pytest.raises(LogError, match="binary data"):
        read_lines(mostly_binary)


# ---- chunk by chunk ----------------------------------------------------------------------------

@st.composite
def _log_text(draw) -> bytes:
    """A phone log with what the reader meets: sensors at their own rates, equal times, lines
    written twice, late and out-of-order lines, other tags, junk, a clock that restarts."""
    lines = []
    t = draw(st.integers(1_000, 10**9))
    for _ in range(draw(st.integers(1, 400))):
        kind = draw(st.sampled_from(["ACC", "GYR", "MAG", "ORI", "ACC", "GYR", "again", "late",
                                     "junk", "other", "restart"]))
        t += draw(st.integers(0, 12))
        if kind == "restart":
            t = max(1, t - draw(st.integers(60_000, 10**6)))
            continue
        if kind == "again" and lines:
            lines.append(lines[-1])
            continue
        if kind == "junk":
            lines.append(draw(st.sampled_from([b"", b"\t\t", b"12\tACC\t1\t2\n", b"x\x00y"]))
                         + b"\n")
            continue
        when = t - draw(st.integers(1, 3000)) if kind == "late" else t
        tag = "ACC" if kind == "late" else kind
        if kind == "other":
            lines.append(f"{when}\tRSSWIFI\tnet\t-40\n".encode())
            continue
        count = 4 if tag == "ORI" else 3
        values = draw(st.lists(st.floats(-9.0, 9.0, allow_nan=False), min_size=count,
                               max_size=count))
        if tag == "ORI":
            values = [1.0, 0.0, 0.0, 0.0]
        lines.append(("\t".join([str(when), tag] + [f"{v:.6g}" for v in values]) + "\n")
                     .encode())
    return b"".join(lines)


@given(text=_log_text(), chunk_bytes=st.integers(1, 2048))
@hsettings(max_examples=60, deadline=None,
           suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_a_log_read_in_chunks_of_any_size_gives_what_it_gives_read_whole(tmp_path, text,
                                                                          chunk_bytes):
    path = tmp_path / "log.txt"
    path.write_bytes(text)
    try:
        whole = read_log(path, chunk_bytes=len(text) + 1)
    except LogError as error:
        with pytest.raises(LogError, match=re.escape(str(error))):
            read_log(path, chunk_bytes=chunk_bytes)
        return
    log = LogFile(path, chunk_bytes=chunk_bytes)
    pieces = list(log.chunks())
    chunked = LogData.concatenate(str(path), pieces, log.stats)
    assert chunked.t_ms.tolist() == whole.t_ms.tolist()
    assert chunked.tag.tolist() == whole.tag.tolist()
    np.testing.assert_array_equal(chunked.values, whole.values)
    assert chunked.session_starts == whole.session_starts
    assert chunked.stats.summary() == whole.stats.summary()
    assert chunked.stats.repeated == whole.stats.repeated
    # and a LogData hands its samples on in chunks the same way
    again = LogData.concatenate(str(path), list(whole.chunks(size=max(1, chunk_bytes // 7))))
    assert again.t_ms.tolist() == whole.t_ms.tolist()
    assert again.session_starts == whole.session_starts
