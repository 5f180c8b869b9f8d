"""Stream a simulated session to the server like the phone does, and watch it arrive.

    python examples/stream_to_server.py [--port 0] [--seconds 10]

Starts an engine listening on 127.0.0.1 (what `orientation-lab serve` and the window do), then
connects the phone emulator (what `orientation-lab send` does) and sends a simulated session as
fast as possible. Point a real phone's Sensor Fusion app at this PC instead of the emulator and the
same engine receives it.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from ekf.simulate import simulate
from app.engine.live.worker import Engine
from app.stream.demo import write_session
from app.stream.emulator import send_log
from app.stream.sources import TcpSource


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, default=0, help="listen port (0: any free port)")
    parser.add_argument("--seconds", type=float, default=10.0, help="length of the session")
    args = parser.parse_args(argv)
    source = TcpSource("127.0.0.1", args.port)
    with tempfile.TemporaryDirectory() as folder, Engine(source, comparisons=False) as engine:
        log = write_session(simulate(duration_s=args.seconds, seed=2), Path(folder) / "s.txt")
        print(f"listening on 127.0.0.1:{source.port}")
        sent = send_log(log, "127.0.0.1", source.port, speed=0.0)
        print(f"the emulator sent {sent} lines")
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            snapshot = engine.snapshot_now()
            health = snapshot.health
            if health.connection_state == "disconnected" and health.lines_total >= sent:
                break
            time.sleep(0.05)
        print(f"the engine received {health.lines_total} lines ({health.damaged} damaged), "
              f"rates {health.rates_hz} Hz, last estimate at t = {snapshot.t_ms} ms")
        return 0 if health.lines_total == sent else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
