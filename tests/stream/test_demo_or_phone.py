"""--demo keeps listening: the demo plays until a phone connects, then the phone's stream wins."""

from __future__ import annotations

import socket
import time

from app.engine.worker import Engine
from app.stream.sources import DemoOrPhoneSource, TcpSource, demo_source


def test_demo_plays_while_listening_and_the_phone_takes_over():
    source = DemoOrPhoneSource(demo_source(speed=20.0), TcpSource("127.0.0.1", 0))
    engine = Engine(source, comparisons=False)
    engine.start()
    try:
        deadline = time.time() + 20
        snap = None
        while time.time() < deadline:
            snap = engine.snapshot_now()
            if snap.t_ms is not None and snap.health.port:
                break
            time.sleep(0.05)
        assert snap is not None and snap.t_ms is not None, "the demo did not play"
        assert snap.health.port and snap.health.connection_state == "replaying"
        port = snap.health.port
        time.sleep(0.3)
        demo_t = engine.snapshot_now().t_ms
        with socket.create_connection(("127.0.0.1", port), timeout=5) as phone:
            lines = "".join(f"{5000 + 10 * k}\tACC\t0.0\t0.0\t9.81\n{5000 + 10 * k}\tGYR\t0.0\t0.0\t0.0\n"
                            for k in range(200))
            phone.sendall(lines.encode())
            deadline = time.time() + 20
            while time.time() < deadline:
                snap = engine.snapshot_now()
                if snap.health.connection_state == "connected" and snap.t_ms != demo_t:
                    break
                time.sleep(0.05)
        assert source.phone_active
        assert snap.health.connection_state == "connected"
        # The phone's samples drive the filter now (its clock continues the time base).
        assert snap.t_ms != demo_t
        assert source.demo.info()["connection_state"] in ("replaying", "finished")
    finally:
        engine.stop()
