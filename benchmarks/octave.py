"""Your MATLAB filter in GNU Octave: how fast the course EKF written in .m runs through the bridge,
how long a 10-minute recording takes to re-filter, and how far YOURS from Octave lags OWN live.

The filters are the solved course filters in .m that the tests use: tests/octave_filters/course
(the course's tu_qw, mu_g, mu_m, mu_normalizeQ calling the kit's Qq, dQqdq, Sq, Somega, as the
course writes them) and tests/octave_filters/course_lean (the same equations with the helpers'
formulas written inside the four functions). Peers in the same run: the same functions in a
plain filterTemplate loop in ``octave-cli`` (no bridge: the data read from a file, the loop in
one .m script), the course EKF in Python through its own process (examples/course_ekf.py) and
the built-in ``course`` estimator. The plain loop does the work the host's loop does on this
session: the course's gates (|a| within 1 m/s^2 of g, |m| within 5 uT of its low-pass), a time
update on every row after the first gyroscope sample (no gaps here, so the host's rules for
gaps change nothing), the estimate kept for every row (filterTemplate's xhat.x); it has no
checks of what the functions return, no start (tilt, heading) and a fixed m0, and calls the
functions as often as the host does (within a call or two in 60,000 rows).

The session is simulated: 100 Hz per sensor, GYR, ACC and MAG stamped together every 10 ms as
the Sensor Fusion app stamps them (the course's logs: 3 samples a row).

* throughput: a 10-minute session (60,000 rows, 180,000 samples), run as ``filter`` and
  ``evaluate`` run it (``UserFilterEstimator``, blocks of 4096 rows); samples per second of wall
  time and per second of Octave's CPU time (the machine is shared: CPU time is the figure);
  oct2py (if installed: ``pip install oct2py``) calling the same host function per block, at
  block sizes of 1, 5 and 4096 rows;
* a 10-minute recording (that session as a phone log) re-filtered: ``filter_log`` with the
  parser and the runner, wall time (target <= 20 s);
* live: the engine (a TCP source) gets a simulated phone streaming 100 Hz per sensor in real time
  for --live-seconds; this process polls snapshots like the window and notes when each row first
  appears in OWN's plot samples and in YOURS': YOURS' lag behind OWN p50/p95/max (target p95 <=
  100 ms), and the snapshots per second the window gets (OWN's frame rate), with no filter of
  yours, with the Python course EKF and with the .m one.

    .venv/bin/python benchmarks/octave.py [--minutes 10] [--live-seconds 30]
    .venv/bin/python benchmarks/octave.py --quick
    .venv/bin/python benchmarks/octave.py --live-only [--live-seconds 30]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import ekf  # noqa: E402
from ekf.simulate import simulate  # noqa: E402
from app.engine.config import open_log  # noqa: E402
from app.engine.offline.filtering import filter_log  # noqa: E402
from app.engine.userfilter.filter import UserFilterEstimator  # noqa: E402
from app.engine.userfilter.octave import HOST_DIR, find_octave  # noqa: E402
from app.engine.userfilter.remote import filter_settings  # noqa: E402
from app.engine.userfilter.protocol import settings_to_wire  # noqa: E402
from app.engine.warmup import warm_up  # noqa: E402
from app.engine.live.worker import Engine  # noqa: E402
from app.stream.emulator import PhoneEmulator  # noqa: E402
from app.stream.protocol import Sample, format_line  # noqa: E402
from app.stream.sources import TcpSource  # noqa: E402

COURSE_M = REPO / "tests" / "octave_filters" / "course"
COURSE_LEAN = REPO / "tests" / "octave_filters" / "course_lean"
COURSE_PY = REPO / "examples" / "course_ekf.py"
COURSE = ekf.PRESETS["course"]
RATES = {"gyr": 100.0, "acc": 100.0, "mag": 100.0, "ori": 100.0}

# The course's filterTemplate loop in plain Octave: the same functions, the same gates, no bridge
# (m0: the simulator's field).
PLAIN_LOOP = r"""
crash_dumps_octave_core(false); sigterm_dumps_octave_core(false);
addpath(getenv('COURSE_M'));
fid = fopen(getenv('ROWS_FILE'), 'r'); D = fread(fid, [10, Inf], 'double'); fclose(fid);
n = columns(D); Rw = 1e-4*eye(3); Ra = 0.1*eye(3); Rm = 2*eye(3); g0 = [0; 0; 9.81];
x = [1; 0; 0; 0]; P = eye(4); omega = []; m0 = [0; 15.5; -48]; L = norm(m0); tprev = NaN;
xhat = zeros(4, n);
c0 = cputime;
for k = 1:n
  t = D(1, k);
  if ~isempty(omega) && t > tprev
    [x, P] = tu_qw(x, P, omega, t - tprev, Rw);
    [x, P] = mu_normalizeQ(x, P);
  end
  tprev = t;
  if ~isnan(D(2, k)), omega = D(2:4, k); end
  acc = D(5:7, k);
  if ~isnan(acc(1)) && abs(norm(acc) - 9.81) <= 1.0
    [x, P] = mu_g(x, P, acc, Ra, g0);
    [x, P] = mu_normalizeQ(x, P);
  end
  mag = D(8:10, k);
  if ~isnan(mag(1))
    out = abs(norm(mag) - L) > 5.0; L = 0.99 * L + 0.01 * norm(mag);
    if ~out
      [x, P] = mu_m(x, P, mag, m0, Rm);
      [x, P] = mu_normalizeQ(x, P);
    end
  end
  xhat(:, k) = x;
end
printf('%.6f\n', cputime - c0);
"""


def session(minutes: float):
    """The lines of a simulated phone log (the sensors stamped together on a 10 ms grid) and its
    rows: t [s], values (n, 9) GYR, ACC, MAG (NaN: none)."""
    sim = simulate(duration_s=60.0 * minutes, rates_hz=RATES, seed=11)
    t0 = None
    samples = []
    for t, tag, values in sim.iter_rows():
        t0 = t if t0 is None else t0
        samples.append(Sample(t - (t - t0) % 10, tag, values))
    lines = [(format_line(s) + "\n").encode("ascii") for s in samples]
    rows: dict[int, np.ndarray] = {}
    for s in samples:
        if s.tag in ("GYR", "ACC", "MAG"):
            row = rows.setdefault(s.t_ms, np.full(9, np.nan))
            at = ("GYR", "ACC", "MAG").index(s.tag) * 3
            row[at:at + 3] = s.values[:3]
    t_ms = np.array(sorted(rows), np.int64)
    values = np.array([rows[t] for t in t_ms.tolist()])
    return lines, t_ms / 1000.0, values


def octave_cpu(pid: int) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return float("nan")


def plain_octave(folder: Path, t: np.ndarray, values: np.ndarray) -> float:
    """Octave's CPU seconds for the plain loop over the rows with the filter in `folder`."""
    with tempfile.TemporaryDirectory() as scratch:
        data = Path(scratch) / "rows.bin"
        np.concatenate([t[:, None], values], axis=1).astype("<f8").tofile(data)
        script = Path(scratch) / "plain_loop.m"
        script.write_text(PLAIN_LOOP)
        out = subprocess.run([str(find_octave()), "--no-gui", "--norc", "--quiet",
                              "--no-window-system", str(script)],
                             env={**os.environ, "COURSE_M": str(folder),
                                  "ROWS_FILE": str(data)},
                             capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(f"the plain loop failed: {out.stderr.strip()}")
    return float(out.stdout.strip().splitlines()[-1])


def through_bridge(path: Path, t: np.ndarray, values: np.ndarray) -> tuple[float, float]:
    """Wall seconds and the filter process's CPU seconds for a run as `filter` does it."""
    with UserFilterEstimator(path, COURSE) as estimator:
        pid = estimator.remote.process.pid
        before = octave_cpu(pid)
        started = time.perf_counter()
        estimator.run_batch(t, values[:, 0:3], values[:, 3:6], values[:, 6:9])
        wall = time.perf_counter() - started
        cpu = octave_cpu(pid) - before
        assert estimator.problem is None, estimator.problem
    return wall, cpu


def through_oct2py(t: np.ndarray, values: np.ndarray, block: int, rows: int) -> float | None:
    """Seconds per block when oct2py calls the host's loop (the state kept in Octave)."""
    os.environ.setdefault("OCTAVE_EXECUTABLE", str(find_octave()))     # octave-cli: no GUI
    try:
        from oct2py import Oct2Py
    except ImportError:
        return None
    oc = Oct2Py()
    try:
        oc.addpath(str(HOST_DIR))
        wire = json.dumps(settings_to_wire(filter_settings(COURSE)))
        oc.eval(f"cd('{COURSE_M}'); ctx = ol_load(pwd, pwd, jsondecode('{wire}'));")
        given = (~np.isnan(values[:, [0, 3, 6]])).astype(float)
        started = time.perf_counter()
        count = 0
        for start in range(0, rows, block):
            end = start + block
            oc.push("T", t[start:end].reshape(-1, 1))
            oc.push("G", given[start:end])
            oc.push("V", np.nan_to_num(values[start:end]))
            oc.eval("[ctx, reply, entries] = ol_run_block(ctx, T, G, V); Q = entries{1, 4};")
            oc.pull("Q")
            count += 1
        return (time.perf_counter() - started) / count
    finally:
        oc.exit()


def pipe_per_block(t: np.ndarray, values: np.ndarray, block: int, rows: int) -> float:
    """Seconds per block through the pipe, each block waited for (as oct2py waits)."""
    with UserFilterEstimator(COURSE_M, COURSE) as estimator:
        started = time.perf_counter()
        count = 0
        for start in range(0, rows, block):
            end = start + block
            estimator.run_batch(t[start:end], values[start:end, 0:3], values[start:end, 3:6],
                                values[start:end, 6:9])
            count += 1
        return (time.perf_counter() - started) / count


def live(lines: list[bytes], user: Path | None) -> dict[str, float]:
    """YOURS' lag behind OWN per row and the snapshots per second, a phone streaming in real
    time (see the module docstring)."""
    own: dict[float, float] = {}
    yours: dict[float, float] = {}
    snapshots = 0
    engine = Engine(TcpSource("127.0.0.1", 0), settings=COURSE, comparisons=False, index=False,
                    user_filter=None if user is None else str(user))
    with engine:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:             # the filter loaded, the kernels ready
            snapshot = engine.snapshot_now()
            if not engine.preparing and (user is None or (
                    snapshot.user is not None and snapshot.user.state == "running")):
                break
            time.sleep(0.05)
        done = threading.Event()
        with PhoneEmulator("127.0.0.1", engine.source.port) as phone:
            sender = threading.Thread(target=lambda: (phone.stream_lines(lines, 1.0),
                                                      done.set()), daemon=True)
            started = time.perf_counter()
            sender.start()
            quiet_since = None
            while True:
                snapshot = engine.poll()
                now = time.perf_counter()
                if snapshot is not None:
                    snapshots += 1
                    for t in snapshot.plot.t_est.tolist():
                        own.setdefault(t, now)
                    for t in snapshot.plot.t_user.tolist():
                        yours.setdefault(t, now)
                if done.is_set():
                    quiet_since = quiet_since or now
                    if now - quiet_since > 1.0:
                        break
                time.sleep(0.002)
            streamed = (quiet_since or now) - started
            sender.join()
    out = {"rows": len(own), "fps": snapshots / streamed}
    lags = np.array([yours[t] - own[t] for t in own if t in yours])
    if len(lags):
        out.update(answered=len(lags), p50=float(np.percentile(lags, 50)),
                   p95=float(np.percentile(lags, 95)), max=float(lags.max()))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0,
                        help="the recording's length (default 10)")
    parser.add_argument("--live-seconds", type=float, default=30.0,
                        help="live streaming for the lag (default 30)")
    parser.add_argument("--quick", action="store_true", help="a smoke run: 0.1 min, 3 s live")
    parser.add_argument("--live-only", action="store_true", help="only the live lag")
    args = parser.parse_args()
    minutes, live_s = (0.1, 3.0) if args.quick else (args.minutes, args.live_seconds)
    if shutil.which(str(find_octave())) is None:
        print("GNU Octave not found")
        return 1
    warm_up()
    if args.live_only:
        return live_table(live_s)
    lines, t, values = session(minutes)
    samples = int(np.count_nonzero(~np.isnan(values[:, [0, 3, 6]])))
    print(f"{minutes:g} min at 100 Hz per sensor: {len(t)} rows, {samples} samples"
          + (" [--quick: not a figure]" if args.quick else ""))
    print(f"{'':<40}{'wall s':>8}{'samples/s':>11}{'cpu s':>8}{'samples/cpu-s':>15}")
    for label, folder in (("as the course writes it", COURSE_M), ("lean", COURSE_LEAN)):
        plain = plain_octave(folder, t, values)
        print(f"{'.m ' + label + ', plain octave-cli':<40}{'':>8}{'':>11}{plain:>8.2f}"
              f"{samples / plain:>15,.0f}")
        wall, cpu = through_bridge(folder, t, values)
        print(f"{'.m ' + label + ', through the bridge':<40}{wall:>8.2f}{samples / wall:>11,.0f}"
              f"{cpu:>8.2f}{samples / cpu:>15,.0f}")
    wall, cpu = through_bridge(COURSE_PY, t, values)
    print(f"{'course_ekf.py, its own process':<40}{wall:>8.2f}{samples / wall:>11,.0f}"
          f"{cpu:>8.2f}{samples / cpu:>15,.0f}")
    started = time.perf_counter()
    ekf.make_estimator("course", COURSE).run_batch(t, values[:, 0:3], values[:, 3:6],
                                                   values[:, 6:9])
    wall = time.perf_counter() - started
    print(f"{'built-in course':<40}{wall:>8.2f}{samples / wall:>11,.0f}")

    print("\nper block, waited for (ms):")
    print(f"{'rows per block':<16}{'pipe':>10}{'oct2py':>10}")
    for block, rows in ((1, 200), (5, 500), (4096, min(len(t), 3 * 4096))):
        pipe = pipe_per_block(t, values, block, rows)
        o2p = through_oct2py(t, values, block, rows)
        print(f"{block:<16}{pipe * 1e3:>10.2f}"
              f"{'not installed' if o2p is None else f'{o2p * 1e3:.2f}':>10}")

    with tempfile.TemporaryDirectory() as folder:
        log = Path(folder) / "recording.txt"
        log.write_bytes(b"".join(lines))
        print(f"\na {minutes:g}-minute recording re-filtered (filter_log; target <= 20 s for 10 "
              "minutes):")
        for label, path in (("as the course writes it", COURSE_M), ("lean", COURSE_LEAN)):
            started = time.perf_counter()
            with UserFilterEstimator(path, COURSE) as estimator:
                pid = estimator.remote.process.pid
                before = octave_cpu(pid)
                rows = filter_log(open_log(log), estimator, COURSE)
                cpu = octave_cpu(pid) - before
            wall = time.perf_counter() - started
            print(f"  .m {label}: {wall:.1f} s ({len(rows.t_ms)} rows; Octave's CPU {cpu:.1f} s)")

    return live_table(live_s)


def live_table(live_s: float) -> int:
    live_lines, _, _ = session(live_s / 60.0)
    print(f"\nlive, {live_s:g} s at 100 Hz per sensor:")
    print(f"{'your filter':<18}{'rows':>7}{'answered':>10}{'p50 ms':>9}{'p95 ms':>9}{'max ms':>9}"
          f"{'snapshots/s':>13}")
    for label, user in (("none", None), ("course_ekf.py", COURSE_PY), (".m in Octave", COURSE_M),
                        (".m lean", COURSE_LEAN)):
        result = live(live_lines, user)
        lag = "".join(f"{result[key] * 1e3:>9.1f}" for key in ("p50", "p95", "max")) \
            if "p95" in result else f"{'':>27}"
        print(f"{label:<18}{result['rows']:>7}{result.get('answered', 0):>10}{lag}"
              f"{result['fps']:>13.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
