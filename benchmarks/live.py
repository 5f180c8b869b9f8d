"""Live-link figures (issue 3): no loss, throughput, latency, memory. Prints figures; not a test.

    .venv/bin/python benchmarks/live.py                 # everything, 20-minute sessions
    .venv/bin/python benchmarks/live.py --minutes 2     # shorter simulated/paced sessions

- No loss: every real log in ../shared/data/realphone and a simulated 500 Hz session are sent
  with the phone emulator at full speed through the engine with a recorder (what `serve
  --record` runs): raw.txt must equal the input byte for byte, and the estimates must equal
  run_offline(read_log(file)) (what `orientation-lab filter` computes) bit for bit.
- Throughput: lines per second from the socket to published estimates (simulated session, full
  speed, comparisons off and on).
- Latency: chunk arrival on the socket -> estimate published to the GUI side, at 2,000 lines/s
  (500 Hz GYR, ACC, MAG, ORI), p50/p99/max.
- Memory: process RSS sampled during a paced 500 Hz session of --minutes minutes.
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

from app.engine import Engine  # noqa: E402
from app.io.emulator import PhoneEmulator, read_lines  # noqa: E402
from app.io.logfile import read_log  # noqa: E402
from app.io.protocol import Sample, format_line  # noqa: E402
from app.io.recorder import Recorder  # noqa: E402
from app.io.sources import TcpSource  # noqa: E402
from app.pipeline import run_offline  # noqa: E402

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


def _wait_done(engine: Engine, lines: int, timeout: float = 3600.0) -> float:
    """Until the engine has seen `lines` lines and the phone hung up; returns the finish time."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        health = engine.snapshot_now().health
        if health.lines_total >= lines and health.connection_state == "disconnected" \
                and engine.waiting_since is not None:
            return engine.waiting_since
        time.sleep(0.01)
    raise RuntimeError("engine did not finish")


def run_through_engine(lines: list[bytes], speed: float, comparisons: bool,
                       record_dir: Path | None, sample_rss: bool = False):
    """Send `lines` through a loopback engine; returns (engine, seconds, rss samples)."""
    source = TcpSource("127.0.0.1", 0, max_queued=1024)
    recorder = Recorder(record_dir) if record_dir is not None else None
    engine = Engine(source, comparisons=comparisons, recorder=recorder, record_rows=True)
    engine.start()
    rss: list[tuple[float, float]] = []
    try:
        started = time.monotonic()
        with PhoneEmulator("127.0.0.1", source.port) as phone:
            sender = threading.Thread(target=phone.stream_lines, args=(lines, speed))
            sender.start()
            while sender.is_alive():
                sender.join(timeout=10.0)
                if sample_rss:
                    rss.append((time.monotonic() - started, rss_mib()))
                    engine.poll()   # a GUI would drain the plot buffer
                    engine.rows_log.clear()
        finished = _wait_done(engine, len(lines))
        seconds = finished - started
    finally:
        engine.stop()
    return engine, seconds, rss


def engine_rows(engine: Engine):
    t_ms = np.concatenate([r.t_ms for r in engine.rows_log]) if engine.rows_log else np.empty(0)
    quat = np.concatenate([r.quat for r in engine.rows_log]) if engine.rows_log else np.empty((0, 4))
    return t_ms, quat


def no_loss(name: str, path: Path, lines: list[bytes]) -> bool:
    with tempfile.TemporaryDirectory() as directory:
        record = Path(directory) / "session"
        engine, seconds, _ = run_through_engine(lines, 0.0, False, record)
        raw_identical = (record / "raw.txt").read_bytes() == path.read_bytes()
        offline = run_offline(read_log(path).samples)
    t_ms, quat = engine_rows(engine)
    same = np.array_equal(t_ms, offline.t_ms) and np.array_equal(quat, offline.quat)
    print(f"  {name:48s} {len(lines):9d} lines  raw.txt identical: {raw_identical}  "
          f"estimates identical: {same}  ({len(lines) / seconds:,.0f} lines/s)")
    return raw_identical and same


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=20.0,
                        help="length of the simulated and paced sessions (default 20)")
    parser.add_argument("--latency-seconds", type=float, default=20.0)
    args = parser.parse_args()
    import ekf
    print(f"estimator: {type(ekf.make_estimator()).__name__} (ekf.make_estimator default)")
    ok = True

    print("No loss (send --speed 0 -> serve --record):")
    logs = sorted(REALPHONE.glob("*.txt")) if REALPHONE.is_dir() else []
    if not logs:
        print(f"  real logs not found at {REALPHONE}: skipped")
    for path in logs:
        ok &= no_loss(path.name, path, read_lines(path))
    simulated = simulated_lines(args.minutes)
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
    print(f"  {len(latency_ms)} chunks: p50 {np.percentile(latency_ms, 50):.2f} ms, "
          f"p99 {np.percentile(latency_ms, 99):.2f} ms, max {latency_ms.max():.2f} ms "
          f"(target p99 <= 5 ms)")

    print(f"Memory over a paced {args.minutes:g}-minute 500 Hz session (comparisons on):")
    engine, seconds, rss = run_through_engine(simulated, 1.0, True, None, sample_rss=True)
    values = [value for _, value in rss]
    if len(values) >= 3:
        third = max(1, len(values) // 3)
        print(f"  RSS first third {np.mean(values[:third]):.1f} MiB, last third "
              f"{np.mean(values[-third:]):.1f} MiB, max {max(values):.1f} MiB "
              f"({len(values)} samples over {seconds / 60:.1f} min)")
    print("no-loss checks:", "all passed" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
