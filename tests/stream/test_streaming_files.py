"""A log read block by block (line_blocks), its pacing carried from block to block (Pacer), and
`send` streaming its file: the same lines and times as the whole file at once."""

from __future__ import annotations

import gzip
import socket
import threading

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

from app.cli import main
from app.stream import lines as lines_module
from app.stream.emulator import PhoneEmulator
from app.stream.lines import LogError, Pacer, line_blocks, line_starts, pacing_times

HEALTH = [HealthCheck.function_scoped_fixture]

_line = st.one_of(
    st.builds(lambda t, tag: f"{t}\t{tag}\t1\t2\t3\n".encode(),
              st.integers(0, 10**12), st.sampled_from(["ACC", "GYR", "MAG", "ORI", "RSSWIFI"])),
    st.builds(lambda t, k: f"{t}\tTAG{k}\t1\n".encode(), st.integers(0, 10**6),
              st.integers(0, 80)),                      # more tags than the kernel holds
    st.builds(lambda digits: digits.encode() + b"\tACC\t0\n",
              st.text("0123456789", min_size=19, max_size=25)),     # longer than int64
    st.sampled_from([b"\n", b"junk\n", b"12\n", b"\t\t\n", b"7\tACC"]))


@given(lines=st.lists(_line, min_size=1, max_size=120), cuts=st.lists(st.integers(0, 120)))
@hsettings(max_examples=80, deadline=None)
def test_pacing_block_by_block_is_the_pacing_of_the_whole(lines, cuts):
    lines = [line if line.endswith(b"\n") else line + b"\n" for line in lines]
    expected = pacing_times(lines)
    pacer = Pacer()
    bounds = sorted({0, len(lines), *(min(c, len(lines)) for c in cuts)})
    got = []
    for first, last in zip(bounds[:-1], bounds[1:]):
        block = b"".join(lines[first:last])
        got.extend(pacer.times(block, line_starts(block)).tolist())
    assert got == expected


@given(data=st.binary(min_size=1, max_size=3000),
       block_bytes=st.integers(1, 700), drop_torn=st.booleans())
@hsettings(max_examples=80, deadline=None, suppress_health_check=HEALTH)
def test_blocks_of_whole_lines_hold_the_file(tmp_path, monkeypatch, data, block_bytes,
                                             drop_torn):
    monkeypatch.setattr(lines_module, "_MAX_CARRY_BYTES", 500)     # a "line" of more: pieces
    monkeypatch.setattr(lines_module, "check_text", lambda path, chunk: None)
    path = tmp_path / "log.txt"
    path.write_bytes(data)
    assume(not data.startswith(b"\x1f\x8b"))       # (a gzip file's magic)
    torn = data[data.rfind(b"\n") + 1:]
    assume(not (drop_torn and len(torn) > 500))     # (an endless torn line goes on in pieces)
    whole = data + b"\n" if not data.endswith(b"\n") else data
    if drop_torn and not data.endswith(b"\n"):
        whole = data[:data.rfind(b"\n") + 1]
    try:
        blocks = list(line_blocks(path, block_bytes, drop_torn))
    except LogError as error:
        assert drop_torn and b"\n" not in data and "no whole line" in str(error)
        return
    assert b"".join(blocks) == whole
    long_line = max(len(part) for part in whole.split(b"\n"))
    assert all(block.endswith(b"\n") for block in blocks) or long_line > 500


def _sink() -> tuple[socket.socket, list[bytes], threading.Thread]:
    server = socket.create_server(("127.0.0.1", 0))
    received: list[bytes] = []

    def serve() -> None:
        connection, _ = server.accept()
        with connection:
            while data := connection.recv(1 << 16):
                received.append(data)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return server, received, thread


def test_send_streams_a_gzip_log_block_by_block(tmp_path, realphone_dir, capsys):
    raw = (realphone_dir / "tsrt14_lab2_rotation.txt").read_bytes()
    path = tmp_path / "log.txt.gz"
    path.write_bytes(gzip.compress(raw))
    server, received, thread = _sink()
    with server:
        port = server.getsockname()[1]
        assert main(["send", str(path), "--port", str(port), "--speed", "0"]) == 0
        thread.join(30)
    assert b"".join(received) == raw
    count = raw.count(b"\n")
    assert f"sent {count} lines" in capsys.readouterr().err


def test_send_paces_the_lines_block_by_block(tmp_path):
    """Blocks of a few lines each: the timing runs on across blocks (10 lines 20 ms apart at
    speed 4: about 45 ms, all arrive in order)."""
    lines = [f"{1000 + 20 * k}\tACC\t0\t0\t9.8\n".encode() for k in range(10)]
    server, received, thread = _sink()
    with server:
        with PhoneEmulator("127.0.0.1", server.getsockname()[1]) as phone:
            sent = phone.stream_blocks(lambda: [b"".join(lines[:3]), b"".join(lines[3:])],
                                       speed=4.0)
        thread.join(30)
    assert sent == 10 and b"".join(received) == b"".join(lines)


def test_send_dev_zero_is_one_line_and_exit_2(capsys):
    """Was: `send /dev/zero` read the endless file whole (MemoryError)."""
    assert main(["send", "/dev/zero", "--port", "9", "--speed", "0"]) == 2
    err = capsys.readouterr().err
    assert "binary data" in err and len(err.strip().splitlines()) == 1


def test_a_log_that_breaks_off_while_it_is_sent_is_one_line(tmp_path, realphone_dir, capsys):
    raw = (realphone_dir / "tsrt14_lab2_rotation.txt").read_bytes() * 40
    packed = gzip.compress(raw)
    path = tmp_path / "broken.txt.gz"
    path.write_bytes(packed[:len(packed) * 2 // 3])
    server, received, thread = _sink()
    with server:
        assert main(["send", str(path), "--port", str(server.getsockname()[1]),
                     "--speed", "0"]) == 2
        thread.join(30)
    err = capsys.readouterr().err
    assert "damaged or incomplete gzip" in err and len(err.strip().splitlines()) == 1
    sent = b"".join(received)
    assert 0 < len(sent) < len(raw) and raw.startswith(sent)


@pytest.mark.parametrize("content", [b"", b"\x00\x01\x02" * 30_000])
def test_send_refuses_an_empty_or_binary_file_before_connecting(tmp_path, capsys, content):
    path = tmp_path / "bad.txt"
    path.write_bytes(content)
    assert main(["send", str(path), "--port", "9"]) == 2
    err = capsys.readouterr().err
    assert ("empty file" in err or "binary data" in err) and "cannot send" not in err
    np.testing.assert_equal(len(err.strip().splitlines()), 1)
