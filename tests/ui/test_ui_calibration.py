"""The calibration workspace driven with pytest-qt by crafted snapshots: a simulated rest stream
through Start, the warnings on a moving one, the magnetometer cloud filling a sphere, Apply and
profiles. The 3D cloud needs OpenGL (marked gl)."""

from __future__ import annotations

import numpy as np
import pytest

import ekf
from ekf.simulate import DEFAULT_NOISE_STD, simulate
from app.engine.commands import SetSettings
from app.engine.tuning.profiles import ProfileStore
from app.engine.snapshot import PlotChunk, Snapshot
from ekf.calibration import UNITS
from app.stream.demo import write_session
from app.ui.calibration import CalibrationWorkspace

BIAS = (0.01, -0.02, 0.005)


def snapshots(session, per_snapshot_s: float = 0.25):
    """The session's samples as the engine's snapshots would carry them, a frame at a time."""
    t = {name: getattr(session, name).t_ms / 1000.0 for name in ("acc", "gyr", "mag")}
    start, end = min(v[0] for v in t.values()), max(v[-1] for v in t.values())
    seq = 0
    for lo in np.arange(start, end + per_snapshot_s, per_snapshot_s):
        parts = {}
        for name in ("acc", "gyr", "mag"):
            chosen = (t[name] >= lo) & (t[name] < lo + per_snapshot_s)
            parts["t_" + name] = t[name][chosen]
            parts[name] = getattr(session, name).values[chosen]
        seq += 1
        yield Snapshot(seq=seq, plot=PlotChunk(**parts))


@pytest.fixture
def workspace(qtbot, tmp_path):
    sent = []
    widget = CalibrationWorkspace(sent.append, settings=lambda: ekf.PRESETS["course"],
                                  store=ProfileStore(tmp_path / "profiles"))
    qtbot.addWidget(widget)
    widget.sent = sent
    return widget


def test_start_collects_ten_seconds_and_finds_the_noise_and_bias(workspace):
    rest = simulate(duration_s=15.0, script="rest", seed=11, gyro_bias=BIAS)
    workspace.rest.start()
    assert workspace.rest.duration.value() == 10.0
    for snapshot in snapshots(rest):
        workspace.feed(snapshot)
    assert not workspace.rest.collecting and workspace.rest.progress.value() == 100
    result = workspace.rest.result
    assert 9.9 <= result.analysis.duration_s <= 10.0
    stats = result.analysis.result
    np.testing.assert_allclose(stats.gyr.std, DEFAULT_NOISE_STD["gyr"], rtol=0.1)
    np.testing.assert_allclose(stats.gyr_bias, BIAS, rtol=0.1)
    assert workspace.rest.table.rowCount() == 9
    assert workspace.rest.table.item(0, 0).text().startswith("acc [")
    assert workspace.rest.warnings.text() == ""
    assert "Gyroscope" in workspace.rest.series_plots[1].titleLabel.text
    assert workspace.allan.allan is not None          # the Allan tab follows the rest tab
    assert "angle random walk" in workspace.allan.summary.text()


def test_a_moving_stream_is_warned_about(workspace):
    moving = simulate(duration_s=12.0, seed=3)
    workspace.rest.start(8.0)
    for snapshot in snapshots(moving):
        workspace.feed(snapshot)
    text = workspace.rest.warnings.text()
    assert "moved" in text


def test_stop_early_analyses_what_came_and_warns_of_too_few(workspace):
    rest = simulate(duration_s=1.0, script="rest", seed=2)
    workspace.rest.start()
    for snapshot in snapshots(rest):
        workspace.feed(snapshot)
    workspace.rest.start_button.click()               # Stop
    assert "only" in workspace.rest.warnings.text()   # too few samples


def _turning_readings(n, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.standard_normal((n, 3))
    return 45.0 * d / np.linalg.norm(d, axis=1, keepdims=True) + [20.0, -30.0, 150.0]


def test_the_magnetometer_cloud_fills_a_sphere_live(workspace):
    readings = _turning_readings(1200)
    workspace.mag.start_button.click()
    coverages = []
    for k in range(0, len(readings), 60):
        chunk = PlotChunk(t_mag=np.arange(60) * 0.02 + k, mag=readings[k:k + 60])
        workspace.feed(Snapshot(seq=k, plot=chunk))
        coverages.append(workspace.mag.coverage_bar.value())
    assert coverages == sorted(coverages) and coverages[-1] == 100
    result = workspace.mag.result
    np.testing.assert_allclose(result.offset, [20, -30, 150], atol=0.5)
    assert "spread" in workspace.mag.summary.text()
    assert len(workspace.mag.projection_plots[0].items) >= 2     # raw and corrected clouds


def test_apply_sends_the_settings_with_the_profile_and_profiles_round_trip(workspace):
    rest = simulate(duration_s=12.0, script="rest", seed=11, gyro_bias=BIAS)
    workspace.rest.start()
    for snapshot in snapshots(rest):
        workspace.feed(snapshot)
    workspace.mag.start_button.click()
    workspace.feed(Snapshot(plot=PlotChunk(t_mag=np.arange(800) * 0.02,
                                           mag=_turning_readings(800))))
    workspace.mag.start_button.click()                 # Stop: a final fit
    workspace.name.setText("Test phone")
    settings = workspace.apply()
    command = workspace.sent[-1]
    assert isinstance(command, SetSettings) and command.source == "calibration"
    assert command.calibration["name"] == "Test phone"
    np.testing.assert_allclose(settings.gyr_bias, BIAS, rtol=0.1)
    np.testing.assert_allclose(settings.mag_hard_iron, [20, -30, 150], atol=0.5)
    # onto the course model the measured noise goes too
    assert settings.acc_noise_cov[2][2] == pytest.approx(DEFAULT_NOISE_STD["acc"][2] ** 2,
                                                         rel=0.25)
    assert workspace.save_profile() is not None
    assert workspace.profiles.findText("Test phone") >= 0
    other = CalibrationWorkspace(workspace.sent.append, store=workspace.store)
    profile = other.load_profile("Test phone")
    assert profile.rest and profile.mag
    again = other.apply()
    assert again.mag_hard_iron == settings.mag_hard_iron and again.g == settings.g
    other.deleteLater()


def test_apply_without_anything_says_so(workspace):
    assert workspace.apply() is None
    assert "nothing to apply" in workspace.message.text()
    assert workspace.load_profile("nobody") is None


def test_a_stretch_of_a_log(workspace, realphone_dir):
    assert workspace.analyse_log(realphone_dir / "tsrt14_lab2_calibration.txt")
    stats = workspace.rest.result.analysis.result
    assert stats.g == pytest.approx(9.0, abs=0.05)
    assert workspace.rest.result.how == "longest still interval"
    assert not workspace.analyse_log(realphone_dir / "no_such.txt")


@pytest.mark.gl
def test_the_3d_cloud_with_opengl(qtbot, tmp_path):
    widget = CalibrationWorkspace(lambda c: None, store=ProfileStore(tmp_path), use_gl=True)
    qtbot.addWidget(widget)
    widget.show()
    widget.mag.start_button.click()
    widget.feed(Snapshot(plot=PlotChunk(t_mag=np.arange(500) * 0.02,
                                        mag=_turning_readings(500))))
    assert widget.mag.view3d is not None
    assert widget.mag.scatter3d.pos.shape == (500, 3)


def test_a_still_log_is_no_magnetometer_fit_and_the_tab_has_its_own_log(workspace, tmp_path,
                                                                        realphone_dir):
    assert workspace.analyse_log(realphone_dir / "tsrt14_lab2_calibration.txt")
    assert workspace.mag.result is None and workspace.mag.coverage_bar.value() <= 0
    assert not workspace.analyse_mag_log(realphone_dir / "tsrt14_lab2_calibration.txt")
    assert "hardly turned" in workspace.mag.summary.text()
    turning = tmp_path / "turning.txt"
    readings = _turning_readings(800)
    turning.write_text("".join(f"{1000 + 20 * k}\tMAG\t{x}\t{y}\t{z}\n"
                               f"{1000 + 20 * k}\tACC\t0\t0\t9.81\n"
                               for k, (x, y, z) in enumerate(readings)))
    assert workspace.analyse_mag_log(turning)
    np.testing.assert_allclose(workspace.mag.result.offset, [20, -30, 150], atol=0.5)
    assert workspace.mag.from_log_button.text() == "From log…"


def test_apply_warns_of_an_earth_field_outside_25_to_65_ut(workspace):
    rest = simulate(duration_s=12.0, script="rest", seed=11, gyro_bias=BIAS)
    workspace.rest.start()
    for snapshot in snapshots(rest):
        workspace.feed(snapshot)
    workspace.loaded = None
    profile = workspace.profile()
    profile.rest["mag"]["mean"] = [0.0, 70.0, -450.0]        # a rest beside iron
    workspace.loaded = profile
    workspace.rest.result = None
    workspace.apply()
    assert "warning: m0 is" in workspace.message.text()
    assert "not the Earth's 25-65 uT" in workspace.message.text()


def _no_data_texts(workspace):
    return ([t.text() for t in workspace.rest.no_data if t.isVisible()],
            workspace.allan.no_data.text() if workspace.allan.no_data.isVisible() else "",
            [t.text() for t in workspace.mag.no_data if t.isVisible()])


def test_empty_plots_say_no_data_until_a_result_comes(workspace):
    workspace.show()
    rest, allan, mag = _no_data_texts(workspace)
    assert rest == ["no data"] * 15 and allan.startswith("no data") and mag == ["no readings"] * 3
    for snapshot in snapshots(simulate(duration_s=12.0, script="rest", seed=11)):
        workspace.feed(snapshot)
    workspace.rest.start()
    for snapshot in snapshots(simulate(duration_s=12.0, script="rest", seed=11)):
        workspace.feed(snapshot)
    readings = _turning_readings(600)
    workspace.mag.start_button.click()
    for k in range(0, len(readings), 60):
        workspace.feed(Snapshot(seq=k, plot=PlotChunk(t_mag=np.arange(60) * 0.02 + k,
                                                      mag=readings[k:k + 60])))
    assert _no_data_texts(workspace) == ([], "", [])
    workspace.mag.clear_button.click()
    assert _no_data_texts(workspace)[2] == ["no readings"] * 3


def test_the_allan_plots_log_tick_labels_do_not_overlap_at_1280(workspace, qtbot):
    workspace.resize(880, 520)              # the workspace's share of a 1280x720 window
    workspace.show()
    workspace.rest.start()
    for snapshot in snapshots(simulate(duration_s=14.0, script="rest", seed=4)):
        workspace.feed(snapshot)
    workspace.tabs.setCurrentWidget(workspace.allan)
    qtbot.waitUntil(lambda: workspace.allan.plot_widget.isVisible())
    for name in ("bottom", "left"):
        axis = workspace.allan.plot.getAxis(name)
        low, high = axis.range
        horizontal = name == "bottom"
        length = axis.geometry().width() if horizontal else axis.geometry().height()
        metrics = axis.fontMetrics() if hasattr(axis, "fontMetrics") else \
            workspace.fontMetrics()
        spans = []
        for spacing, values in axis.tickValues(low, high, length):
            for value, text in zip(values, axis.tickStrings(values, axis.scale, spacing)):
                if not text:
                    continue
                centre = (value - low) / (high - low) * length
                half = (metrics.horizontalAdvance(text) if horizontal else metrics.height()) / 2
                spans.append((centre - half, centre + half, text))
        spans.sort()
        assert len(spans) >= 2, name
        overlaps = [(a[2], b[2]) for a, b in zip(spans, spans[1:]) if b[0] < a[1] + 2]
        assert overlaps == [], name


def test_a_stretch_is_chosen_on_the_time_series_or_the_whole_taken(workspace, tmp_path):
    """Issue 51: From log… analysed only the longest still interval, with no way to take the
    whole log or a stretch of it (the command line has --whole and --range); a live Start that
    moved said "select a still stretch" with no way to select one."""
    moving = simulate(duration_s=12.0, seed=3)          # still 0-3 s, then turns
    rest = workspace.rest
    assert not rest.stretch_bar.isVisibleTo(workspace)
    rest.start(10.0)
    for snapshot in snapshots(moving):
        workspace.feed(snapshot)
    assert rest.result.how == "all of them" and "moved" in rest.warnings.text()
    assert rest.stretch_bar.isVisibleTo(workspace)
    assert "drag the blue range over a still stretch" in rest.stretch_label.text()
    assert rest.regions[0].getRegion() == pytest.approx((0.0, 10.0), abs=0.01)
    region = rest.regions[2]                             # drag the range on the mag plot
    region.setRegion((0.5, 2.5))
    assert rest.regions[0].getRegion() == pytest.approx((0.5, 2.5))      # all three follow
    region.sigRegionChangeFinished.emit(region)
    result = rest.result
    assert result.how == "chosen range" and result.analysis.duration_s == pytest.approx(2.0,
                                                                                       abs=0.02)
    assert "moved" not in result.analysis.warning_kinds() and rest.warnings.text() == ""
    assert "Analysed 0.5–2.5 s of the live samples (10.0 s): chosen range" in \
        rest.stretch_label.text()
    rest.whole_button.click()
    assert rest.result.how == "whole log" and rest.result.analysis.duration_s > 9.9
    rest.still_button.click()
    assert rest.result.how == "longest still interval"
    assert rest.regions[1].getRegion()[1] == pytest.approx(2.9, abs=0.1)
    # a log: its longest still stretch first, then the whole of it or a range
    log = tmp_path / "moving.txt"
    write_session(moving, log)
    assert workspace.analyse_log(log)
    assert rest.result.how == "longest still interval" and rest.source.name == "moving.txt"
    assert workspace.analyse_log(log, whole=True)
    assert rest.result.analysis.duration_s == pytest.approx(12.0, abs=0.05)
    assert workspace.analyse_log(log, 1.0, 2.0)
    assert rest.result.analysis.duration_s == pytest.approx(1.0, abs=0.02)
    # the command line's path gives the same figures for the same stretch
    from app.engine.tuning.calibration import rest_from_log
    from app.engine.config import open_log
    cli = rest_from_log(open_log(log), 1.0, 2.0)
    np.testing.assert_array_equal(cli.analysis.result.gyr.cov, rest.result.analysis.result.gyr.cov)
    assert not workspace.analyse_log(log, 20.0, 30.0)
    assert "nothing in the range" in workspace.message.text()
    assert rest.result.analysis.duration_s == pytest.approx(1.0, abs=0.02)  # kept


def test_the_table_names_the_tests_behind_the_verdict(workspace):
    rest = simulate(duration_s=12.0, script="rest", seed=11)
    workspace.rest.start()
    for snapshot in snapshots(rest):
        workspace.feed(snapshot)
    table = workspace.rest.table
    headers = [table.horizontalHeaderItem(c).text() for c in range(table.columnCount())]
    assert {"K² p", "A² (1 % crit.)", "verdict"} <= set(headers)
    verdicts = {table.item(r, headers.index("verdict")).text() for r in range(table.rowCount())}
    assert verdicts <= {"Gaussian", "mixed", "not Gaussian", "Gaussian, correlated",
                        "mixed, correlated", "not Gaussian, correlated"}
    assert table.item(0, 0).text() == f"acc [{UNITS['acc']}]"
    assert "D'Agostino–Pearson K² p ≥ 0.01" in workspace.rest.verdict_rule.text()
    assert "mixed" in workspace.rest.verdict_rule.text()
