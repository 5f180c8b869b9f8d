"""Live-link figures: no loss, throughput, latency, memory. Prints figures; not a test.

    .venv/bin/python benchmarks/live.py                 # everything, 20-minute sessions
    .venv/bin/python benchmarks/live.py --minutes 2     # shorter simulated/paced sessions

- No loss: every real log in ../shared/data/realphone and a simulated 500 Hz session are sent
  with the phone emulator at full speed through the engine with a recorder (what `serve
  --record` runs): raw.txt must equal the input's lines that parse byte for byte (a damaged
  line is counted, never recorded), and the estimates must equal
  run_offline(read_log(file)) (what `orientation-lab filter` computes) bit for bit.
- Throughput: lines per second from the socket to published estimates (simulated session, full
  speed, comparisons off and on). The phone emulator runs in this process too (it shares the
  GIL and the 2 cores), so the figure is a lower bound for the engine alone.
- Latency: chunk arrival on the socket -> the estimates of every sample in it published to the
  GUI side (Engine.latencies_s: time held by the reorder window included), at 2,000 lines/s
  (500 Hz GYR, ACC, MAG, ORI, paced in real time), p50/p99/max.
- Memory: process RSS during a --minutes 500 Hz session (comparisons on), paced at
  --memory-speed times real time (default 10x: the 20-minute session takes 2 minutes; 1 = real
  time), polled like a GUI at 30 Hz; RSS at start/end/max and the slope (MiB per session minute,
  least squares over the second half of the session).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.engine.live.worker import Engine  # noqa: E402
from app.stream.emulator import PhoneEmulator  # noqa: E402
from app.stream.lines import read_lines  # noqa: E402
from app.stream.logfile import read_log  # noqa: E402
from app.stream.protocol import ParseError, Sample, format_line, parse_line  # noqa: E402
from app.stream.recorder import Recorder  # noqa: E402
from app.stream.sources import TcpSource  # noqa: E402
from app.engine.offline.filtering import run_offline  # noqa: E402

REALPHONE = ROOT.parent / "shared" / "data" / "realphone"
RATES_500 = {"gyr": 500.0, "acc": 500.0, "mag": 500.0, "ori": 500.0}


def rss_mib() -> float:
    with open("/proc/self/statm") as stream:
        pages = int(stream.read().split()[1])
    import os
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def simulated_lines(minutes: float, seed: int = 1) -> list[bytes]:
    from ekf.simulate import simulate
    session = simulate(duration_s=minutes * 60.0, rates_hz=RATES_500, seed=seed)
    return [(format_line(Sample(t, tag, values)) + "\n").encode("ascii")
            for t, tag, values in session.iter_rows()]


def _wait_done(engine: Engine, lines: int, timeout: float = 3600.0,
               settle_s: float = 2.0) -> float:
    """Until the engine has seen `lines` lines and the phone hung up (or, when some never
    arrive, the link has been idle for `settle_s` after the hang-up: then it says how many are
    missing); returns the finish time."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        health = engine.snapshot_now().health
        idle_since = engine.waiting_since
        if health.connection_state == "disconnected" and idle_since is not None:
            if health.lines_total >= lines:
                return idle_since
            if time.monotonic() - idle_since > settle_s:
                print(f"  warning: the engine saw {health.lines_total} of {lines} lines",
                      flush=True)
                return idle_since
        time.sleep(0.01)
    raise RuntimeError("engine did not finish")


def run_through_engine(lines: list[bytes], speed: float, comparisons: bool,
                       record_dir: Path | None, sample_rss: bool = False):
    """Send `lines` through a loopback engine; returns (engine, seconds, rss samples as
    (session time of the latest estimate in s, RSS MiB))."""
    source = TcpSource("127.0.0.1", 0, max_queued=1024)
    recorder = Recorder(record_dir) if record_dir is not None else None
    engine = Engine(source, comparisons=comparisons, recorder=recorder,
                    record_rows=not sample_rss)
    engine.start()
    rss: list[tuple[float, float]] = []
    try:
        started = time.monotonic()
        with PhoneEmulator("127.0.0.1", source.port) as phone:
            sender = threading.Thread(target=phone.stream_lines, args=(lines, speed))
            sender.start()
            if sample_rss:
                rss.append((0.0, rss_mib()))
                next_rss = time.monotonic() + 1.0
                first_ms = None
                while sender.is_alive():
                    sender.join(timeout=1 / 30)
                    snapshot = engine.poll()   # a GUI drains the plot buffer at its frame rate
                    if snapshot is not None and snapshot.t_ms is not None and first_ms is None:
                        first_ms = snapshot.t_ms
                    if time.monotonic() >= next_rss:
                        next_rss += 1.0
                        t_ms = engine.snapshot_now().t_ms
                        if t_ms is not None and first_ms is not None:
                            rss.append(((t_ms - first_ms) / 1000.0, rss_mib()))
            else:
                sender.join()
        finished = _wait_done(engine, len(lines))
        seconds = finished - started
        if sample_rss:
            engine.poll()
            rss.append((rss[-1][0], rss_mib()))
    finally:
        engine.stop()
    return engine, seconds, rss


def engine_rows(engine: Engine):
    t_ms = np.concatenate([r.t_ms for r in engine.rows_log]) if engine.rows_log else np.empty(0)
    quat = np.concatenate([r.quat for r in engine.rows_log]) if engine.rows_log else np.empty((0, 4))
    return t_ms, quat


def good_lines(data: bytes) -> bytes:
    """The lines of `data` that parse to a sample: what a recording of it holds."""
    out = []
    for line in data.splitlines(keepends=True):
        try:
            parse_line(line.decode("utf-8", "replace"))
        except ParseError:
            continue
        out.append(line)
    return b"".join(out)


def no_loss(name: str, path: Path, lines: list[bytes]) -> bool:
    with tempfile.TemporaryDirectory() as directory:
        record = Path(directory) / "session"
        engine, seconds, _ = run_through_engine(lines, 0.0, False, record)
        raw_identical = (record / "raw.txt").read_bytes() == good_lines(path.read_bytes())
        offline = run_offline(read_log(path))
    t_ms, quat = engine_rows(engine)
    same = np.array_equal(t_ms, offline.t_ms) and np.array_equal(quat, offline.quat)
    print(f"  {name:48s} {len(lines):9d} lines  raw.txt = its lines that parse: {raw_identical}  "
          f"estimates identical: {same}  ({len(lines) / seconds:,.0f} lines/s)")
    return raw_identical and same


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=20.0,
                        help="length of the simulated and paced sessions (default 20)")
    parser.add_argument("--latency-seconds", type=float, default=20.0,
                        help="length of the paced 2,000 lines/s latency run (default 20)")
    parser.add_argument("--memory-speed", type=float, default=10.0,
                        help="pace of the memory session, x real time (default 10; 1 = real time)")
    parser.add_argument("--skip-no-loss", action="store_true",
                        help="skip the no-loss checks (they take a few minutes for 20 minutes)")
    parser.add_argument("--quick", action="store_true",
                        help="a smoke run: 6-second sessions, one real log, 2.5 s of latency")
    args = parser.parse_args()
    if args.quick:
        args.minutes, args.latency_seconds, args.memory_speed = 0.1, 2.5, 20.0
    import ekf
    import ekf.fast
    print(f"estimator: {type(ekf.make_estimator()).__name__} (ekf.make_estimator default)")
    ekf.fast.warm_up()   # compile / load the kernels before anything is timed
    ok = True

    simulated = simulated_lines(args.minutes)
    if not args.skip_no_loss:
        print("No loss (send --speed 0 -> serve --record):")
        logs = sorted(REALPHONE.glob("*.txt")) if REALPHONE.is_dir() else []
        if args.quick:
            logs = logs[:1]
        if not logs:
            print(f"  real logs not found at {REALPHONE}: skipped")
        for path in logs:
            ok &= no_loss(path.name, path, read_lines(path))
        with tempfile.TemporaryDirectory() as directory:
            path = Path(directory) / "simulated.txt"
            path.write_bytes(b"".join(simulated))
            ok &= no_loss(f"simulated {args.minutes:g} min, 500 Hz x 4 tags", path, simulated)

    print("Throughput (socket -> published estimates, full speed):")
    for comparisons in (False, True):
        engine, seconds, _ = run_through_engine(simulated, 0.0, comparisons, None)
        print(f"  comparisons {'on ' if comparisons else 'off'}: {len(simulated) / seconds:,.0f}"
              f" lines/s ({len(simulated)} lines in {seconds:.1f} s; target >= 100,000)")

    print("Latency at 2,000 lines/s (500 Hz GYR/ACC/MAG/ORI), chunk arrival -> published:")
    count = int(args.latency_seconds * 2000)
    engine, seconds, _ = run_through_engine(simulated[:count], 1.0, True, None)
    latency_ms = np.array(engine.latencies_s) * 1000.0
    arrivals = np.array(engine.latency_arrivals_s)
    steady = arrivals >= arrivals.min() + 1.0
    for label, chosen in (("all chunks", np.ones(len(latency_ms), bool)),
                          ("after the first second (no start-of-stream hold)", steady)):
        values = latency_ms[chosen]
        if not len(values):
            print(f"  {label}: no chunks")
            continue
        print(f"  {label}: {len(values)} chunks: p50 {np.percentile(values, 50):.2f} ms, "
              f"p99 {np.percentile(values, 99):.2f} ms, max {values.max():.2f} ms "
              f"(target p99 <= 5 ms)")
    print("  (at the start of a stream the reorder window holds samples until all four filter "
          "tags have arrived (otherwise 250 ms to 1 s of phone time), so a sensor starting late keeps its "
          "first samples)")

    print(f"Memory over a {args.minutes:g}-minute 500 Hz session (comparisons on), paced at "
          f"{args.memory_speed:g}x real time:")
    engine, seconds, rss = run_through_engine(simulated, args.memory_speed, True, None,
                                              sample_rss=True)
    session_s = np.array([t for t, _ in rss])
    values = np.array([value for _, value in rss])
    half = session_s >= session_s[-1] / 2
    slope = np.polyfit(session_s[half] / 60.0, values[half], 1)[0] if half.sum() >= 3 else np.nan
    print(f"  RSS start {values[0]:.1f} MiB, end {values[-1]:.1f} MiB, max {values.max():.1f} MiB;"
          f" slope over the second half {slope:+.3f} MiB per session minute "
          f"({len(values)} samples, {session_s[-1] / 60:.1f} session minutes in "
          f"{seconds / 60:.1f} wall minutes)")
    if not args.skip_no_loss:
        print("no-loss checks:", "all passed" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
