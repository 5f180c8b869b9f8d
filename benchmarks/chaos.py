"""Chaos: every fault a client or a disk can bring, against `orientation-lab serve`.

    .venv/bin/python benchmarks/chaos.py              # every scenario (about 3 minutes)
    .venv/bin/python benchmarks/chaos.py --quick      # five short scenarios (a smoke run)
    .venv/bin/python benchmarks/chaos.py --only flood-before,disk-full

Each scenario starts `serve --host 127.0.0.1 --record TMP/rec` as a subprocess (a fresh one per
scenario), streams a simulated phone session with its original timing (x --speed) from a phone
emulator and does its damage beside it (strangers, floods, junk, connect storms, a full disk,
late or torn lines), bounded in count and time. Then it prints a table:

- phone lines recorded / sent: the phone's lines found in the recorded raw.txt (all of them,
  except what a full disk or a size limit could not take);
- engine alive: serve still runs at the end, stops cleanly on SIGTERM (status 0, no traceback,
  no engine error);
- RSS: serve's peak resident memory (VmHWM);
- latency added: how much later than in the baseline the phone's first and last lines reach
  raw.txt (the recorder flushes every 0.4 s; the baseline's own delay is printed with it);
- check: what the scenario is about (the phone's estimates as if alone, a time axis not
  shifted, out-of-order counts, the recording's stop reason, ...).
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.stream.emulator import PhoneEmulator  # noqa: E402
from app.stream.lines import pacing_times  # noqa: E402
from app.stream.protocol import Sample, format_line  # noqa: E402

STRANGER_T0 = 999_999_000_000_000_000      # ~1e18 ms: the most a time stamp may have


# ---- the phone's data ---------------------------------------------------------------------------

def phone_lines(seconds: float, seed: int = 3) -> list[bytes]:
    """A simulated phone session in the phone's format (GYR/ACC/ORI 100 Hz, MAG 50 Hz)."""
    from ekf.simulate import simulate
    session = simulate(duration_s=seconds, seed=seed,
                       rates_hz={"gyr": 100.0, "acc": 100.0, "mag": 50.0, "ori": 100.0})
    return [(format_line(Sample(t, tag, values)) + "\n").encode("ascii")
            for t, tag, values in session.iter_rows()]


def _time_tag(line: bytes) -> tuple[int, bytes]:
    fields = line.split(b"\t", 2)
    return int(fields[0]), fields[1]


def late_tag(lines: list[bytes], tag: bytes, delay_ms: int) -> list[bytes]:
    """The tag's lines written `delay_ms` after their time (the others at once)."""
    keyed = [(t + (delay_ms if line_tag == tag else 0), k, line)
             for k, line in enumerate(lines) for t, line_tag in [_time_tag(line)]]
    return [line for *_, line in sorted(keyed)]


def shifted_clock(lines: list[bytes], tag: bytes, offset_ms: int) -> list[bytes]:
    out = []
    for line in lines:
        t, line_tag = _time_tag(line)
        out.append(line.replace(str(t).encode(), str(t + offset_ms).encode(), 1)
                   if line_tag == tag else line)
    return out


def late_block(lines: list[bytes], start_s: float, length_s: float, late_s: float):
    t0 = _time_tag(lines[0])[0]
    lo, hi = t0 + int(start_s * 1000), t0 + int((start_s + length_s) * 1000)
    block = [line for line in lines if lo <= _time_tag(line)[0] < hi]
    rest = [line for line in lines if not lo <= _time_tag(line)[0] < hi]
    at = next(k for k, line in enumerate(rest) if _time_tag(line)[0] >= hi + late_s * 1000)
    return rest[:at] + block + rest[at:]


def stranger_lines(n: int, t0: int = STRANGER_T0) -> bytes:
    """Valid lines from somebody else: fake times near 1e18 ms and another field."""
    return b"".join(f"{t0 + 10 * k}\tGYR\t0.3\t0.0\t0.0\n{t0 + 10 * k}\tACC\t0.0\t9.81\t0.0\n"
                    f"{t0 + 10 * k}\tMAG\t30.0\t-5.0\t3.0\n".encode() for k in range(n))


# ---- serve and the phone ------------------------------------------------------------------------

def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


class Serve:
    """`orientation-lab serve` on 127.0.0.1 in a subprocess, recording into `record`."""

    def __init__(self, record: Path, extra: list[str], file_limit: int | None = None) -> None:
        self.port = _free_port()
        self.record = record
        command = [sys.executable, "-m", "app", "serve", "--host", "127.0.0.1", "--port",
                   str(self.port), "--record", str(record), "--quiet", *extra]

        def limit_files() -> None:       # a file size limit: writes beyond fail like ENOSPC
            resource.setrlimit(resource.RLIMIT_FSIZE, (file_limit, file_limit))

        self.process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE, text=True,
                                        preexec_fn=limit_files if file_limit else None)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                return
            except OSError:
                if self.process.poll() is not None:
                    break
                time.sleep(0.05)
        raise RuntimeError("serve did not start: " + self.stop()[2])

    def rss_mib(self) -> float:
        try:
            status = Path(f"/proc/{self.process.pid}/status").read_text()
        except OSError:
            return float("nan")
        match = re.search(r"VmHWM:\s+(\d+) kB", status)
        return int(match.group(1)) / 1024 if match else float("nan")

    def alive(self) -> bool:
        if self.process.poll() is not None:
            return False
        try:
            socket.create_connection(("127.0.0.1", self.port), timeout=1.0).close()
        except OSError:
            return False
        return True

    def stop(self) -> tuple[int, str, str]:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        try:
            out, err = self.process.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            self.process.kill()
            out, err = self.process.communicate()
        return self.process.returncode, out, err


class PacedPhone(threading.Thread):
    """The phone: connects and streams its lines with their timing / speed."""

    def __init__(self, port: int, lines: list[bytes], speed: float) -> None:
        super().__init__(daemon=True)
        self.port, self.lines, self.speed = port, lines, speed
        self.first_sent = self.last_sent = None
        self.error: str | None = None
        self.duration_s = pacing_times(lines)[-1] / speed

    def run(self) -> None:
        try:
            with PhoneEmulator("127.0.0.1", self.port, timeout=30.0) as phone:
                self.first_sent = time.monotonic()
                phone.stream_lines(self.lines, self.speed)
                self.last_sent = time.monotonic()
        except OSError as error:
            self.error = f"phone: {error}"


def _raw_files(record: Path) -> list[Path]:
    return sorted(record.parent.glob(record.name + "*/raw.txt"))


class RawWatch(threading.Thread):
    """When the phone's lines reach raw.txt: checkpoints every `every` lines (the first and
    the last among them), polled every 20 ms."""

    def __init__(self, record: Path, good: list[bytes], every: int = 100) -> None:
        super().__init__(daemon=True)
        self.record = record
        self.indices = sorted(set(range(0, len(good), every)) | {len(good) - 1})
        self.markers = [good[k] for k in self.indices]
        self.seen: list[float | None] = [None] * len(self.markers)
        self.done = threading.Event()

    def run(self) -> None:
        next_marker = 0
        while not self.done.is_set() and next_marker < len(self.markers):
            data = b"".join(path.read_bytes() for path in _raw_files(self.record)
                            if path.exists())
            now = time.monotonic()
            while next_marker < len(self.markers) and self.markers[next_marker] in data:
                self.seen[next_marker] = now
                next_marker += 1
            self.done.wait(0.02)

    def delays(self, phone: PacedPhone) -> tuple[float, float] | None:
        """(first line's delay, median delay over the checkpoints) from the time the phone
        sent each (its pacing), or None when the last line never arrived."""
        if phone.first_sent is None or self.seen[-1] is None:
            return None
        pace = pacing_times(phone.lines)
        sent_at = {line: phone.first_sent + pace[k] / phone.speed
                   for k, line in enumerate(phone.lines)}
        delays = [seen - sent_at[marker] for marker, seen in zip(self.markers, self.seen)
                  if seen is not None and marker in sent_at]
        return delays[0], sorted(delays)[len(delays) // 2]


# ---- attackers ----------------------------------------------------------------------------------

def connect(port: int, source: str = "127.0.0.1") -> socket.socket:
    return socket.create_connection(("127.0.0.1", port), timeout=5.0, source_address=(source, 0))


def blast(port: int, data: bytes, seconds: float = 5.0) -> int:
    """Send `data` on a new connection as fast as the server takes it (it may close us)."""
    sent = 0
    try:
        with connect(port) as sock:
            sock.setblocking(False)
            deadline = time.monotonic() + seconds
            view = memoryview(data)
            while sent < len(data) and time.monotonic() < deadline:
                try:
                    sent += sock.send(view[sent:sent + (1 << 16)])
                except BlockingIOError:
                    time.sleep(0.001)
    except OSError:
        pass                                     # closed by the server: that is the point
    return sent


def send_and_close(port: int, data: bytes, hold_s: float = 0.0) -> None:
    try:
        with connect(port) as sock:
            sock.sendall(data)
            time.sleep(hold_s)
    except OSError:
        pass


def in_thread(function, *args) -> threading.Thread:
    thread = threading.Thread(target=function, args=args, daemon=True)
    thread.start()
    return thread


def storm(port: int, count: int = 200, silent: int = 50) -> None:
    """A connect storm, slow-loris connections that send nothing and half-open ones."""
    sockets = []
    for k in range(count + silent):
        try:
            sock = connect(port)
        except OSError:
            continue
        if k < count:
            sock.close()                              # connect and leave
        else:
            sockets.append(sock)                      # stay, send nothing
    for sock in sockets[:10]:
        try:
            sock.shutdown(socket.SHUT_WR)             # half-open
        except OSError:
            pass
    time.sleep(3.0)
    for sock in sockets:
        sock.close()


# ---- scenarios ----------------------------------------------------------------------------------

@dataclass
class Scenario:
    name: str
    title: str
    lines: str = "plain"                       # the phone's lines: see phone_variant()
    serve: list[str] = field(default_factory=list)
    before: object = None                      # before(port): before the phone connects
    during: object = None                      # during(port, serve): while it streams
    file_limit: int | None = None
    full_disk: bool = False                    # lines the disk could not take are expected
    check: object = None                       # check(result) -> text
    setup: object = None                       # setup(record dir, tmp) before serve starts


def phone_variant(kind: str, lines: list[bytes]) -> tuple[list[bytes], list[bytes]]:
    """(what the phone sends, its good lines that must be recorded)."""
    half = len(lines) // 2
    if kind == "absurd":
        bad = [b"%d\tACC\t1e160\t0\t0\n", b"%d\tGYR\t1.0E20\t0.0\t0.0\n",
               b"%d\tMAG\t0\t1e100\t0\n", b"%d\tORI\t2.0\t0.0\t0.0\t0.0\n"]
        t = _time_tag(lines[half])[0]
        return lines[:half] + [b % t for b in bad] + lines[half:], lines
    if kind == "binary":
        junk = [b"\x00" * 300 + b"\n", bytes(range(256)) + b"\n", lines[half][:-1] + b"\x00\n"]
        return lines[:half] + junk + lines[half:], lines
    if kind == "newlines":
        return lines[:half] + [b"\n" * (1 << 20)] + lines[half:], lines
    if kind == "late-tag":
        sent = late_tag(lines, b"MAG", 150)
        return sent, sent
    if kind == "clock":
        sent = shifted_clock(lines, b"GYR", 2000)
        return sent, sent
    if kind == "late-block":
        sent = late_block(lines, 3.0 if len(lines) > 3000 else 0.5, 0.9, 2.9)
        return sent, sent
    if kind == "torn-ori":
        k = next(i for i in range(half, len(lines)) if b"\tORI\t" in lines[i])
        torn = lines[k].rsplit(b"\t", 1)[0] + b"\n"
        return lines[:k] + [torn] + lines[k + 1:], lines[:k] + lines[k + 1:]
    return lines, lines


def _final(result) -> str:
    return next((line for line in result.out.splitlines() if line.startswith("final:")), "")


def check_alone(result) -> str:
    """The phone's estimates in estimates.csv are those of `filter` on the phone alone: its
    rows appear there as one run, on its own times (nothing of another stream carried over)."""
    alone = result.tmp / "alone.txt"
    alone.write_bytes(b"".join(result.phone_good))
    filtered = subprocess.run([sys.executable, "-m", "app", "filter", str(alone)], cwd=ROOT,
                              capture_output=True, text=True, timeout=120).stdout.splitlines()[1:]
    path = result.record_dir / "estimates.csv"
    recorded = path.read_text().splitlines()[1:] if path.exists() else []
    starts = [k for k, line in enumerate(recorded) if filtered and line == filtered[0]]
    same = any(recorded[k:k + len(filtered)] == filtered for k in starts)
    return f"estimates as if alone: {'yes' if same else 'NO'}"


def _final_part(result, prefix: str) -> str:
    return next((part for part in _final(result).split(" | ") if part.startswith(prefix)),
                f"{prefix} NOT SEEN")


def check_counts(*wanted: str):
    def check(result) -> str:
        final = _final(result)
        found = [w for w in wanted if w in final]
        missing = [w for w in wanted if w not in final]
        return ("; ".join(found) or "-") + (f"; MISSING {', '.join(missing)}" if missing else "")
    return check


def check_stopped(result) -> str:
    """The recording's one-line stop reason from serve's stderr, file names shortened."""
    match = re.search(r"recording stopped: ([^\n]*?)(?: \(the stream|$)", result.err, re.M)
    if not match:
        return "recording stopped: NOT SEEN"
    reason = re.sub(r"/\S*/", "", match.group(1))
    return f"recording stopped: {reason}"


def check_out_of_order(result) -> str:
    final = _final(result)
    match = re.search(r"(\d+) out of order", final)
    sessions = re.search(r"(\d+) new sessions", final)
    return (f"{match.group(1) if match else 0} out of order, "
            f"{sessions.group(1) if sessions else 0} new sessions; " +
            ("; ".join(q for q in final.split(" | ") if q.startswith("clock:")) or "no quirk"))


def check_second_folder(result) -> str:
    second = Path(str(result.record_dir) + "-2")
    ok = (second / "raw.txt").exists() and (result.record_dir / "raw.txt").read_bytes() == \
        result.tmp.joinpath("first-raw.txt").read_bytes()
    return f"recorded into {second.name}, first session untouched: {'yes' if ok else 'NO'}"


def _earlier_stranger(port: int) -> None:
    send_and_close(port, stranger_lines(300), hold_s=0.3)
    time.sleep(0.5)


def _stranger_during(port: int, serve: Serve, phone: PacedPhone) -> list[threading.Thread]:
    def stranger() -> None:
        time.sleep(0.3 * phone.duration_s)
        send_and_close(port, stranger_lines(300), hold_s=phone.duration_s)
    return [in_thread(stranger)]


def _second_phone(port: int, serve: Serve, phone: PacedPhone) -> list[threading.Thread]:
    other = PacedPhone(port, phone_lines(phone.duration_s * phone.speed, seed=11), phone.speed)

    def later() -> None:
        time.sleep(0.3 * phone.duration_s)
        other.run()
    return [in_thread(later)]


def _flood_before(port: int) -> None:
    blast(port, b"\n" * (16 << 20))


def _floods_during(port: int, serve: Serve, phone: PacedPhone) -> list[threading.Thread]:
    time.sleep(0.2 * phone.duration_s)
    return [in_thread(blast, port, b"\n" * (16 << 20)),
            in_thread(blast, port, os.urandom(4 << 20)),
            in_thread(blast, port, b"1" * (100 << 20)),            # a 100 MB line
            in_thread(blast, port, b"x\t\n" * (2 << 20))]


def _storm_during(port: int, serve: Serve, phone: PacedPhone) -> list[threading.Thread]:
    time.sleep(0.2 * phone.duration_s)
    return [in_thread(storm, port)]


def _outsider_during(port: int, serve: Serve, phone: PacedPhone) -> list[threading.Thread]:
    def outsider() -> None:
        time.sleep(0.3 * phone.duration_s)
        try:
            with connect(port, source="127.0.0.2") as sock:
                sock.sendall(stranger_lines(100))
                time.sleep(0.5)
        except OSError:
            pass
    return [in_thread(outsider)]


def _remove_folder(port: int, serve: Serve, phone: PacedPhone) -> list[threading.Thread]:
    def remove() -> None:
        time.sleep(0.4 * phone.duration_s)
        raw = serve.record / "raw.txt"
        if raw.exists():
            shutil.copy(raw, serve.record.parent / "removed-raw.txt")   # to count what was in
        shutil.rmtree(serve.record, ignore_errors=True)
    return [in_thread(remove)]


def _old_session(record: Path, tmp: Path) -> None:
    record.mkdir(parents=True)
    (record / "raw.txt").write_bytes(stranger_lines(50))
    (record / "session.json").write_text("{}")
    shutil.copy(record / "raw.txt", tmp / "first-raw.txt")


def _readable_recording(result) -> str:
    done = subprocess.run([sys.executable, "-m", "app", "filter", str(result.record_dir), "-o",
                           os.devnull], cwd=ROOT, capture_output=True, text=True, timeout=120)
    damaged = re.search(r"\d+ damaged \([^)]*\)", _final(result))
    return (f"{damaged.group(0) if damaged else 'no damage'}; recording read by filter: "
            f"{'yes' if done.returncode == 0 else 'NO: ' + done.stderr.strip()[:60]}")


def _both(*checks):
    return lambda result: "; ".join(check(result) for check in checks)


SCENARIOS = [
    Scenario("baseline", "the phone alone"),
    Scenario("absurd", "absurd values in the phone's stream (ACC 1e160, GYR 1e20, MAG 1e100, "
             "ORI not unit)", lines="absurd",
             check=_both(check_counts("4 damaged (1 ACC out of range, 1 GYR out of range, "
                                      "1 MAG out of range, 1 ORI out of range)"), check_alone)),
    Scenario("stranger-during", "a stranger streams valid lines (t~1e18) while the phone "
             "streams", during=_stranger_during, check=check_alone),
    Scenario("stranger-before", "an earlier stranger's samples (t~1e18), then the phone",
             before=_earlier_stranger, check=check_alone),
    Scenario("second-phone", "a second phone streams while the phone streams",
             during=_second_phone, check=check_alone),
    Scenario("flood-before", "16 MiB of bare newlines before the phone", before=_flood_before,
             check=check_counts("connections closed: 1 nothing valid")),
    Scenario("floods-during", "floods on 4 other connections: 16 MiB newlines, 4 MiB random, "
             "a 100 MB line, 8 MiB junk lines", during=_floods_during,
             check=lambda r: _final_part(r, "connections closed")),
    Scenario("newlines-in-stream", "1 MiB of newlines in the phone's own stream",
             lines="newlines"),
    Scenario("binary", "NUL bytes and binary junk in the phone's own stream", lines="binary",
             check=_readable_recording),
    Scenario("storm", "200 connects, 50 silent (slow-loris), 10 half-open",
             during=_storm_during, check=lambda r: _final_part(r, "connections closed")),
    Scenario("not-allowed", "--allow 127.0.0.1, a client from 127.0.0.2",
             serve=["--allow", "127.0.0.1"], during=_outsider_during,
             check=check_counts("1 not allowed")),
    Scenario("disk-full", "the disk fills (file size limit 64 KiB: writes fail)",
             file_limit=64 << 10, full_disk=True,
             check=check_stopped),
    Scenario("size-limit", "--record-max-mb 0.05", serve=["--record-max-mb", "0.05"],
             full_disk=True, check=check_stopped),
    Scenario("folder-removed", "the record folder is removed while recording",
             during=_remove_folder, full_disk=True,
             check=check_stopped),
    Scenario("second-recording", "serve --record into a folder holding a session",
             setup=_old_session, check=check_second_folder),
    Scenario("late-tag", "MAG written 150 ms after its time", lines="late-tag",
             check=check_out_of_order),
    Scenario("clock-offset", "GYR's clock 2 s ahead", lines="clock", check=check_out_of_order),
    Scenario("late-block", "a 0.9 s block written 2.9 s late", lines="late-block",
             check=check_out_of_order),
    Scenario("torn-ori", "an ORI line torn to 3 values", lines="torn-ori",
             check=check_counts("1 damaged (1 value count)")),
]
QUICK = ["baseline", "absurd", "stranger-during", "flood-before", "disk-full"]


# ---- a stranger's trickle (issue 46, item 4) ---------------------------------------------------

TRICKLE_T0 = STRANGER_T0 + 10**9           # the trickle's own clock: its lines are told apart
TRICKLE_LINE = b"%d\tACC\t0.0\t9.81\t0.0\n"


def trickle(port: int, every_s: float = 2.0, lifetime_s: float = 180.0) -> threading.Thread:
    """A stranger that sends one valid line every `every_s` seconds for as long as the server
    keeps it (at most lifetime_s): never silent, never at a phone's rate."""
    sock = connect(port)

    def run() -> None:
        deadline = time.monotonic() + lifetime_s
        with sock:
            for k in range(10**6):
                try:
                    sock.sendall(TRICKLE_LINE % (TRICKLE_T0 + 2000 * k))
                except OSError:
                    return                               # closed by the server
                if time.monotonic() + every_s > deadline:
                    return
                time.sleep(every_s)
    return in_thread(run)


def _trickle_before(port: int) -> None:
    trickle(port)
    time.sleep(1.0)                                  # its first line before the phone's


FIRST_CONNECTION_S = 1.5


def _first_connection() -> list[bytes]:
    return phone_lines(FIRST_CONNECTION_S, seed=17)


def _trickle_at_reconnect(port: int) -> None:
    """The phone streams 1.5 s; a trickle connects while it does (it waits); the phone hangs
    up. The scenario's phone is its reconnection."""
    with PhoneEmulator("127.0.0.1", port, timeout=30.0) as phone:
        lines = _first_connection()
        half = len(lines) // 3
        phone.stream_lines(lines[:half], 1.0)
        trickle(port)
        phone.stream_lines(lines[half:], 1.0)
    time.sleep(0.3)


def check_trickle(result) -> str:
    """None of the trickle's lines recorded; for the reconnect, the phone's first connection
    all recorded too."""
    data = Counter()
    for path in _raw_files(result.record_dir):
        data.update(path.read_bytes().splitlines(keepends=True))
    stamp = str(TRICKLE_T0)[:9].encode()
    trickled = sum(count for line, count in data.items() if line.startswith(stamp))
    text = f"trickle lines recorded: {trickled}" + (" NO" if trickled else "")
    if result.scenario.before is _trickle_at_reconnect:
        first = _first_connection()
        missing = sum(max(0, count - data[line]) for line, count in Counter(first).items())
        text += f"; first connection's lines recorded: {len(first) - missing} / {len(first)}" \
            + (" NO" if missing else "")
    return text


SCENARIOS += [
    Scenario("trickle-before", "a stranger sends a valid line every 2 s, from before the phone",
             before=_trickle_before, check=check_trickle),
    Scenario("trickle-reconnect", "the phone streams 1.5 s (a trickle connects meanwhile), hangs "
             "up and reconnects", before=_trickle_at_reconnect, check=check_trickle),
]



# ---- running --------------------------------------------------------------------------------

@dataclass
class Result:
    scenario: Scenario
    tmp: Path
    record_dir: Path
    phone_good: list[bytes]
    sent: int = 0
    recorded: int = 0
    alive: bool = False
    rss_mib: float = float("nan")
    latency: tuple[float, float] | None = None      # (first line, median) delays, s
    out: str = ""
    err: str = ""
    check: str = ""


def count_recorded(result: Result) -> int:
    """How many of the phone's lines are in the recording(s) (a line counted at most as often
    as the phone sent it)."""
    data = Counter()
    files = _raw_files(result.record_dir) + [result.tmp / "removed-raw.txt"]
    for path in files:
        if path.exists():
            data.update(path.read_bytes().splitlines(keepends=True))
    wanted = Counter(result.phone_good)
    return sum(min(count, data[line]) for line, count in wanted.items())


def _stream(scenario: Scenario, serve: Serve, sent: list[bytes], good: list[bytes],
            speed: float) -> tuple[PacedPhone, RawWatch]:
    if scenario.before:
        scenario.before(serve.port)
    watch = RawWatch(serve.record, good)
    watch.start()
    phone = PacedPhone(serve.port, sent, speed)
    phone.start()
    threads = scenario.during(serve.port, serve, phone) if scenario.during else []
    phone.join(timeout=phone.duration_s + 120)
    watch.join(timeout=3.0)
    watch.done.set()
    for thread in threads:
        thread.join(timeout=15.0)
    return phone, watch


def run_scenario(scenario: Scenario, lines: list[bytes], speed: float, root: Path) -> Result:
    tmp = Path(tempfile.mkdtemp(prefix=scenario.name + "-", dir=root))
    record = tmp / "rec"
    if scenario.setup:
        scenario.setup(record, tmp)
    sent, good = phone_variant(scenario.lines, lines)
    result = Result(scenario, tmp, record, good, sent=len(good))
    serve = Serve(record, scenario.serve, scenario.file_limit)
    try:
        phone, watch = _stream(scenario, serve, sent, good, speed)
        time.sleep(0.5)
        result.alive = serve.alive() and phone.error is None
        result.rss_mib = serve.rss_mib()
        result.latency = watch.delays(phone)
    finally:
        code, result.out, result.err = serve.stop()
    if scenario.setup is None and (record.parent / (record.name + "-2")).exists():
        result.alive = False                         # nobody asked for a second folder
    result.alive &= code == 0 and "Traceback" not in result.err \
        and "engine error" not in result.err
    result.recorded = count_recorded(result)
    result.check = scenario.check(result) if scenario.check else ""
    return result


def latency_added(result: Result, baseline: Result | None) -> float | None:
    """Seconds later than the baseline: the larger of the first line's and the median's."""
    if result.latency is None or baseline is None or baseline.latency is None:
        return None
    return max(result.latency[0] - baseline.latency[0], result.latency[1] - baseline.latency[1])


def table(results: list[Result]) -> str:
    baseline = next((r for r in results if r.scenario.name == "baseline"), None)
    rows = [("scenario", "phone lines recorded / sent", "engine alive", "RSS",
             "latency added", "check")]
    for r in results:
        added = latency_added(r, baseline)
        if r.latency is None:
            latency = "n/a (not recorded)" if r.scenario.full_disk else "NOT RECORDED"
        elif r is baseline:
            latency = f"0 (own: first {r.latency[0] * 1000:.0f}, median " \
                      f"{r.latency[1] * 1000:.0f} ms)"
        else:
            latency = f"{added * 1000:+.0f} ms" if added is not None else "?"
        complete = "all" if r.recorded == r.sent else (
            "disk's share" if r.scenario.full_disk else "LOST")
        rows.append((f"{r.scenario.name}: {r.scenario.title}",
                     f"{r.recorded} / {r.sent} ({complete})", "yes" if r.alive else "NO",
                     f"{r.rss_mib:.0f} MiB", latency, r.check))
    widths = [max(len(row[k]) for row in rows) for k in range(len(rows[0]))]
    lines = [" | ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip()
             for row in rows]
    lines.insert(1, "-+-".join("-" * width for width in widths))
    return "\n".join(lines)


def verdict(results: list[Result]) -> list[str]:
    """What breaks the issue's acceptance: a lost phone line, a dead engine, a slow flood."""
    problems = []
    baseline = next((r for r in results if r.scenario.name == "baseline"), None)
    for r in results:
        if not r.alive:
            problems.append(f"{r.scenario.name}: the engine is not alive at the end")
        if r.recorded != r.sent and not r.scenario.full_disk:
            problems.append(f"{r.scenario.name}: {r.sent - r.recorded} phone lines not recorded")
        added = latency_added(r, baseline)
        if r.scenario.name == "flood-before" and baseline is not None and (
                added is None or added >= 1.0):
            problems.append("flood-before: the 16 MiB newline flood delays the phone >= 1 s")
        if "NO" in r.check.split() or "MISSING" in r.check or "NOT SEEN" in r.check:
            problems.append(f"{r.scenario.name}: {r.check}")
    return problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=12.0,
                        help="length of the phone's session (default 12)")
    parser.add_argument("--speed", type=float, default=2.0,
                        help="the phone streams at this many times its original pace (default 2)")
    parser.add_argument("--only", help="comma-separated scenario names")
    parser.add_argument("--quick", action="store_true",
                        help=f"a smoke run: {', '.join(QUICK)} with 3 s of phone data")
    args = parser.parse_args()
    chosen = SCENARIOS
    if args.quick:
        args.seconds = 3.0
        chosen = [s for s in SCENARIOS if s.name in QUICK]
    if args.only:
        names = args.only.split(",")
        chosen = [s for s in SCENARIOS if s.name in names or s.name == "baseline"]
    lines = phone_lines(args.seconds)
    print(f"phone: {len(lines)} lines, {args.seconds:g} s of a simulated session at "
          f"{args.speed:g}x; one `serve --record` subprocess per scenario", flush=True)
    results = []
    with tempfile.TemporaryDirectory(prefix="chaos-") as root:
        for scenario in chosen:
            started = time.monotonic()
            results.append(run_scenario(scenario, lines, args.speed, Path(root)))
            print(f"  {scenario.name}: {time.monotonic() - started:.1f} s", flush=True)
    print(table(results))
    problems = verdict(results)
    print("\n".join(["problems:"] + problems) if problems else "every scenario passed")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
