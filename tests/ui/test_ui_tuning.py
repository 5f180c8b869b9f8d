"""The tuning panel and the A/B view with pytest-qt on a simulated log: a search runs in its
thread, reports progress, can be cancelled, and its result is applied or kept as a profile."""

from __future__ import annotations

import pytest
from PySide6 import QtGui

import ekf
from ekf.simulate import simulate
from app.engine.commands import SetSettings
from app.engine.tuning.profiles import ProfileStore
from app.engine.offline.refilter import Refilterer
from app.stream.demo import write_session
from app.stream.logfile import LogData
from app.engine.config import open_log
from app.ui.tuning import ABCompareView, TuningPanel


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    path = tmp_path_factory.mktemp("tune") / "sim.txt"
    write_session(simulate(duration_s=40.0, seed=7), path)
    return open_log(path)


@pytest.fixture
def panel(qtbot, prepared, tmp_path):
    sent = []
    widget = TuningPanel(prepared, sent.append, settings=lambda: ekf.PRESETS["course"],
                         store=ProfileStore(tmp_path / "profiles"))
    qtbot.addWidget(widget)
    widget.sent = sent
    return widget


def test_ranges_default_to_the_two_halves_and_parameters_show_their_ranges(panel, prepared):
    assert panel.tune_end.value() == pytest.approx(prepared.duration_s / 2, abs=0.1)
    assert panel.check_start.value() == panel.tune_end.value()
    chosen = [p.name for p in panel.chosen_parameters()]
    assert chosen[:3] == ["gyr_noise_cov", "acc_noise_cov", "mag_noise_cov"]
    assert panel.parameters.item(0, 1).text() == "1e-06"


def test_a_search_reports_progress_and_before_after_figures(panel, qtbot):
    panel.max_evals.setValue(12)
    with qtbot.waitSignal(panel.finished, timeout=60_000):
        assert panel.start()
        assert not panel.start_button.isEnabled() and panel.cancel_button.isEnabled()
    qtbot.waitUntil(lambda: panel.result is not None, timeout=5000)
    result = panel.result
    assert result.evaluations <= 12 and panel.progress.value() == 100
    assert panel.figures.rowCount() == 4
    assert float(panel.figures.item(1, 1).text()) <= float(panel.figures.item(0, 1).text())
    assert panel.parameters.item(0, 4).text()          # "after" shown
    # what the search did reads as information, not as an error (issue 51)
    assert panel.summary.text() == f"{result.evaluations} runs in {result.elapsed_s:.1f} s"
    assert "runs in" not in panel.warning.text()
    assert "b00020" not in panel.summary.styleSheet()
    red = QtGui.QColor("#b00020")
    assert panel.summary.palette().color(QtGui.QPalette.ColorRole.WindowText) != red
    panel.apply_button.click()
    assert isinstance(panel.sent[-1], SetSettings) and panel.sent[-1].source == "tuned"
    profile = panel.keep_as_profile()
    assert profile.name == "tuned" and panel.keep_as_profile().name == "tuned (2)"
    assert panel.store.load("tuned").tuning["evaluations"] == result.evaluations


def test_cancel_stops_with_the_best_so_far(panel, qtbot):
    panel.max_evals.setValue(5000)
    with qtbot.waitSignal(panel.finished, timeout=60_000):
        panel.start()
        qtbot.waitUntil(lambda: panel.job.latest is not None, timeout=30_000)
        panel.cancel_button.click()
    qtbot.waitUntil(lambda: panel.result is not None, timeout=5000)
    assert panel.result.cancelled and panel.result.evaluations < 5000
    assert "cancelled" in panel.summary.text()


def test_a_session_without_a_gyroscope_offers_none_of_its_settings(qtbot, prepared, tmp_path):
    """Issue 51: auto-tune searched gyr_noise_cov on a log without a gyroscope."""
    from PySide6 import QtCore
    keep = prepared.tag != 0                                    # GYR's code
    no_gyro = LogData(prepared.path, prepared.t_ms[keep], prepared.tag[keep],
                      prepared.values[keep])
    panel = TuningPanel(no_gyro, lambda command: None, store=ProfileStore(tmp_path / "p"))
    qtbot.addWidget(panel)
    names = [panel.parameters.verticalHeaderItem(r).text()
             for r in range(panel.parameters.rowCount())]
    row = names.index("gyr_noise_cov")
    check = panel.parameters.item(row, 0)
    assert check.checkState() == QtCore.Qt.CheckState.Unchecked
    assert not check.flags() & QtCore.Qt.ItemFlag.ItemIsEnabled
    assert "no gyroscope in this session" in check.toolTip()
    chosen = [p.name for p in panel.chosen_parameters()]
    assert "gyr_noise_cov" not in chosen and "acc_noise_cov" in chosen
    assert not any(name.startswith(("gyr_", "gyro_")) for name in chosen)


def test_no_parameter_chosen_is_refused(panel):
    from PySide6 import QtCore
    for r in range(panel.parameters.rowCount()):
        panel.parameters.item(r, 0).setCheckState(QtCore.Qt.CheckState.Unchecked)
    assert not panel.start()
    assert "at least one" in panel.warning.text()


def test_ab_view_shows_current_ghost_and_difference(qtbot, prepared):
    seen = []
    refilterer = Refilterer(prepared, on_result=seen.append)
    view = ABCompareView(refilterer)       # hooks itself on after the callback already there
    qtbot.addWidget(view)
    try:
        refilterer.submit(ekf.PRESETS["course"])
        qtbot.waitUntil(lambda: view.table.rowCount() == 1, timeout=20_000)
        view.keep_button.click()
        refilterer.submit(None)
        qtbot.waitUntil(lambda: refilterer.runs == 2 and view.table.rowCount() == 3,
                        timeout=20_000)
        labels = [view.table.item(r, 0).text() for r in range(3)]
        assert labels == ["current", "ghost", "difference"]
        assert "ms" in view.timing.text()
        view.clear_button.click()
        assert view.table.rowCount() == 1
        assert len(seen) == 2
    finally:
        refilterer.close()
