"""The window on the real engine, replaying a small simulated log: snapshots arrive, the plots
fill, and a sensor switch reaches the filter (the engine's status and the light follow)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PySide6 import QtCore


@pytest.fixture
def small_log(tmp_path: Path) -> Path:
    from ekf.simulate import simulate

    from app.stream.protocol import Sample, format_line
    session = simulate(duration_s=20.0, seed=3)
    path = tmp_path / "small.txt"
    with open(path, "w", newline="\n") as file:
        for t_ms, tag, values in session.to_rows():
            file.write(format_line(Sample(int(t_ms), tag, tuple(float(v) for v in values))) + "\n")
    return path


def test_window_on_a_real_engine_replay(make_window, small_log, qtbot):
    from app.engine.live.worker import Engine
    from app.stream.sources import LogFileSource

    engine = Engine(LogFileSource(small_log, speed=2.0, loop=True))
    engine.start()
    window = make_window(engine)
    try:
        window.show()
        qtbot.waitUntil(lambda: window.plots.buffers["gyr"].size > 100, timeout=60000)
        snapshot = window.last_snapshot
        assert snapshot.health.connection_state == "replaying"
        assert window.transport.play_button.isEnabled()
        assert window.own_view.quat is not None and window.phone_view.quat is not None
        assert window.lights.states()["acc"] in ("ok", "acc disturbed")
        qtbot.waitUntil(lambda: len(window.comparison.rows()) == 7, timeout=15000)

        window.controls.sensor_checkboxes["acc"].click()
        qtbot.waitUntil(
            lambda: window.last_snapshot.status.sensors_enabled.get("acc") is False, timeout=15000)
        qtbot.waitUntil(lambda: window.lights.states()["acc"] == "off", timeout=5000)
        assert not window.controls.sensor_checkboxes["acc"].isChecked()

        # Pause the plots: the view stays, the samples keep coming (into the rolling buffers;
        # an indexed replay draws its whole session instead).
        window.plots.set_paused(True)
        frozen = window.plots.x_range()
        size = window.plots.live_buffers["gyr"].appended
        qtbot.waitUntil(lambda: window.plots.live_buffers["gyr"].appended > size + 50,
                        timeout=15000)
        assert window.plots.x_range() == pytest.approx(frozen)
        euler = window.plots.buffers["own"].values
        assert np.isfinite(euler).all() and np.abs(euler).max() <= 180.0
        assert window.plots.buffers["error"].size > 100
    finally:
        window.close()
    assert not engine.running
    assert not window.timer.isActive()
    QtCore.QCoreApplication.processEvents()


def test_a_replay_that_ends_offers_play_and_is_drawn_whole(make_window, small_log, qtbot):
    from app.engine.live.worker import Engine
    from app.stream.sources import LogFileSource

    engine = Engine(LogFileSource(small_log, speed=0.0), comparisons=False)
    engine.start()
    window = make_window(engine)
    try:
        window.show()
        qtbot.waitUntil(lambda: window.last_snapshot is not None and
                        (window.last_snapshot.replay or {}).get("finished"), timeout=60000)
        assert window.transport.play_button.text() == "Play"         # not "Pause" at the end
        qtbot.waitUntil(lambda: window.plots.session is not None, timeout=60000)
        assert window.plots.buffers["gyr"].last_time() == pytest.approx(20.0, abs=0.05)
        assert window.transport.position_label.text().endswith("/ 0:20.0")
    finally:
        window.close()
