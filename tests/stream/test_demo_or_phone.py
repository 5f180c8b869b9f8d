"""--demo keeps listening: the demo plays until a phone connects, then the phone's stream wins."""

from __future__ import annotations

import socket

from waiting import wait_for_snapshot

from app.engine.live.worker import Engine
from app.stream.sources import DemoOrPhoneSource, TcpSource, demo_source


def test_demo_plays_while_listening_and_the_phone_takes_over():
    source = DemoOrPhoneSource(demo_source(speed=20.0), TcpSource("127.0.0.1", 0))
    engine = Engine(source, comparisons=False)
    engine.start()
    try:
        snap = wait_for_snapshot(engine, lambda s: s.t_ms is not None and s.health.port, 20,
                                 "the demo to play")
        assert snap.health.port and snap.health.connection_state == "replaying"
        port = snap.health.port
        demo_t = wait_for_snapshot(engine, lambda s: s.t_ms != snap.t_ms, 20,
                                   "the demo's time to go on").t_ms
        with socket.create_connection(("127.0.0.1", port), timeout=5) as phone:
            lines = "".join(f"{5000 + 10 * k}\tACC\t0.0\t0.0\t9.81\n{5000 + 10 * k}\tGYR\t0.0\t0.0\t0.0\n"
                            for k in range(200))
            phone.sendall(lines.encode())
            snap = wait_for_snapshot(engine, lambda s: s.health.connection_state == "connected"
                                     and s.t_ms != demo_t, 20, "the phone's stream to take over")
        assert source.phone_active
        assert snap.health.connection_state == "connected"
        # The phone's samples drive the filter now (its clock continues the time base).
        assert snap.t_ms != demo_t
        assert source.demo.info()["connection_state"] in ("replaying", "finished")
    finally:
        engine.stop()
