"""Sessions: open a one-hour 100 Hz recorded session, seek in it, the window's memory
with it loaded. Prints figures; not a test.

    .venv/bin/python benchmarks/session.py            # a one-hour session (~2 minutes in all)
    .venv/bin/python benchmarks/session.py --quick    # a 3-minute one (smoke test)

- The session: a simulated phone (ACC, GYR, ORI 100 Hz, MAG 50 Hz) written as a recorded
  session folder (raw.txt in the phone's float text, session.json with a timeline: the
  magnetometer switched out and in again, two markers).
- open: from opening the folder (the --replay / File → Open resolution) to the engine playing it
  (its first snapshot, the replay ready: play, pause, seek work from then on). The index (a
  checkpoint every second, the whole session's plot data) is then built in the background;
  "indexed" is when it is complete (seeks before then replay from the latest checkpoint so far).
- seek: once indexed, N seeks to random positions (fixed seed) while paused, each timed from
  engine.send(seek) to the engine's state being that of playing to the target (a checkpoint
  restored, at most one second of lines replayed: Engine.seeks). The 7 comparison filters run
  (every estimator is in every checkpoint).
- window memory: a fresh interpreter opens the window (offscreen) on the session, waits until the
  whole session is drawn from the index, and reports its RSS; the same for a one-minute session
  for comparison.

The last line is ``seek: median X ms, worst Y ms over N seeks; open: Z s``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.engine.commands import ReplayControl  # noqa: E402
from app.engine.config import open_replay  # noqa: E402
from app.engine.live.worker import Engine  # noqa: E402

RATES = {"gyr": 100.0, "acc": 100.0, "mag": 50.0, "ori": 100.0}


def rss_mib() -> float:
    with open("/proc/self/statm") as stream:
        pages = int(stream.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def build_session(folder: Path, duration_s: float, seed: int = 12) -> Path:
    """A recorded session folder: raw.txt and a session.json with a small timeline."""
    from ekf.simulate import simulate
    from app.stream.demo import write_session
    folder.mkdir(parents=True, exist_ok=True)
    write_session(simulate(duration_s=duration_s, rates_hz=RATES, seed=seed),
                  folder / "raw.txt")
    per_second = int(sum(RATES.values()))
    timeline = [
        {"kind": "sensor", "sensor": "mag", "enabled": False, "t_ms": None,
         "sample": int(0.3 * duration_s) * per_second},
        {"kind": "sensor", "sensor": "mag", "enabled": True, "t_ms": None,
         "sample": int(0.4 * duration_s) * per_second},
        {"kind": "marker", "id": 1, "label": "mag out", "t_s": 0.3 * duration_s, "t_ms": None},
        {"kind": "marker", "id": 2, "label": "mag in", "t_s": 0.4 * duration_s, "t_ms": None}]
    (folder / "session.json").write_text(json.dumps(
        {"format": 2, "app": "orientation-lab", "estimator": "ekf",
         "sensors": {"gyr": True, "acc": True, "mag": True},
         "comparisons": {"enabled": True, "estimator": "ekf"}, "timeline": timeline}))
    return folder


def wait(condition, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.002)
    raise SystemExit(f"session.py: timed out waiting for {what}")


def open_and_seek(folder: Path, seeks: int) -> dict:
    started = time.perf_counter()
    source = open_replay(folder, paused=True)
    engine = Engine(source)
    engine.start()
    wait(lambda: (engine.snapshot_now().replay or {}).get("lines"), 60, "the replay")
    opened = time.perf_counter() - started
    replay = wait(lambda: (r := engine.snapshot_now().replay) and r.get("indexed") and r,
                  600, "the index")
    indexed = time.perf_counter() - started
    index = engine.replay_lane.manager.index
    rng = np.random.default_rng(7)
    times, replayed = [], []
    try:
        for position in rng.uniform(0.0, source.duration_s, seeks):
            count = len(engine.seeks)
            sent = time.perf_counter()
            engine.send(ReplayControl(seek_s=float(position)))
            wait(lambda: len(engine.seeks) > count, 30, "a seek")
            done, lines = engine.seeks[-1]
            times.append(done - sent)
            replayed.append(lines)
            time.sleep(0.03)            # a user does not seek 100 times a second
    finally:
        engine.stop()
    return {"open_s": opened, "indexed_s": indexed, "index_s": replay.get("index_seconds"),
            "seek_ms": np.array(times) * 1000.0, "lines": np.array(replayed),
            "duration_s": source.duration_s, "line_count": source.line_count,
            "checkpoints": len(index.store), "checkpoint_mb": index.store.nbytes() / 2**20,
            "plot_mb": index.plot.nbytes() / 2**20, "raw_mb": len(source.data) / 2**20,
            "rate": source.line_count / source.duration_s}


def window_memory(folder: Path) -> float:
    """RSS [MiB] of a fresh window process with the session loaded and drawn."""
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen")
    result = subprocess.run([sys.executable, __file__, "--window-memory", str(folder)],
                            capture_output=True, text=True, env=env, timeout=900, cwd=ROOT)
    if result.returncode != 0:
        raise SystemExit(f"session.py: the window process failed:\n{result.stderr[-2000:]}")
    return float(result.stdout.strip().splitlines()[-1])


def _window_memory_child(folder: str) -> None:
    from PySide6 import QtCore, QtWidgets
    from app.ui.main_window import MainWindow
    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication([])
    settings_dir = tempfile.TemporaryDirectory()
    settings = QtCore.QSettings(str(Path(settings_dir.name) / "s.ini"),
                                QtCore.QSettings.Format.IniFormat)
    engine = Engine(open_replay(folder, paused=True))
    engine.start()
    window = MainWindow(engine, settings=settings, use_gl=False)
    window.resize(1280, 720)
    window.show()
    deadline = time.monotonic() + 600
    while window.plots.session is None and time.monotonic() < deadline:
        app.processEvents()
        time.sleep(0.01)
    for _ in range(30):                      # draw a few frames of it
        app.processEvents()
        time.sleep(0.02)
    if window.plots.session is None:
        raise SystemExit("the whole session was never drawn")
    print(f"{rss_mib():.1f}")
    window.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a 3-minute session, 20 seeks")
    parser.add_argument("--minutes", type=float, default=None, help="session length")
    parser.add_argument("--seeks", type=int, default=None)
    parser.add_argument("--no-window", action="store_true", help="skip the window's memory")
    parser.add_argument("--window-memory", metavar="FOLDER", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.window_memory:
        _window_memory_child(args.window_memory)
        return
    minutes = args.minutes or (3.0 if args.quick else 60.0)
    seeks = args.seeks or (20 if args.quick else 100)
    with tempfile.TemporaryDirectory(prefix="orientation-lab-session-") as temporary:
        made = time.perf_counter()
        folder = build_session(Path(temporary) / "session", minutes * 60.0)
        print(f"session: {minutes:g} min at 100 Hz built in {time.perf_counter() - made:.1f} s")
        figures = open_and_seek(folder, seeks)
        print(f"session: {figures['line_count']:,} lines ({figures['rate']:.0f} lines/s), "
              f"raw.txt {figures['raw_mb']:.0f} MB")
        print(f"index: complete {figures['indexed_s']:.1f} s after opening (built in "
              f"{figures['index_s']:.1f} s in the background): {figures['checkpoints']} "
              f"checkpoints ({figures['checkpoint_mb']:.0f} MB), whole-session plot data "
              f"{figures['plot_mb']:.0f} MB")
        lines = figures["lines"]
        print(f"seek: lines replayed from the checkpoint: median {np.median(lines):.0f}, "
              f"max {lines.max()} (at most one second: {figures['rate']:.0f})")
        if not args.no_window:
            small = build_session(Path(temporary) / "small", 60.0)
            print(f"window: RSS {window_memory(folder):.0f} MiB with the {minutes:g}-minute "
                  f"session loaded and drawn ({window_memory(small):.0f} MiB with a 1-minute "
                  "one)")
        seek_ms = figures["seek_ms"]
        print(f"seek: median {np.median(seek_ms):.0f} ms, worst {seek_ms.max():.0f} ms over "
              f"{len(seek_ms)} seeks; open: {figures['open_s']:.2f} s")


if __name__ == "__main__":
    main()
