"""The YOURS widgets on a real engine's snapshots, mounted as the report says: the panel, the
consistency view (OWN and YOURS innovations) and a third PhoneView fed snapshot.user."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from app.engine.live.worker import Engine
from app.stream.sources import LogFileSource
from app.ui.consistency import ConsistencyView
from app.ui.phone_view import PhoneView
from app.ui.user_filter_panel import UserFilterPanel

REPO = Path(__file__).resolve().parents[2]


def _log(tmp_path: Path) -> Path:
    lines = []
    for k in range(400):
        t = 1000 + 10 * k
        lines += [f"{t}\tGYR\t0.0\t0.0\t{0.5 if k > 100 else 0.0}\n",
                  f"{t}\tACC\t0.0\t0.0\t9.81\n", f"{t}\tORI\t1.0\t0.0\t0.0\t0.0\n"]
        if k % 2 == 0:
            lines.append(f"{t}\tMAG\t0.0\t20.0\t-40.0\n")
    path = tmp_path / "log.txt"
    path.write_text("".join(lines))
    return path


def test_the_widgets_draw_a_real_engine_s_snapshots(qtbot, tmp_path):
    # speed 2, not 8: live, your filter's process gets what it can answer within a budget of its
    # time (app.engine.userfilter.lane) and is thinned to what fits
    engine = Engine(LogFileSource(_log(tmp_path), speed=2), comparisons=False,
                    user_filter=str(REPO / "examples" / "course_ekf.py"))
    panel = UserFilterPanel(engine.send)
    view = ConsistencyView(engine.send)
    yours = PhoneView("YOURS", use_gl=False)
    for widget in (panel, view, yours):
        qtbot.addWidget(widget)
    view.show()                                   # asks the engine for our innovations
    shown = []

    def show_the_latest_until_finished() -> bool:
        snapshot = engine.poll()
        if snapshot is None:
            return False
        shown.append(snapshot)
        view.apply_snapshot(snapshot)
        panel.update_status(snapshot.user)
        if snapshot.user is not None:
            yours.set_orientation(snapshot.user.quat, snapshot.user.cov)
        user = snapshot.user       # YOURS answers later than OWN: every row answered
        return (snapshot.health.connection_state == "finished" and user is not None
                and user.state == "running" and user.backlog_rows == 0)
    with engine:
        qtbot.waitUntil(show_the_latest_until_finished, timeout=30_000)
    snapshot = shown[-1]
    assert snapshot.user.state == "running"
    assert "course_ekf.py" in panel.file_label.text() and "running" in panel.state_label.text()
    assert view.series[(0, 0)].size > 200 and view.series[(1, 0)].size > 200   # OWN, YOURS acc
    view.source_combo.setCurrentIndex(1)
    view.refresh()
    assert view.stats["k"] == 3 and np.isfinite(view.stats["inside"])
    assert yours.quat is not None and "q = (" in yours.placeholder.text()
    assert yours.attitude_std_deg() is not None            # drawn from the filter's P
