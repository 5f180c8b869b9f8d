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

Then the offline commands against hostile outputs and inputs, one subprocess each in a scratch
folder (a second table: exit status, one line on stderr, what the scenario checks): `-o` into
a character device, a full device, a FIFO (read to its end, or closed by its reader), a
symlink, a dangling symlink, a folder; settings, session.json and interval files a program
could choke on; out-of-range numbers. Devices are copies made with mknod in the scratch
folder (as root; without root those scenarios are skipped): the system's /dev/null and
/dev/full are never an output here, and the run checks at its end that they are still the
devices they were.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import signal
import socket
import stat
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
    """The phone: connects and streams its lines with their timing / speed. Each item of
    `lines` is due at the time of its first line (an item of several lines goes out whole:
    phone_variant's bad time stamps ride on the line before them, never pacing the stream)."""

    def __init__(self, port: int, lines: list[bytes], speed: float) -> None:
        super().__init__(daemon=True)
        self.port, self.lines, self.speed = port, lines, speed
        self.first_sent = self.last_sent = None
        self.error: str | None = None
        self.duration_s = pacing_times(lines)[-1] / speed

    def run(self) -> None:
        try:
            pace = pacing_times(self.lines)
            with PhoneEmulator("127.0.0.1", self.port, timeout=30.0) as phone:
                self.first_sent = time.monotonic()
                start = time.perf_counter()
                index = 0
                while index < len(self.lines):
                    now = (time.perf_counter() - start) * self.speed
                    end = index
                    while end < len(self.lines) and pace[end] <= now:
                        end += 1
                    if end > index:
                        phone.send(b"".join(self.lines[index:end]))
                        index = end
                    else:
                        time.sleep(min(0.05, (pace[index] - now) / self.speed))
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
    if kind == "fullwidth":
        t = _time_tag(lines[half])[0]
        bad = ["%d\tACC\t\uff19.81\t0.0\t0.0\n" % t, "%d\tGYR\t0.0\t0.\u0663\t0.0\n" % t]
        return lines[:half] + [b.encode() for b in bad] + lines[half:], lines
    if kind == "bad-stamp":
        t = _time_tag(lines[half])[0]
        year = 365 * 24 * 3600 * 1000
        bad = [b"0\tGYR\t0.01\t0.02\t0.03\n"] + [
            b"%d\tACC\t0.1\t0.2\t9.8\n" % (t + year + 10 * k) for k in range(5)]
        # each sent with the line before it (the phone's pacing follows that line's time)
        sent = lines[:half - 1] + [lines[half - 1] + bad[0]] + lines[half:half + 39] \
            + [lines[half + 39] + b"".join(bad[1:])] + lines[half + 40:]
        good = lines[:half] + bad[:1] + lines[half:half + 40] + bad[1:] + lines[half + 40:]
        return sent, good                     # they parse: recorded verbatim, never filtered
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
                           str(result.tmp / "filtered.csv")], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    damaged = re.search(r"\d+ damaged \([^)]*\)", _final(result))
    return (f"{damaged.group(0) if damaged else 'no damage'}; recording read by filter: "
            f"{'yes' if done.returncode == 0 else 'NO: ' + done.stderr.strip()[:60]}")


def check_bad_stamps(result) -> str:
    """Six bad time stamps: dropped and counted, no clock quirk, no new session."""
    final = _final(result)
    order = re.search(r"(\d+) out of order", final)
    quirks = [q for q in final.split(" | ") if q.startswith("clock:")]
    ok = order is not None and order.group(1) == "6" and "new sessions" not in final \
        and not quirks
    return (f"{order.group(1) if order else 0} out of order, "
            f"{'no new session, no quirk' if ok else 'NO: ' + final[:120]}")


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
    Scenario("fullwidth", "digits of other scripts in the phone's stream (\uff19.81, 0.\u0663)",
             lines="fullwidth", check=check_counts("2 damaged (2 bad number)")),
    Scenario("bad-stamp", "one sample at t = 0 and 5 a year ahead in the phone's stream",
             lines="bad-stamp", check=check_bad_stamps),
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



# ---- offline commands: hostile outputs and inputs -----------------------------------------------

NULL, FULL = (1, 3), (1, 7)          # the character devices /dev/null and /dev/full (Linux)


def _root() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0


def _device(path: Path, numbers: tuple[int, int]) -> None:
    os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(*numbers))


def _is_device(path: Path, numbers: tuple[int, int]) -> bool:
    try:
        info = os.lstat(path)
    except OSError:
        return False
    return stat.S_ISCHR(info.st_mode) and info.st_rdev == os.makedev(*numbers)


class _Reader(threading.Thread):
    """Reads a FIFO to its end, or opens it and closes it at once."""

    def __init__(self, path: Path, close_at_once: bool) -> None:
        super().__init__(daemon=True)
        self.path, self.close_at_once, self.data = path, close_at_once, b""

    def run(self) -> None:
        with open(self.path, "rb") as fifo:
            if not self.close_at_once:
                self.data = fifo.read()

    def stop(self) -> None:
        if self.is_alive():                 # nobody opened it for writing: let it go
            try:
                os.close(os.open(self.path, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass
        self.join(timeout=30)


@dataclass
class Offline:
    """`orientation-lab ARGV` in a scratch folder ({name} in ARGV: a file there); `expect` its
    exit status; `needle` in its last stderr line; `out` the output kind prepared first:
    "null", "full" (device copies), "fifo", "fifo-closed", "link", "dangling", "folder"."""

    name: str
    title: str
    argv: list[str]
    expect: int = 2
    needle: str = ""
    out: str = ""
    root: bool = False                # needs root (mknod)


_SEEDED = {"walk.txt", "rest.txt", "turning.txt", "rest_gyr_z.txt", "constant.txt"}
_WRITTEN = ("cal.json", "sim.txt", "tuned.json", "e.csv")     # outputs a refusal never leaves

OFFLINE = [
    # item 1: -o paths
    Offline("out-null-filter", "filter -o a character device (a copy of /dev/null)",
            ["filter", "{walk}", "-o", "{out}"], 0, out="null", root=True),
    Offline("out-null-export", "export mat -o a character device",
            ["export", "{walk}", "--format", "mat", "-o", "{out}"], 0, out="null",
            root=True),
    Offline("out-null-calibrate", "calibrate -o a character device",
            ["calibrate", "{rest}", "-o", "{out}"], 0, out="null", root=True),
    Offline("out-null-calibrate-mag", "calibrate-mag -o a character device",
            ["calibrate-mag", "{turning}", "-o", "{out}"], 0, out="null", root=True),
    Offline("out-null-tune", "tune -o a character device",
            ["tune", "{walk}", "--max-evals", "3", "--no-check", "-o", "{out}"], 0,
            out="null", root=True),
    Offline("out-null-simulate", "simulate -o a character device",
            ["simulate", "--duration", "5", "-o", "{out}"], 0, out="null", root=True),
    Offline("out-full-filter", "filter -o a full device (a copy of /dev/full)",
            ["filter", "{walk}", "-o", "{out}"], 2, "No space left on device", "full",
            root=True),
    Offline("out-full-export", "export csv -o a full device",
            ["export", "{walk}", "--format", "csv", "-o", "{out}"], 2,
            "No space left on device", "full", root=True),
    Offline("out-full-simulate", "simulate -o a full device",
            ["simulate", "--duration", "5", "-o", "{out}"], 2, "No space left on device",
            "full", root=True),
    Offline("out-fifo", "filter -o a FIFO read to its end",
            ["filter", "{walk}", "-o", "{out}"], 0, out="fifo"),
    Offline("out-fifo-closed", "simulate -o a FIFO its reader closes at once",
            ["simulate", "--duration", "60", "-o", "{out}"], 2, "Broken pipe",
            out="fifo-closed"),
    Offline("out-link", "filter -o a symlink to an older output",
            ["filter", "{walk}", "-o", "{out}"], 0, out="link"),
    Offline("out-dangling", "filter -o a dangling symlink",
            ["filter", "{walk}", "-o", "{out}"], 0, out="dangling"),
    Offline("out-folder", "filter -o a folder",
            ["filter", "{walk}", "-o", "{out}"], 2, "is a folder", "folder"),
    Offline("out-input", "filter -o its own input",
            ["filter", "{walk}", "-o", "{walk}"], 2, "is the input"),
    # item 5: tracebacks before
    Offline("in-settings-brackets", "--settings of 100,000 '['",
            ["filter", "{walk}", "--settings", "{brackets}"], 2, "nested too deeply"),
    Offline("in-session-brackets", "a session.json of 100,000 '['",
            ["filter", "{session}"], 2, "nested too deeply"),
    Offline("in-intervals-letters", 'evaluate --intervals ["ab", "cd"]',
            ["evaluate", "{walk}", "--intervals", "{letters}"], 2, "interval 1 is"),
    Offline("in-constant-axis", "calibrate --settings course on a constant gyroscope axis",
            ["calibrate", "{rest_gyr_z}", "--settings", "course", "-o", "{cal}"], 2,
            "gyr z is constant"),
    Offline("in-seed", "simulate --seed -1",
            ["simulate", "--seed", "-1", "-o", "{sim}"], 2, "whole number >= 0"),
    Offline("in-duration", "simulate --duration 1e9",
            ["simulate", "--duration", "1e9", "-o", "{sim}"], 2, "a session may have"),
    Offline("in-rate", "simulate --rate 1e9",
            ["simulate", "--rate", "1e9", "-o", "{sim}"], 2, "at most 1000 Hz"),
    Offline("in-record-max-mb", "serve --record-max-mb 1e308",
            ["serve", "--record-max-mb", "1e308"], 2, "size in MB from 0"),
    # item 6: exit 0 with nothing usable before
    Offline("in-intervals-reversed", "evaluate with a reversed interval",
            ["evaluate", "{walk}", "--intervals", "{reversed}"], 2,
            "ends before it starts"),
    Offline("in-intervals-nan", "evaluate with a NaN interval",
            ["evaluate", "{walk}", "--intervals", "{nan}"], 2, "two finite numbers"),
    Offline("in-skip", "evaluate --skip 1e308",
            ["evaluate", "{walk}", "--skip", "1e308"], 2, "no reference sample"),
    Offline("in-tune-range", "tune --range 500:600 on a 22 s log",
            ["tune", "{walk}", "--range", "500:600"], 2, "after the log's end"),
    Offline("in-tune-params", "tune --params acc_noise_cov=1e300:1e308 -o S",
            ["tune", "{walk}", "--params", "acc_noise_cov=1e300:1e308", "-o",
             "{tuned}"], 2, "is not allowed"),
    Offline("in-tune-absurd", "tune --params acc_noise_cov=1e200:1e300 -o S",
            ["tune", "{walk}", "--params", "acc_noise_cov=1e200:1e300", "--max-evals",
             "4", "--no-check", "-o", "{tuned}"], 2, "nothing written"),
    Offline("in-rate-low", "simulate --rate 0.001",
            ["simulate", "--rate", "0.001", "-o", "{sim}"], 2, "fewer than 2 samples"),
    Offline("in-bias-nan", "simulate --gyro-bias nan 0 0",
            ["simulate", "--gyro-bias", "nan", "0", "0", "-o", "{sim}"], 2,
            "finite number"),
    Offline("in-constant", "calibrate on constant data",
            ["calibrate", "{constant}"], 2, "are constant"),
    # item 11: messages
    Offline("in-export-range", "export --from 1e308 --to 1e308",
            ["export", "{walk}", "--format", "csv", "-o", "{e}", "--from", "1e308",
             "--to", "1e308"], 2, "no samples from 1e+308 s to 1e+308 s"),
    Offline("in-allow", "serve --allow 10.0.0.0/99",
            ["serve", "--allow", "10.0.0.0/99"], 2, "argument --allow: not an address"),
]


def _offline_files(folder: Path) -> None:
    from ekf.simulate import simulate
    from app.stream.demo import write_session
    write_session(simulate(duration_s=22, seed=3), folder / "walk.txt")
    write_session(simulate(duration_s=6, script="rest", seed=4), folder / "rest.txt")
    turning = simulate(duration_s=30, seed=5)
    turning.mag.values = turning.mag.values + [30.0, -25.0, 200.0]
    write_session(turning, folder / "turning.txt")
    rest = (folder / "rest.txt").read_text().splitlines()
    fixed = {"GYR": ["0.001", "0.002", "0.003"], "ACC": ["0.1", "0.2", "9.8"],
             "MAG": ["10.0", "20.0", "-30.0"]}
    zero_z, constant = [], []
    for line in rest:
        fields = line.split("\t")
        zero_z.append("\t".join(fields[:4] + ["0.0"]) if fields[1] == "GYR" else line)
        constant.append("\t".join(fields[:2] + fixed[fields[1]]) if fields[1] in fixed
                        else line)
    (folder / "rest_gyr_z.txt").write_text("\n".join(zero_z) + "\n")
    (folder / "constant.txt").write_text("\n".join(constant) + "\n")
    (folder / "brackets.json").write_text("[" * 100_000)
    (folder / "session").mkdir()
    shutil.copy(folder / "walk.txt", folder / "session" / "raw.txt")
    (folder / "session" / "session.json").write_text("[" * 100_000)
    for name, intervals in (("letters", '["ab", "cd"]'), ("reversed", "[[5000, 1000]]"),
                            ("nan", "[[NaN, 1000]]")):
        (folder / f"{name}.json").write_text('{"score_intervals_ms": %s}' % intervals)


@dataclass
class OfflineResult:
    scenario: Offline
    code: int | None = None
    lines: int = 0
    check: str = ""


def _prepare_output(kind: str, out: Path) -> tuple[_Reader | None, Path | None]:
    reader, target = None, None
    if kind in ("null", "full"):
        _device(out, NULL if kind == "null" else FULL)
    elif kind in ("fifo", "fifo-closed"):
        os.mkfifo(out)
        reader = _Reader(out, close_at_once=kind == "fifo-closed")
        reader.start()
    elif kind == "link":
        target = out.with_name("older.csv")
        target.write_text("an older output\n")
        out.symlink_to(target.name)
    elif kind == "dangling":
        target = out.with_name("made.csv")
        out.symlink_to(target.name)
    elif kind == "folder":
        out.mkdir()
    return reader, target


def _output_check(kind: str, out: Path, reader: _Reader | None, target: Path | None) -> str:
    if kind in ("null", "full"):
        return "device kept" if _is_device(out, NULL if kind == "null" else FULL) \
            else "NO: the device was replaced"
    if kind in ("fifo", "fifo-closed"):
        ok = stat.S_ISFIFO(os.lstat(out).st_mode)
        got = f"; {len(reader.data)} bytes read" if reader and kind == "fifo" else ""
        if kind == "fifo" and reader and not reader.data.startswith(b"t_ms,"):
            return "NO: the reader got no CSV"
        return ("FIFO kept" if ok else "NO: the FIFO was replaced") + got
    if kind in ("link", "dangling"):
        ok = out.is_symlink() and target is not None and target.is_file() \
            and target.read_text().startswith("t_ms,")
        return "link kept, its target written" if ok else "NO: link or target wrong"
    if kind == "folder":
        return "folder kept" if out.is_dir() and not any(out.iterdir()) else "NO: folder changed"
    return ""


def run_offline(scenario: Offline, folder: Path) -> OfflineResult:
    result = OfflineResult(scenario)
    if scenario.root and not _root():
        result.check = "skipped (needs root for mknod)"
        return result
    work = Path(tempfile.mkdtemp(prefix=scenario.name + "-", dir=folder))
    out = work / "out"
    reader, target = _prepare_output(scenario.out, out) if scenario.out else (None, None)
    names = {Path(name).stem: str(folder / name) for name in _SEEDED | {
        "brackets.json", "letters.json", "reversed.json", "nan.json", "session"}}
    names.update({Path(name).stem: str(work / name) for name in _WRITTEN})
    argv = [part.format(out=out, **names) for part in scenario.argv]
    try:
        done = subprocess.run([sys.executable, "-m", "app", *argv], cwd=ROOT,
                              capture_output=True, text=True, timeout=300)
    finally:
        if reader is not None:
            reader.stop()
    err = done.stderr.strip().splitlines()
    result.code = done.returncode
    errors = [line for line in err if "error" in line or "Traceback" in line]
    result.lines = len(errors)
    checks = []
    if done.returncode != scenario.expect:
        checks.append(f"NO: exit {done.returncode}, expected {scenario.expect}")
    if "Traceback" in done.stderr:
        checks.append("NO: a traceback")
    if scenario.expect == 2 and (len(errors) != 1 or scenario.needle not in errors[-1]):
        checks.append("NO: " + (errors[-1][:100] if errors else "no error line"))
    if scenario.expect == 2 and errors and re.search(r"\d{20}", errors[-1]):
        checks.append("NO: a number of 20 digits or more")
    written = [p.name for p in work.iterdir() if p.name in _WRITTEN]
    if scenario.expect == 2 and written:
        checks.append(f"NO: {', '.join(written)} written")
    if scenario.out:
        checks.append(_output_check(scenario.out, out, reader, target))
    elif not checks:
        said = errors[-1].split("error: ", 1)[-1].replace(f"{folder}/", "") if errors else "ok"
        checks.append(said[:80])
    result.check = "; ".join(c for c in checks if c)
    return result


def offline_table(results: list[OfflineResult]) -> str:
    rows = [("offline scenario", "exit", "error lines", "check")]
    for r in results:
        rows.append((f"{r.scenario.name}: {r.scenario.title}",
                     "-" if r.code is None else str(r.code), str(r.lines), r.check))
    widths = [max(len(row[k]) for row in rows) for k in range(4)]
    lines = [" | ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip()
             for row in rows]
    lines.insert(1, "-+-".join("-" * width for width in widths))
    return "\n".join(lines)


def offline_problems(results: list[OfflineResult]) -> list[str]:
    return [f"{r.scenario.name}: {r.check}" for r in results if "NO" in r.check.split()
            or "NO:" in r.check]


def system_devices() -> dict[str, bool]:
    """/dev/null and /dev/full: still the character devices they are?"""
    return {"/dev/null": _is_device(Path("/dev/null"), NULL),
            "/dev/full": _is_device(Path("/dev/full"), FULL)}


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


QUICK_OFFLINE = ["out-null-filter", "out-full-filter", "out-fifo", "in-settings-brackets",
                 "in-skip"]


def main() -> int:
    devices = system_devices()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=12.0,
                        help="length of the phone's session (default 12)")
    parser.add_argument("--speed", type=float, default=2.0,
                        help="the phone streams at this many times its original pace (default 2)")
    parser.add_argument("--only", help="comma-separated scenario names (either table)")
    parser.add_argument("--quick", action="store_true",
                        help=f"a smoke run: {', '.join(QUICK + QUICK_OFFLINE)} with 3 s of "
                             "phone data")
    args = parser.parse_args()
    chosen, offline = SCENARIOS, OFFLINE
    if args.quick:
        args.seconds = 3.0
        chosen = [s for s in SCENARIOS if s.name in QUICK]
        offline = [s for s in OFFLINE if s.name in QUICK_OFFLINE]
    if args.only:
        names = args.only.split(",")
        chosen = [s for s in SCENARIOS if s.name in names]
        chosen = ([s for s in SCENARIOS if s.name == "baseline" and s not in chosen]
                  + chosen) if chosen else []
        offline = [s for s in OFFLINE if s.name in names]
    results, offline_results = [], []
    with tempfile.TemporaryDirectory(prefix="chaos-") as root:
        if chosen:
            lines = phone_lines(args.seconds)
            print(f"phone: {len(lines)} lines, {args.seconds:g} s of a simulated session at "
                  f"{args.speed:g}x; one `serve --record` subprocess per scenario", flush=True)
            for scenario in chosen:
                started = time.monotonic()
                results.append(run_scenario(scenario, lines, args.speed, Path(root)))
                print(f"  {scenario.name}: {time.monotonic() - started:.1f} s", flush=True)
        if offline:
            folder = Path(root) / "offline"
            folder.mkdir()
            _offline_files(folder)
            print(f"offline: {len(offline)} commands, one subprocess each"
                  f"{'' if _root() else ' (not root: the device scenarios are skipped)'}",
                  flush=True)
            for scenario in offline:
                started = time.monotonic()
                offline_results.append(run_offline(scenario, folder))
                print(f"  {scenario.name}: {time.monotonic() - started:.1f} s", flush=True)
    problems = []
    if results:
        print(table(results))
        problems += verdict(results)
    if offline_results:
        print(offline_table(offline_results))
        problems += offline_problems(offline_results)
    after = system_devices()
    problems += [f"{name} is no longer the device it was" for name, ok in after.items()
                 if devices[name] and not ok]
    print("\n".join(["problems:"] + problems) if problems else "every scenario passed")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
