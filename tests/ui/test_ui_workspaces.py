"""The window's other workspaces and YOURS, driven as a user would (pytest-qt, offscreen): the
Calibrate, Tune and Consistency tabs are mounted and fed; settings changed anywhere reach the
engine once and show everywhere; the Tune workspace re-filters its session at each change with
a ghost to compare; your filter gets a 3D view, dotted curves, a legend toggle and a panel, and
a re-run's history replaces its curves."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from PySide6 import QtCore, QtWidgets

import ekf
from app.engine.commands import SetConsistencyEnabled, SetSettings, UnloadUserFilter
from app.engine.snapshot import UserHistory
from app.stream.demo import write_session
from ekf.simulate import simulate
from ui_helpers import make_snapshot, make_user_snapshot, user_status


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("workspaces") / "sim.txt"
    write_session(simulate(duration_s=30.0, seed=3), path)
    return path


def test_the_workspaces_are_tabs_of_the_window(make_window, fake_engine):
    window = make_window(fake_engine)
    titles = [window.workspaces.tabText(i) for i in range(window.workspaces.count())]
    assert titles == ["Live / Replay", "Calibrate", "Tune", "Consistency"]
    assert window.workspaces.tabBar().isVisibleTo(window)
    assert window.user_dock.windowTitle() == "Your filter"


def test_yours_gets_a_view_dotted_curves_and_a_legend_toggle_while_loaded(make_window,
                                                                         fake_engine):
    window = make_window(fake_engine)
    window.show()
    plots = window.plots
    assert not window.user_view.isVisibleTo(window)
    assert plots.groups["orientation"].toggles["YOURS"].isHidden()
    for seq in range(1, 4):
        window.apply_snapshot(make_user_snapshot(seq, 0.5 * (seq - 1)))
    assert window.user_view.isVisibleTo(window)
    assert window.user_view.quat is not None
    assert not plots.groups["orientation"].toggles["YOURS"].isHidden()
    assert not plots.groups["error"].toggles["YOURS"].isHidden()
    assert plots.buffers["user"].size == 150 and plots.buffers["user_error"].size == 150
    plots.set_current_group("orientation")
    plots.refresh()
    yours = [(spec, curve) for spec, curve in plots.curves if spec.stream == "user"]
    assert len(yours) == 3 and all(spec.dotted for spec, _ in yours)
    assert all(len(curve.xData) > 0 for _, curve in yours)
    # Hiding YOURS' errors leaves OWN's; hiding "heading" hides both headings.
    plots.set_shown("error", "YOURS", False)
    visible = {spec.label: curve.isVisible() for spec, curve in plots.curves
               if spec.plot == "error"}
    assert visible == {"total": True, "heading": True, "inclination": True,
                       "YOURS total": False, "YOURS heading": False, "YOURS inclination": False}
    plots.set_shown("error", "YOURS", True)
    plots.set_shown("error", "heading", False)
    assert not any(curve.isVisible() for spec, curve in plots.curves
                   if spec.plot == "error" and "heading" in spec.label)
    assert all(curve.isVisible() for spec, curve in plots.curves
               if spec.plot == "error" and "total" in spec.label)
    # Unloaded: the view, the toggles and YOURS' samples go.
    window.apply_snapshot(make_snapshot(4, 1.5))
    assert not window.user_view.isVisibleTo(window)
    assert plots.buffers["user"].size == 0
    assert plots.groups["error"].toggles["YOURS"].isHidden()


def test_the_cursor_reads_yours_only_when_it_is_loaded(make_window, fake_engine):
    window = make_window(fake_engine)
    plots = window.plots
    window.apply_snapshot(make_snapshot(1, 0.0))
    plots.set_current_group("orientation")
    plots.set_cursor_visible(True)
    plots.set_cursor_time(0.2)
    assert "YOURS" not in plots.readout_label.text()
    window.apply_snapshot(make_user_snapshot(2, 0.5))
    plots.set_cursor_time(0.6)
    assert "YOURS" in plots.readout_label.text()
    values = plots.cursor_values()
    assert values["YOURS yaw"] == pytest.approx(values["OWN yaw"] + 2.0, abs=1e-9)


def test_a_rerun_history_replaces_yours_curves(make_window, fake_engine):
    window = make_window(fake_engine)
    for seq in range(1, 3):
        window.apply_snapshot(make_user_snapshot(seq, 0.5 * (seq - 1)))
    t_ms = np.arange(0, 1000, 10, dtype=np.int64)
    history = UserHistory(t_ms, np.full((len(t_ms), 3), 7.0), t_ms + 3,
                          np.full((len(t_ms), 3), 0.25))
    snapshot = make_user_snapshot(3, 1.0, user_status(generation=2, history=history))
    window.apply_snapshot(snapshot)
    buffer = window.plots.buffers["user"]
    # the history (0..0.99 s) and then only the live rows after it (1.0 s on)
    assert buffer.t[0] == 0.0 and np.all(np.diff(buffer.t) > 0)
    assert np.all(buffer.values[buffer.t < 0.995] == 7.0)
    assert buffer.size == len(t_ms) + 50
    # the same history object again is not drawn twice
    window.apply_snapshot(make_user_snapshot(4, 1.5, user_status(generation=2, history=history)))
    assert buffer.size == len(t_ms) + 100


def test_unload_from_the_file_menu_tells_the_engine(make_window, fake_engine):
    window = make_window(fake_engine)
    window.unload_filter_action.trigger()
    assert fake_engine.commands_of(UnloadUserFilter)


def test_settings_from_a_panel_reach_the_engine_once_and_show_everywhere(make_window,
                                                                         fake_engine):
    window = make_window(fake_engine)
    panel = window.tune.settings_panel
    assert panel.edit("acc_gate", "0.7")
    sent = fake_engine.commands_of(SetSettings)
    assert len(sent) == 1 and sent[0].settings.acc_gate == pytest.approx(0.7)
    # What the filter runs with comes from the engine, not from what was sent.
    assert window.filter_settings is ekf.PRESETS["default"]
    window.apply_snapshot(make_snapshot(1, 0.0, settings=sent[0].settings))
    assert window.filter_settings is sent[0].settings and panel.settings is sent[0].settings
    assert len(fake_engine.commands_of(SetSettings)) == 1
    # Settings the engine took from elsewhere (a session's timeline) show in the panel.
    other = dataclasses.replace(ekf.PRESETS["course"], acc_gate=1.5)
    window.apply_snapshot(make_snapshot(2, 0.5, settings=other))
    assert window.filter_settings is other
    assert panel.settings == other
    assert len(fake_engine.commands_of(SetSettings)) == 1


def test_calibration_apply_starts_from_the_running_settings(make_window, fake_engine, sim_log):
    window = make_window(fake_engine)
    running = dataclasses.replace(ekf.PRESETS["default"], acc_gate=1.25)
    window.apply_snapshot(make_snapshot(1, 0.0, settings=running))
    assert window.calibration.analyse_log(sim_log)
    applied = window.calibration.apply()
    assert applied is not None and applied.acc_gate == pytest.approx(1.25)
    sent = fake_engine.commands_of(SetSettings)
    assert sent[-1].source == "calibration" and sent[-1].settings is applied
    window.apply_snapshot(make_snapshot(2, 0.5, settings=applied))     # the engine runs them
    assert window.filter_settings is applied
    assert window.tune.settings_panel.settings == applied


@pytest.mark.filterwarnings("ignore:Precision loss")    # the fake samples are smooth sines
def test_the_rest_collection_is_fed_by_the_window(make_window, fake_engine):
    window = make_window(fake_engine)
    rest = window.calibration.rest
    rest.start(duration_s=60.0)
    for seq in range(1, 4):
        window.apply_snapshot(make_snapshot(seq, 0.5 * (seq - 1)))
    assert rest.collector is not None and rest.collector.elapsed_s > 0.9
    rest.stop()


def test_the_consistency_view_asks_for_innovations_only_while_shown(make_window, fake_engine):
    window = make_window(fake_engine)
    window.show()
    assert not fake_engine.commands_of(SetConsistencyEnabled)
    window.workspaces.setCurrentWidget(window.consistency)
    assert [c.enabled for c in fake_engine.commands_of(SetConsistencyEnabled)] == [True]
    window.workspaces.setCurrentIndex(0)
    assert [c.enabled for c in fake_engine.commands_of(SetConsistencyEnabled)] == [True, False]


def test_tune_refilters_the_session_at_each_change_with_a_ghost(qtbot, make_window, fake_engine,
                                                                 sim_log):
    window = make_window(fake_engine)
    tune = window.tune
    assert tune.refilterer is None and "No session" in tune.ab_plots.message.text()
    assert tune.set_log(sim_log)
    assert "sim.txt" in tune.log_label.text()
    qtbot.waitUntil(lambda: tune.refilterer.current is not None, timeout=20_000)
    first = tune.refilterer.current
    assert first.summary is not None and first.summary.samples > 100
    tune.ab_view.keep_button.click()
    assert tune.refilterer.ghost is not None
    changed = dataclasses.replace(window.filter_settings,
                                  mag_noise_cov=[[20.0, 0, 0], [0, 20.0, 0], [0, 0, 20.0]])
    window.send(SetSettings(changed, source="panel"))
    assert tune.refilterer.wait(10.0) and tune.refilterer.current is first   # not yet run
    window.apply_snapshot(make_snapshot(1, 0.0, settings=changed))   # what the engine runs
    qtbot.waitUntil(lambda: tune.refilterer.current is not first, timeout=20_000)
    qtbot.waitUntil(lambda: tune.ab_view.table.rowCount() == 3, timeout=5000)
    assert [tune.ab_view.table.item(r, 0).text() for r in range(3)] == \
        ["current", "ghost", "difference"]
    difference = tune.difference_deg()
    assert np.nanmax(difference) > 0.01        # the runs differ somewhere
    curve = tune.ab_plots.curves[("total", "ghost")]
    assert curve.xData is not None and len(curve.xData) == len(first.errors.t_ms)
    assert tune.tuning_panel is not None       # the session has ORI: auto-tune offered
    # the same settings again: no new run
    runs = tune.refilterer.runs
    window.send(SetSettings(changed, source="panel"))
    window.apply_snapshot(make_snapshot(2, 0.5, settings=changed))
    assert tune.refilterer.wait(10.0) and tune.refilterer.runs == runs


def test_tune_difference_of_two_identical_runs_draws_along_zero(qtbot, make_window,
                                                                 fake_engine, sim_log):
    """Issue 51: for two runs that agree the Δ plot blew rounding noise up to its height (an
    axis of 3e-06°)."""
    window = make_window(fake_engine)
    tune = window.tune
    window.show()
    window.workspaces.setCurrentWidget(tune)
    assert tune.set_log(sim_log)
    qtbot.waitUntil(lambda: tune.refilterer.current is not None, timeout=20_000)
    first = tune.refilterer.current
    tune.ab_view.keep_button.click()
    # a setting that acts only past a bound this session never reaches: the same estimates
    same = dataclasses.replace(window.filter_settings, mag_reject_noise_scale=20.0)
    window.send(SetSettings(same, source="panel"))
    window.apply_snapshot(make_snapshot(1, 0.0, settings=same))      # what the engine runs
    qtbot.waitUntil(lambda: tune.refilterer.current is not first, timeout=20_000)
    qtbot.waitUntil(lambda: tune.ab_view.table.rowCount() == 3, timeout=5000)
    tune.redraw()
    assert np.nanmax(tune.difference_deg()) < 1e-3
    view_box = tune.ab_plots.plots["difference"].getViewBox()
    for _ in range(3):                          # the plot lays out and ranges as it paints
        QtWidgets.QApplication.processEvents()
    view_box.prepareForPaint()
    low, high = view_box.viewRange()[1]
    assert low == pytest.approx(0.0, abs=1e-9) and high >= 0.1


def test_tune_says_why_when_a_log_cannot_be_used(make_window, fake_engine, tmp_path):
    window = make_window(fake_engine)
    bad = tmp_path / "nothing.txt"
    bad.write_text("this is not a log\n")
    assert not window.tune.set_log(bad)
    assert "nothing.txt" in window.tune.log_label.text()
    assert not window.tune.set_log(tmp_path / "missing.txt")
    assert "missing.txt" in window.tune.log_label.text()


def test_tune_loads_the_replayed_session_when_first_shown(qtbot, make_window, fake_engine,
                                                          sim_log, settings_file):
    from app.ui.main_window import MainWindow
    settings = QtCore.QSettings(str(settings_file), QtCore.QSettings.Format.IniFormat)
    window = MainWindow(fake_engine, settings=settings, use_gl=False, tune_log=sim_log)
    qtbot.addWidget(window)
    try:
        window.show()
        assert window.tune.prepared is None          # not read until the tab is shown
        window.workspaces.setCurrentWidget(window.tune)
        qtbot.waitUntil(lambda: window.tune.prepared is not None, timeout=10_000)
        qtbot.waitUntil(lambda: window.tune.refilterer.current is not None, timeout=20_000)
    finally:
        window.shutdown()
    assert window.tune.refilterer is None            # stopped with the window


def test_tune_offers_the_smoother_against_the_forward_ghost(qtbot, make_window, fake_engine,
                                                            sim_log):
    from app.engine.config import open_log
    from app.engine.offline.filtering import filter_log
    window = make_window(fake_engine)
    tune = window.tune
    assert tune.set_log(sim_log)
    qtbot.waitUntil(lambda: tune.refilterer.current is not None, timeout=20_000)
    forward = tune.refilterer.current
    tune.ab_view.keep_button.click()
    tune.smooth_checkbox.click()
    qtbot.waitUntil(lambda: tune.refilterer.current is not forward, timeout=20_000)
    smoothed = tune.refilterer.current
    rows = smoothed.rows.select(smoothed.rows.has_sample)
    expected = filter_log(open_log(sim_log), smooth=True)
    np.testing.assert_allclose(rows.quat, expected.quat, atol=1e-12)   # the command's smoother
    assert smoothed.summary.total_rmse_deg < forward.summary.total_rmse_deg
    assert np.nanmax(tune.difference_deg()) > 0.01
    tune.smooth_checkbox.click()                                       # back to forward
    qtbot.waitUntil(lambda: tune.refilterer.current is not smoothed, timeout=20_000)
    np.testing.assert_array_equal(tune.refilterer.current.rows.quat, forward.rows.quat)
