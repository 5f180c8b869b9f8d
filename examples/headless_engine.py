"""Run the engine without a window on the simulator and print its estimates as they come.

    python examples/headless_engine.py [--seconds 3]

The same engine the window runs: a source (here the simulator, streamed as phone lines at 5x
real time), the parser, the time ordering and the estimators in a background thread; the caller
polls snapshots at its own pace, as the window does at its frame rate.
"""

from __future__ import annotations

import argparse
import sys
import time

from ekf import quaternion
from app.engine.commands import SetSensorEnabled
from app.engine.live.worker import Engine
from app.stream.sources import SimulatorSource


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="how long to run (wall time)")
    args = parser.parse_args(argv)
    source = SimulatorSource(duration_s=60.0, seed=1, speed=5.0, loop=False)
    with Engine(source, comparisons=True) as engine:
        started = time.monotonic()
        switched = False
        while time.monotonic() - started < args.seconds:
            time.sleep(0.5)
            snapshot = engine.poll()
            if snapshot is None or snapshot.own_quat is None or snapshot.t_ms is None:
                continue
            yaw, pitch, roll = quaternion.to_euler(snapshot.own_quat) * 57.29577951308232
            compared = [c for c in snapshot.comparisons if c.samples]
            best = min(compared, key=lambda c: c.rmse_deg[0], default=None)
            print(f"t = {snapshot.t_ms / 1000:7.2f} s  yaw {yaw:7.1f}°  pitch {pitch:6.1f}°  "
                  f"roll {roll:6.1f}°  {len(snapshot.plot.t_est)} new estimates"
                  + (f"  best combination so far: {best.name} ({best.rmse_deg[0]:.1f}° RMSE "
                     "against PHONE)"
                     if best else ""))
            if not switched and time.monotonic() - started > args.seconds / 2:
                engine.send(SetSensorEnabled("mag", False))   # user intent, as a command
                switched = True
                print("magnetometer switched off")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
