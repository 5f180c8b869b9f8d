"""Memory of the offline commands and `send` on long logs: peak RSS against the log's size.

    .venv/bin/python benchmarks/memory.py            # logs of 10, 30 and 60 minutes (~10 min)
    .venv/bin/python benchmarks/memory.py --quick    # 2 and 8 minutes (smoke test)

Each log is a simulated phone (ACC, GYR, ORI 100 Hz, MAG 50 Hz: 350 lines/s, the hour 1.26
million lines, 61 MB) written by `orientation-lab simulate`. Every command runs in its own
interpreter (``python -m app``); its peak resident set size is the kernel's (``os.wait4``'s
``ru_maxrss``, which counts the pages a child starts with: this script imports no numpy and
writes its logs in a child, so it stays at a few MB). `send` streams to a local socket that
discards what it gets (and checks every byte arrived). Every command runs once on a 15-second
log first, unmeasured (numba compiles its kernels into the cache on a first run).
``startup`` is an interpreter that imports the offline commands and exits: the floor under
every figure.

The goals (issue 46 item 3), checked on the longest log and between the shortest and the
longest:

* filter, evaluate, export (csv, log, mat): at most 300 MB on the hour, --smooth 600 MB;
* every command: memory grows at most linearly with the log, by at most 5 bytes per byte of log
  (between the shortest and the longest log, give or take 16 MiB of the allocator's noise);
* send: memory independent of the log's size (grows by at most 16 MiB).

With --quick the logs are too short for the hour's limits; the growth is checked. Exit status 1
when a goal is missed. Not a test: the figures go to docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RATES = {"gyr": 100.0, "acc": 100.0, "mag": 50.0, "ori": 100.0}
MB = 1e6
MIB = 2**20
LIMIT_MB = 300.0              # filter, evaluate, export on the hour
SMOOTH_LIMIT_MB = 600.0       # filter --smooth on the hour
SLOPE = 5.0                   # bytes of memory per byte of log, at most
SEND_GROWTH_MIB = 16.0        # send: memory independent of the log's size
NOISE_MIB = 16.0              # the allocator's give and take between two runs


@dataclass
class Result:
    command: str
    minutes: float
    log_bytes: int
    peak_bytes: int
    seconds: float
    ok: bool
    note: str = ""

    @property
    def ratio(self) -> float:
        return self.peak_bytes / self.log_bytes


def write_log(path: Path, minutes: float, seed: int = 3) -> Path:
    """A simulated log, written by `orientation-lab simulate` in its own process (this one stays
    small: a child's peak RSS counts the pages it starts with, those of this process)."""
    subprocess.run([sys.executable, "-m", "app", "simulate", "--duration", str(minutes * 60.0),
                    "--seed", str(seed), "--rate", str(RATES["acc"]), "--mag-rate",
                    str(RATES["mag"]), "--force", "-o", str(path)], cwd=ROOT, check=True)
    return path


def run(argv: list[str], stdin=None) -> tuple[int, int, float, str]:
    """(exit status, peak RSS bytes, wall seconds, stderr's last line) of `python -m app ARGV`."""
    started = time.perf_counter()
    with tempfile.TemporaryFile() as err:
        process = subprocess.Popen([sys.executable, "-m", "app", *argv], cwd=ROOT,
                                   stdin=stdin, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(process.pid, 0)
        process.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        lines = err.read().decode(errors="replace").strip().splitlines()
    return (process.returncode, usage.ru_maxrss * 1024, time.perf_counter() - started,
            lines[-1] if lines else "")


class Sink:
    """A local TCP server that reads one connection to its end and counts the bytes."""

    def __init__(self) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.received = 0
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        connection, _ = self.server.accept()
        with connection:
            while True:
                data = connection.recv(1 << 20)
                if not data:
                    break
                self.received += len(data)

    def close(self) -> None:
        self.thread.join(timeout=60.0)
        self.server.close()


def commands(log: Path, out: Path) -> dict[str, list[str]]:
    return {
        "filter": ["filter", str(log), "-o", str(out / "estimates.csv")],
        "filter --smooth": ["filter", str(log), "--smooth", "-o", str(out / "smoothed.csv")],
        "evaluate": ["evaluate", str(log)],
        "export csv": ["export", str(log), "--format", "csv", "-o", str(out / "export.csv")],
        "export log": ["export", str(log), "--format", "log", "-o", str(out / "export.txt")],
        "export mat": ["export", str(log), "--format", "mat", "-o", str(out / "export.mat")],
    }


def measure(log: Path, minutes: float, out: Path, only: list[str] | None) -> list[Result]:
    size = log.stat().st_size
    results = []
    for name, argv in commands(log, out).items():
        if only and name not in only:
            continue
        code, peak, seconds, last = run(argv)
        results.append(Result(name, minutes, size, peak, seconds, code == 0,
                               "" if code == 0 else f"exit {code}: {last}"))
        for produced in out.iterdir():
            produced.unlink()
    if not only or "send" in only:
        sink = Sink()
        code, peak, seconds, last = run(["send", str(log), "--port", str(sink.port),
                                         "--speed", "0"])
        sink.close()
        complete = sink.received == size
        note = "" if code == 0 and complete else (
            f"exit {code}: {last}" if code else f"{sink.received} of {size} bytes arrived")
        results.append(Result("send", minutes, size, peak, seconds, code == 0 and complete,
                              note))
    return results


def startup() -> int:
    """Peak RSS of an interpreter that imports what the offline commands import."""
    code = ("import app.cli.offline, app.cli.live, app.engine.offline.export, ekf.smoother, "
            "app.engine.offline.filtering")
    with subprocess.Popen([sys.executable, "-c", code], cwd=ROOT) as process:
        _, _, usage = os.wait4(process.pid, 0)
    return usage.ru_maxrss * 1024


def judge(results: list[Result], quick: bool) -> list[str]:
    """The goals missed, in words."""
    missed = [f"{r.command} on {r.minutes:g} min failed: {r.note}" for r in results if not r.ok]
    by_command: dict[str, list[Result]] = {}
    for r in results:
        by_command.setdefault(r.command, []).append(r)
    for command, runs in by_command.items():
        runs.sort(key=lambda r: r.log_bytes)
        short, long = runs[0], runs[-1]
        if not quick and long.minutes >= 60:
            limit = SMOOTH_LIMIT_MB if command == "filter --smooth" else LIMIT_MB
            if command != "send" and long.peak_bytes > limit * MB:
                missed.append(f"{command}: {long.peak_bytes / MB:.0f} MB on the hour "
                              f"(at most {limit:.0f} MB)")
        if len(runs) < 2:
            continue
        growth = long.peak_bytes - short.peak_bytes
        slope = _slope(short, long)
        if command == "send":
            if growth > SEND_GROWTH_MIB * MIB:
                missed.append(f"send: {growth / MIB:.0f} MiB more for the longer log "
                              f"(at most {SEND_GROWTH_MIB:.0f} MiB)")
        elif growth > SLOPE * (long.log_bytes - short.log_bytes) + NOISE_MIB * MIB:
            missed.append(f"{command}: grows by {slope:.1f} bytes per byte of log "
                          f"(at most {SLOPE:g})")
    return missed


def _slope(short: Result, long: Result) -> float:
    """Extra bytes of memory per extra byte of log."""
    return (long.peak_bytes - short.peak_bytes) / (long.log_bytes - short.log_bytes)


def table(results: list[Result], floor: int) -> str:
    minutes = sorted({r.minutes for r in results})
    sizes = {r.minutes: r.log_bytes for r in results}
    head = "command".ljust(18) + "".join(
        f"{m:>6g} min ({sizes[m] / MB:5.1f} MB)".rjust(26) for m in minutes) + "  slope"
    lines = [head, "-" * len(head)]
    names = list(dict.fromkeys(r.command for r in results))
    for name in names:
        runs = {r.minutes: r for r in results if r.command == name}
        cells = []
        for m in minutes:
            r = runs.get(m)
            cells.append("" if r is None else
                         f"{r.peak_bytes / MB:7.0f} MB {r.ratio:4.1f}x {r.seconds:5.1f} s")
        ordered = sorted(runs.values(), key=lambda r: r.log_bytes)
        slope = ""
        if len(ordered) > 1:
            slope = f"{_slope(ordered[0], ordered[-1]):6.2f}"
        lines.append(name.ljust(18) + "".join(c.rjust(26) for c in cells) + "  " + slope)
    lines.append(f"startup (imports only): {floor / MB:.0f} MB; a cell: peak RSS, peak / log "
                 "size, wall time; slope: extra bytes of memory per extra byte of log")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2- and 8-minute logs")
    parser.add_argument("--minutes", type=float, nargs="+", metavar="M",
                        help="log lengths (default 10 30 60)")
    parser.add_argument("--only", nargs="+", metavar="COMMAND",
                        help="only these commands (e.g. filter 'export csv' send)")
    parser.add_argument("--logs", type=Path, metavar="DIR",
                        help="keep the generated logs here (reused when present)")
    args = parser.parse_args()
    minutes = args.minutes or ([2.0, 8.0] if args.quick else [10.0, 30.0, 60.0])
    with tempfile.TemporaryDirectory(prefix="memory-bench-") as tmp:
        logs = args.logs or Path(tmp)
        logs.mkdir(parents=True, exist_ok=True)
        out = Path(tmp) / "out"
        out.mkdir()
        warm = logs / "warm_up.txt"
        if not warm.is_file():
            write_log(warm, 0.25)
        measure(warm, 0.25, out, args.only)      # compiles or loads the kernels, unmeasured
        results: list[Result] = []
        for m in minutes:
            log = logs / f"sim_{m:g}min.txt"
            if not log.is_file():
                write_log(log, m)
            found = measure(log, m, out, args.only)
            for r in found:
                print(f"{m:g} min: {r.command}: {r.peak_bytes / MB:.0f} MB "
                      f"({r.ratio:.1f}x the log), {r.seconds:.1f} s{'' if r.ok else ' ' + r.note}",
                      file=sys.stderr, flush=True)
            results += found
    print(table(results, startup()))
    missed = judge(results, args.quick)
    for line in missed:
        print(f"goal missed: {line}")
    if not missed:
        print("every goal met")
    return 1 if missed else 0


if __name__ == "__main__":
    raise SystemExit(main())
