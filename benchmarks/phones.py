"""Any phone: phyphox and Sensor Logger on loopback. Prints figures; not a test.

    .venv/bin/python benchmarks/phones.py            # a 10-minute log, the phone gone 5 s
    .venv/bin/python benchmarks/phones.py --quick    # a 40-second log, the phone gone 2 s

A simulated 10-minute session (ACC, GYR, ORI 100 Hz, MAG 50 Hz) is played at its own rate by
each phone emulator; at half time the phone disappears for 5 s (phyphox: it refuses
connections while its measurement goes on; Sensor Logger: its batches wait and go out after).
Four flows run at once, each with its own emulator:

- `serve --phyphox URL --record DIR` and `serve --sensor-logger PORT --record DIR` (the
  command, in a subprocess): the recording's raw.txt must hold the log's samples, each tag's
  in the log's order, none lost; its estimates.csv must equal `orientation-lab filter LOG`
  (every row but the last few, which a live stream leaves in the reorder window).
- The same sources into an engine in this process (comparisons on, as the window runs):
  latency from the moment a sample exists on the emulated phone (phyphox: it is in the
  phone's buffers; Sensor Logger: its sample time, before batching) to the engine's published
  estimate at that sample's time, read every 5 ms; p50/p95/max outside the gap (and the
  catch-up after it). Targets: phyphox p95 <= 100 ms; Sensor Logger p95 <= the batch period
  (1 s) + 50 ms.
- phyphox requests in flight at once, seen by the client and by the single-threaded server.
"""

from __future__ import annotations

import argparse
import csv
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.engine.live.worker import Engine  # noqa: E402
from app.stream.phyphox import PhyphoxSource  # noqa: E402
from app.stream.protocol import ParseError, Sample, format_line, parse_line  # noqa: E402
from app.stream.sensor_logger import SensorLoggerSource  # noqa: E402

CLI = [sys.executable, "-m", "app"]
RATES = {"gyr": 100.0, "acc": 100.0, "mag": 50.0, "ori": 100.0}
PERIOD_S = 1.0
WARM_UP_S = 3.0


def simulated_lines(seconds: float) -> list[bytes]:
    from ekf.simulate import simulate
    session = simulate(duration_s=seconds, rates_hz=RATES, seed=11)
    return [(format_line(Sample(t, tag, values)) + "\n").encode("ascii")
            for t, tag, values in session.iter_rows()]


def per_tag(lines) -> dict[str, list[tuple[int, tuple]]]:
    out: dict[str, list[tuple[int, tuple]]] = defaultdict(list)
    for line in lines:
        try:
            sample = parse_line(line.decode("ascii") if isinstance(line, bytes) else line)
        except ParseError:
            continue
        out[sample.tag].append((sample.t_ms, sample.values))
    return dict(out)


def read_estimates(path: Path) -> tuple[np.ndarray, np.ndarray]:
    with open(path, newline="") as stream:
        rows = list(csv.reader(stream))[1:]
    t = np.array([int(r[0]) for r in rows], np.int64)
    q = np.array([[float(v) for v in r[1:5]] for r in rows])
    return t, q


# ---- the emulated phones, each in a process of its own (as a phone is) ---------------------------

def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def send(log: Path, *options: str) -> subprocess.Popen:
    return subprocess.Popen(CLI + ["send", str(log), *options], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT)


def finish(process: subprocess.Popen, timeout: float) -> str:
    try:
        _, err = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        _, err = process.communicate()
    return err.strip().splitlines()[-1] if err.strip() else f"exit {process.returncode}"


# ---- serve --record, in a subprocess ------------------------------------------------------------

def serve(args: list[str], folder: Path, idle_s: float) -> subprocess.Popen:
    return subprocess.Popen(CLI + ["serve", *args, "--record", str(folder), "--no-comparisons",
                                   "--quiet", "--exit-when-idle", str(idle_s)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)


def phyphox_serve_flow(log: Path, folder: Path, gone: str, duration_s: float,
                       results: dict) -> None:
    port = free_port()
    phone = send(log, "--as", "phyphox", "--port", str(port), "--start-ms", "0", "--gone", gone)
    time.sleep(1.0)                                  # the phone's app is open first
    process = serve(["--phyphox", f"127.0.0.1:{port}"], folder, 15)
    out, err = process.communicate(timeout=duration_s + 180)
    results["phyphox serve"] = {"code": process.returncode,
                                "final": out.strip().splitlines()[-1][-300:],
                                "stderr": err.strip()[-300:], "phone": finish(phone, 30)}


def sensor_logger_serve_flow(log: Path, folder: Path, gone: str, first_ms: int,
                             duration_s: float, results: dict) -> None:
    process = serve(["--sensor-logger", "127.0.0.1:0"], folder, 15)
    port = process.stdout.readline().split("port ")[1].split()[0]
    phone = send(log, "--as", "sensor-logger", "--url", f"http://127.0.0.1:{port}/",
                 "--period", str(PERIOD_S), "--epoch-ms", str(first_ms), "--gone", gone)
    phone_said = finish(phone, duration_s + 120)
    out, err = process.communicate(timeout=120)
    results["Sensor Logger serve"] = {"code": process.returncode,
                                      "final": out.strip().splitlines()[-1][-300:],
                                      "stderr": err.strip()[-300:], "phone": phone_said}


# ---- latency, an engine in this process -----------------------------------------------------------

def watch(source, timeout_s: float, stop_when) -> tuple[list[tuple[float, int]], dict]:
    """Run an engine on the source (comparisons on, as the window does); every 5 ms the time
    (epoch s) and the published estimate's phone time. Ends when stop_when(t_ms) or after
    timeout_s."""
    engine = Engine(source, comparisons=True)
    engine.start()
    polls: list[tuple[float, int]] = []
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline:
            t_ms = engine.snapshot_now().t_ms
            if t_ms is not None:
                if not polls or polls[-1][1] != t_ms:
                    polls.append((time.time(), t_ms))
                if stop_when(t_ms):
                    break
            time.sleep(0.005)
        info = engine.source.info()
    finally:
        engine.stop()
    return polls, info


def latencies(polls: list[tuple[float, int]], rows_at: np.ndarray, available) -> np.ndarray:
    """(latency s, when the sample existed, epoch s) of every row: the first poll whose estimate
    reached its time, minus `available(t_ms)`."""
    out = []
    done = 0
    for now, t_ms in polls:
        reached = int(np.searchsorted(rows_at, t_ms, side="right"))
        for t in rows_at[done:reached]:
            at = available(int(t))
            out.append((now - at, at))
        done = max(done, reached)
    return np.array(out).reshape(-1, 2)


def split(found: np.ndarray, gone_at_s: float, gone_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The latencies outside and inside the gap: the first seconds load the filter's kernels;
    the gap (from the batch before it) and its catch-up are apart."""
    if not len(found):
        return np.zeros(0), np.zeros(0)
    latency, at = found[:, 0], found[:, 1] - found[:, 1].min()
    outside = (at > WARM_UP_S) & ((at < gone_at_s - PERIOD_S - 0.1)
                                  | (at > gone_at_s + gone_s + 3.0))
    return latency[outside], latency[~outside]


def phyphox_latency_flow(log: Path, rows_at: np.ndarray, first_ms: int, gone: str,
                         gone_at_s: float, gone_s: float, duration_s: float,
                         results: dict) -> None:
    port = free_port()
    phone = send(log, "--as", "phyphox", "--port", str(port), "--started", "--gone", gone)
    since = float(phone.stderr.readline().split("measuring since ")[1].split()[0])
    times = rows_at - first_ms                          # phyphox's experiment time [ms]
    polls, info = watch(PhyphoxSource(f"127.0.0.1:{port}"), duration_s + 60,
                        lambda t_ms: t_ms >= times[-1])
    said = finish(phone, 30)
    # a sample is in the phone's buffers from its time on
    found = latencies(polls, times, lambda t_ms: since + t_ms / 1000.0)
    outside, gap = split(found, gone_at_s, gone_s)
    results["phyphox latency"] = {"latency": outside, "gap": gap, "info": info, "phone": said}


def sensor_logger_latency_flow(log: Path, rows_at: np.ndarray, gone: str, gone_at_s: float,
                               gone_s: float, duration_s: float, results: dict) -> None:
    port = free_port()
    phone: list[subprocess.Popen] = []

    def push() -> None:                              # once the engine listens
        time.sleep(2.0)
        phone.append(send(log, "--as", "sensor-logger", "--url", f"http://127.0.0.1:{port}/",
                          "--period", str(PERIOD_S), "--gone", gone))
    pusher = threading.Thread(target=push)
    pusher.start()
    polls, info = watch(SensorLoggerSource("127.0.0.1", port), duration_s + 3 * gone_s + 60,
                        lambda t_ms: bool(phone) and phone[0].poll() is not None)
    pusher.join()
    said = finish(phone[0], 60)
    offset = int(said.split("the log's time + ")[1].split()[0])
    # a sample exists at its own time stamp: the phone's clock (epoch ms)
    found = latencies(polls, rows_at + offset, lambda t_ms: t_ms / 1000.0)
    outside, gap = split(found, gone_at_s, gone_s)
    results["Sensor Logger latency"] = {"latency": outside, "gap": gap, "info": info,
                                        "phone": said}


# ---- the figures ----------------------------------------------------------------------------------

def check_recording(name: str, folder: Path, lines: list[bytes], offline: tuple) -> str:
    raw = folder / "raw.txt"
    if not raw.is_file():
        return f"{name}: no recording ({folder})"
    recorded = raw.read_bytes().splitlines()
    got, expected = per_tag(recorded), per_tag(lines)
    lost = {tag: len(expected[tag]) - len(got.get(tag, [])) for tag in expected}
    same = all(got.get(tag) == expected[tag] for tag in expected)
    t, q = read_estimates(folder / "estimates.csv")
    t_off, q_off = offline
    count = len(t)
    equal = np.array_equal(t, t_off[:count]) and np.array_equal(q, q_off[:count])
    return (f"{name}: recording {len(recorded)} lines of {len(lines)}; samples lost per tag "
            f"{lost}; each tag's samples equal the log's, in order: {same}; estimates.csv "
            f"{count} rows of filter's {len(t_off)}, equal bit for bit: {equal}")


def percentiles(values: np.ndarray) -> str:
    if not len(values):
        return "no samples"
    p50, p95 = np.percentile(values * 1000, [50, 95])
    return (f"p50 {p50:.1f} ms, p95 {p95:.1f} ms, max {values.max() * 1000:.1f} ms "
            f"({len(values)} readings)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a 40 s log, gone 2 s")
    args = parser.parse_args()
    seconds, gone_s = (40.0, 2.0) if args.quick else (600.0, 5.0)
    gone_at_s = seconds / 2
    lines = simulated_lines(seconds)
    with tempfile.TemporaryDirectory(prefix="phones-") as folder:
        work = Path(folder)
        log = work / "log.txt"
        log.write_bytes(b"".join(lines))
        subprocess.run(CLI + ["filter", str(log), "-o", str(work / "filter.csv")], check=True,
                       cwd=ROOT, stdout=subprocess.DEVNULL)
        offline = read_estimates(work / "filter.csv")
        results: dict = {}
        rows_at = np.unique(offline[0])              # the rows: GYR, ACC, MAG sample times
        first_ms = min(int(line.split(b"\t", 1)[0]) for line in lines)
        gone = f"{gone_at_s:g}:{gone_s:g}"
        flows = [threading.Thread(target=phyphox_serve_flow, args=(
                     log, work / "phyphox", gone, seconds, results)),
                 threading.Thread(target=sensor_logger_serve_flow, args=(
                     log, work / "sensor-logger", gone, first_ms, seconds, results)),
                 threading.Thread(target=phyphox_latency_flow, args=(
                     log, rows_at, first_ms, gone, gone_at_s, gone_s, seconds, results)),
                 threading.Thread(target=sensor_logger_latency_flow, args=(
                     log, rows_at, gone, gone_at_s, gone_s, seconds, results))]
        started = time.monotonic()
        for flow in flows:
            flow.start()
        for flow in flows:
            flow.join()
        print(f"{seconds:.0f} s log ({len(lines)} lines), the phone gone {gone_s:g} s at "
              f"{gone_at_s:.0f} s; {time.monotonic() - started:.0f} s wall")
        for name, folder_name in (("phyphox serve", "phyphox"),
                                  ("Sensor Logger serve", "sensor-logger")):
            result = results.get(name, {})
            print(check_recording(name, work / folder_name, lines, offline))
            print(f"  serve exit {result.get('code')}; {result.get('final', '')[-200:]}")
            print(f"  phone: {result.get('phone')}")
            if result.get("stderr"):
                print(f"  stderr: {result['stderr']}")
        for name in ("phyphox latency", "Sensor Logger latency"):
            result = results.get(name, {})
            print(f"{name}: {percentiles(result.get('latency', np.zeros(0)))}; the samples of "
                  f"the gap and the catch-up: max "
                  f"{result['gap'].max() * 1000 if len(result.get('gap', [])) else 0:.0f} ms; "
                  f"phone {result.get('phone')}")
        info = results.get("phyphox latency", {}).get("info", {}).get("phyphox", {})
        print(f"phyphox requests in flight at once, most: {info.get('requests_in_flight_max')}"
              " (client); the server counts a request that found another connection waiting "
              "as overlapping (above)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
