"""Start-up: how long until the demo moves, with and without numba's kernel cache, and how long
until the window is up. Prints figures; not a test.

    .venv/bin/python benchmarks/startup.py            # cold (an empty kernel cache) and warm
    .venv/bin/python benchmarks/startup.py --quick    # warm only (smoke test)

- demo moving: a fresh interpreter imports the engine, starts it on the built-in demo (the
  `--demo` source) and waits for the first estimate; timed from the interpreter's start. Cold:
  NUMBA_CACHE_DIR points to an empty folder, so every kernel is compiled (a first start after
  `pip install`); warm: the cache `make run` fills. The engine compiles (or loads) its kernels
  before the demo's clock starts, so the demo then begins at 0:00.
  The cold start is also timed with every kernel compiled in the one process, for comparison
  with the second process that compiles the stream's kernels meanwhile.
- window: a fresh interpreter opens the window offscreen on the demo and exits as soon as it
  has been shown (`--exit-after 0`); timed from the interpreter's start to its exit.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_MOVING = r"""
import sys, time
started = time.perf_counter()
if "--one-process" in sys.argv:
    import app.engine.warmup
    app.engine.warmup._start_stream_helper = lambda: None
from app.engine.live.worker import Engine
from app.stream.sources import demo_source
engine = Engine(demo_source(), comparisons=True)
engine.start()
prepared = None
while True:
    snapshot = engine.snapshot_now()
    if prepared is None and not engine.preparing:
        prepared = time.perf_counter()
    if snapshot.t_ms is not None:
        break
    time.sleep(0.01)
moving = time.perf_counter()
position = snapshot.replay["position_s"] if snapshot.replay else float("nan")
engine.stop()
print(f"{prepared - started:.2f} {moving - started:.2f} {position:.2f}")
"""


def demo_moving(cache_dir: str | None, one_process: bool = False) -> tuple[float, float, float]:
    """(kernels ready s, demo moving s, the demo's position then s), from interpreter start;
    one_process: the warm-up compiles everything itself (no second process for the stream's
    kernels), for comparison."""
    env = dict(os.environ)
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = cache_dir
    started = time.perf_counter()
    result = subprocess.run([sys.executable, "-c", _MOVING, *(["--one-process"] if one_process
                                                             else [])], cwd=ROOT, env=env,
                            capture_output=True, text=True, timeout=900)
    spawn = time.perf_counter() - started
    if result.returncode != 0:
        raise SystemExit(f"the demo run failed:\n{result.stderr}")
    ready, moving, position = (float(v) for v in result.stdout.split()[-3:])
    # the interpreter's own start (before its first line) is part of what a user waits for
    overhead = max(0.0, spawn - moving)
    return ready + overhead, moving + overhead, position


def window_up() -> float:
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen")
    with tempfile.TemporaryDirectory() as data:
        env["ORIENTATION_LAB_DATA"] = data
        started = time.perf_counter()
        result = subprocess.run([sys.executable, "-m", "app", "--demo", "--exit-after", "0"],
                                cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
        elapsed = time.perf_counter() - started
    if result.returncode != 0:
        raise SystemExit(f"the window failed:\n{result.stderr}")
    return elapsed


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="warm only")
    args = parser.parse_args()
    print(f"{os.cpu_count()} cores, Python {sys.version.split()[0]}")
    if not args.quick:
        with tempfile.TemporaryDirectory() as empty:
            ready, moving, position = demo_moving(empty)
        print(f"cold (empty kernel cache): kernels ready {ready:.1f} s, demo moving {moving:.1f} s "
              f"(at {position:.1f} s into the demo; target <= 30 s)")
        with tempfile.TemporaryDirectory() as empty:
            ready, moving, position = demo_moving(empty, one_process=True)
        print(f"cold, the stream's kernels compiled in the same process (for comparison): "
              f"demo moving {moving:.1f} s")
    demo_moving(None)                      # fills the cache if anything was missing
    ready, moving, position = demo_moving(None)
    print(f"warm: kernels ready {ready:.1f} s, demo moving {moving:.1f} s "
          f"(at {position:.1f} s into the demo)")
    print(f"warm: window shown and closed {window_up():.1f} s after starting (target <= 5 s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
