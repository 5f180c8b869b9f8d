"""The plots: bounded buffers, the following window, pause-and-inspect, three tabs, legend
toggles outside the data, wrapped and unwrapped Euler angles, rejected samples as a band,
the cursor readout with units, time since the start."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6 import QtCore

from app.ui.plots import (PlotPanel, SampleBuffer, break_at_wraps, peak_downsample,
                          readout_table, rejected_spans, same_turn, time_text, unwrap_deg,
                          unwrap_in_turn)
from ui_helpers import make_chunk, status_of


def test_sample_buffer_is_bounded_and_keeps_the_newest_rows_in_order():
    buffer = SampleBuffer(columns=2, capacity=100)
    for start in range(0, 1000, 30):
        t = np.arange(start, start + 30, dtype=float)
        buffer.append(t, np.column_stack([t, -t]))
    assert 100 <= buffer.size <= 200
    assert buffer.t[-1] == 1019.0
    assert np.all(np.diff(buffer.t) == 1.0)
    np.testing.assert_array_equal(buffer.values[:, 1], -buffer.t)
    big = np.arange(5000, 5500, dtype=float)
    buffer.append(big, np.column_stack([big, big]))
    np.testing.assert_array_equal(buffer.t, big[-100:])
    window = buffer.window(5450.0, 5460.0)
    assert buffer.t[window][0] == 5449.0 and buffer.t[window][-1] == 5461.0


@pytest.fixture
def panel(qtbot):
    widget = PlotPanel()
    qtbot.addWidget(widget)
    widget.resize(900, 700)
    widget.show()
    return widget


def _curve(panel: PlotPanel, label: str):
    return next(curve for spec, curve in panel.curves if spec.label == label)


def test_following_shows_the_last_window_of_session_time(panel):
    panel.set_window_s(5.0)
    for k in range(20):                       # 10 s of samples at 100 Hz
        panel.append(make_chunk(0.5 * k, count=50))
        panel.refresh()
    low, high = panel.x_range()
    assert high == pytest.approx(9.993)          # the newest sample: PHONE, 3 ms after
    assert high - low == pytest.approx(5.0)
    x, y = _curve(panel, "acc norm").getData()
    assert x[0] <= low + 0.02 and x[-1] == pytest.approx(9.99)
    assert len(x) < 600                        # only the visible window is handed to the curve
    np.testing.assert_allclose(y, np.linalg.norm(panel.buffers["acc"].values[-len(y):, :3],
                                                 axis=1))


def test_only_the_shown_tab_is_drawn_and_a_tab_switch_draws_it(panel):
    panel.append(make_chunk(0.0, count=300))
    panel.refresh()
    assert _curve(panel, "acc x").getData()[0] is not None
    x, _ = _curve(panel, "total").getData()
    assert x is None or len(x) == 0                              # not drawn while hidden
    panel.set_current_group("error")
    panel.refresh()
    x, y = _curve(panel, "total").getData()
    np.testing.assert_allclose(y, np.sqrt(3.0))
    assert panel.x_range() == pytest.approx((2.993 - 10.0, 2.993), abs=0.001)


def test_pause_keeps_the_view_while_data_keeps_arriving_then_follow(panel, qtbot):
    panel.set_window_s(2.0)
    panel.append(make_chunk(0.0, count=300))
    panel.refresh()
    qtbot.mouseClick(panel.pause_button, QtCore.Qt.MouseButton.LeftButton)
    assert panel.paused
    frozen = panel.x_range()
    panel.append(make_chunk(3.0, count=300))
    panel.refresh()
    assert panel.x_range() == pytest.approx(frozen)
    assert panel.buffers["acc"].size == 600    # kept storing
    qtbot.mouseClick(panel.follow_button, QtCore.Qt.MouseButton.LeftButton)
    panel.refresh()
    assert not panel.paused and panel.x_range()[1] == pytest.approx(5.993)


def test_zooming_a_plot_by_hand_pauses(panel):
    panel.append(make_chunk(0.0, count=300))
    panel.refresh()
    panel.plots["gyr"].getViewBox().sigRangeChangedManually.emit([True, False])
    assert panel.paused


def test_rejected_samples_are_a_thin_band_and_the_gates_lines(panel):
    panel.append(make_chunk(0.0, count=100, acc_rejected_every=10))
    panel.set_status(status_of(g=9.81, acc_gate=0.5, mag_expected=50.0, mag_gate=float("nan")))
    panel.refresh()
    x, y = panel.bands["acc"].getData()
    assert len(x) == 20                         # 10 spans, a start and an end each
    np.testing.assert_allclose(x[::2], np.arange(0, 100, 10) / 100.0 - 0.005)
    low, high = panel.plots["acc"].getViewBox().viewRange()[1]
    assert np.all(y < low + 0.05 * (high - low))       # along the bottom, under the curves
    norm_low = np.linalg.norm(panel.buffers["acc"].values[:, :3], axis=1).min()
    assert y[0] < norm_low
    upper, lower = panel.gate_lines["acc"]
    assert upper.isVisible() and upper.value() == pytest.approx(10.31)
    assert lower.value() == pytest.approx(9.31)
    assert not panel.gate_lines["mag"][0].isVisible()       # no gate known yet
    panel.set_shown("sensors", "rejected", False)
    assert not panel.bands["acc"].isVisible()


def test_a_switched_off_magnetometer_draws_off_not_rejected(panel):
    """Issue 51: switching the magnetometer off drew the red "rejected" band (its last
    rejected flag held while off), which reads as rejections."""
    on, off = dict(gyr=True, acc=True, mag=True), dict(gyr=True, acc=True, mag=False)
    for k in range(10):                                      # 0-5 s, off from 2 to 4 s
        chunk = make_chunk(0.5 * k, count=50)
        chunk.mag_rejected = np.ones(50, bool) if 4 <= k < 8 else np.zeros(50, bool)
        panel.append(chunk, off if 4 <= k < 8 else on)
    panel.refresh()
    assert panel.rejected_band_spans("mag").shape == (0, 2)         # no red for the off stretch
    np.testing.assert_allclose(panel.off_band_spans("mag"), [[1.995, 3.995]], atol=0.01)
    x, _ = panel.off_bands["mag"].getData()
    assert len(x) == 2 and panel.off_bands["mag"].isVisible()
    assert panel.off_band_spans("acc").shape == (0, 2)              # the accelerometer stayed on
    toggle = panel.groups["sensors"].toggles["off"]
    assert "switched off" in toggle.toolTip()
    panel.set_shown("sensors", "off", False)
    assert not panel.off_bands["mag"].isVisible()
    # a rejection while on stays red
    chunk = make_chunk(5.0, count=50)
    chunk.mag_rejected = np.zeros(50, bool)
    chunk.mag_rejected[10:20] = True
    panel.append(chunk, on)
    panel.refresh()
    assert panel.rejected_band_spans("mag").shape == (1, 2)
    panel.clear()
    assert panel.off_spans["mag"].spans == []


def test_rejected_spans_merge_runs_and_widen_single_samples():
    t = np.arange(10) * 0.01
    spans = rejected_spans(t, np.array([0, 1, 1, 0, 0, 1, 0, 0, 0, 1], bool))
    np.testing.assert_allclose(spans, [[0.005, 0.025], [0.045, 0.055], [0.085, 0.095]])
    assert rejected_spans(t, np.zeros(10, bool)).shape == (0, 2)


def test_legend_toggles_hide_curves_in_every_plot_of_the_tab(panel, qtbot):
    panel.append(make_chunk(0.0, count=100))
    panel.refresh()
    toggle = panel.groups["sensors"].toggles["norm"]
    qtbot.mouseClick(toggle, QtCore.Qt.MouseButton.LeftButton)
    assert not toggle.isChecked()
    assert not any(_curve(panel, f"{key} norm").isVisible() for key in ("acc", "gyr", "mag"))
    assert _curve(panel, "acc x").isVisible()
    panel.set_cursor_visible(True)
    assert "acc norm" not in panel.cursor_values()
    qtbot.mouseClick(toggle, QtCore.Qt.MouseButton.LeftButton)
    assert _curve(panel, "mag norm").isVisible()


def test_legends_lie_outside_every_data_rectangle(panel):
    panel.append(make_chunk(0.0, count=100))
    for key, group in panel.groups.items():
        panel.set_current_group(key)
        panel.refresh()
        QtCore.QCoreApplication.processEvents()
        legend = group.legend.geometry()
        legend = QtCore.QRect(group.legend.mapTo(panel, QtCore.QPoint(0, 0)), legend.size())
        for plot_key in group.plots:
            view_box = panel.plots[plot_key].getViewBox()
            scene_rect = view_box.sceneBoundingRect().toRect()
            top_left = group.graphics.mapTo(panel, group.graphics.mapFromScene(
                scene_rect.topLeft()))
            data = QtCore.QRect(top_left, scene_rect.size())
            assert data.height() > 60, (key, plot_key, data)
            assert not legend.intersects(data), (key, plot_key, legend, data)


def test_cursor_reads_every_visible_curve_into_a_table_with_units(panel):
    panel.append(make_chunk(10.0, count=200))
    panel.refresh()
    panel.cursor_checkbox.setChecked(True)
    assert all(cursor.isVisible() for cursor in panel.cursors.values())
    panel.set_cursor_time(10.5)
    values = panel.cursor_values()
    assert values["acc z"] == pytest.approx(9.81)
    assert values["mag y"] == pytest.approx(15.0)
    assert values["PHONE pitch"] == pytest.approx(6.0)
    assert values["gyr x"] == pytest.approx(0.1 * np.sin(2 * np.pi * 0.5 * 10.5), abs=1e-9)
    assert values["total"] == pytest.approx(np.sqrt(3.0))
    text = panel.readout_label.text()
    assert "<table" in text and "t = 10.500 s" in text and "m/s²" in text and "rad/s" in text
    panel.set_current_group("orientation")
    assert "OWN" in panel.readout_label.text() and "°" in panel.readout_label.text()
    # All plots share one cursor: dragging one moves the others.
    panel.cursors["mag"].setValue(11.0)
    assert panel.cursor_time() == pytest.approx(11.0)
    assert panel.cursors["yaw"].value() == pytest.approx(11.0)


def test_readout_table_says_dash_where_there_is_no_value():
    html = readout_table({"OWN yaw": 12.3456}, 3.0, 10.0, "orientation")
    assert "12.346" in html and "–" in html and "PHONE" in html and html.count("<tr>") == 3


def test_a_new_session_starts_the_plots_afresh_and_clear(panel, qtbot):
    panel.append(make_chunk(100.0, count=100))
    panel.append(make_chunk(0.0, count=10))           # a looped replay starts again at 0
    assert panel.buffers["acc"].size == 10 and panel.buffers["own"].size == 10
    qtbot.mouseClick(panel.clear_button, QtCore.Qt.MouseButton.LeftButton)
    assert all(buffer.size == 0 for buffer in panel.buffers.values())
    x, _ = _curve(panel, "acc x").getData()
    assert x is None or len(x) == 0


def test_phone_may_be_missing(panel):
    chunk = make_chunk(0.0, count=20)
    chunk.t_ori = np.empty(0)
    chunk.phone_euler_deg = np.empty((0, 3))
    chunk.t_err = np.empty(0)
    chunk.error_deg = np.empty((0, 3))
    panel.append(chunk)
    panel.set_current_group("orientation")
    panel.refresh()
    assert panel.buffers["phone"].size == 0 and panel.buffers["own"].size == 20


def _turning_chunk(turns: float = 3.0, count: int = 300) -> object:
    chunk = make_chunk(0.0, count=count)
    own_yaw = (np.linspace(0.0, 360.0 * turns, count) + 180.0) % 360.0 - 180.0   # wrapped
    chunk.own_euler_deg[:, 0] = own_yaw
    chunk.phone_euler_deg[:, 0] = (own_yaw + 3.0 + 180.0) % 360.0 - 180.0
    return chunk


def test_wrapped_euler_breaks_the_line_at_a_wrap_never_a_vertical_stroke(panel):
    panel.append(_turning_chunk())
    panel.set_current_group("orientation")
    panel.refresh()
    x, y = _curve(panel, "OWN yaw").getData()
    finite = np.isfinite(y)
    assert np.abs(y[finite]).max() <= 180.0
    assert (~finite).sum() >= 2                          # broken at each wrap
    runs = np.split(y, np.flatnonzero(~finite))
    for run in runs:
        run = run[np.isfinite(run)]
        assert len(run) < 2 or np.abs(np.diff(run)).max() < 30    # no stroke across the plot
    low, high = panel.plots["yaw"].getViewBox().viewRange()[1]
    assert low <= -180 and high >= 180
    # the pitch axis spans ±90°
    low, high = panel.plots["pitch"].getViewBox().viewRange()[1]
    assert low <= -90 and high >= 90


def test_unwrapped_euler_puts_own_and_phone_in_the_same_turn(panel):
    panel.append(_turning_chunk())
    panel.set_current_group("orientation")
    panel.set_unwrapped(True)
    panel.refresh()
    x, y = _curve(panel, "OWN yaw").getData()
    assert np.isfinite(y).all() and y.max() - y.min() > 700
    assert np.abs(np.diff(y)).max() < 30
    xp, yp = _curve(panel, "PHONE yaw").getData()
    assert np.nanmax(np.abs(yp - np.interp(xp, x, y) - 3.0)) < 2.0


def test_euler_helpers():
    t = np.array([0.0, 1.0, 2.0, 3.0])
    angles = np.array([[170.0, 0, 0], [179.0, 0, 0], [-178.0, 0, 0], [-170.0, 0, 0]])
    t2, broken = break_at_wraps(t, angles)
    assert len(t2) == 5 and np.isnan(broken[2]).all() and t2[2] == 1.5
    unwrapped = unwrap_deg(angles)
    np.testing.assert_allclose(unwrapped[:, 0], [170, 179, 182, 190])
    moved = unwrap_in_turn(t, unwrapped, np.array([2.5]), np.array([[-175.0, 0, 0]]))
    assert moved[0, 0] == pytest.approx(185.0)
    reference = np.array([0.0, 350.0, -725.0, 10.0, np.nan])
    angles = np.array([719.0, -5.0, 0.0, np.nan, 40.0])
    np.testing.assert_allclose(same_turn(angles, reference)[:3], [-1.0, 355.0, -720.0])
    assert np.isnan(same_turn(angles, reference)[3]) and same_turn(angles, reference)[4] == 40.0


def test_time_since_the_start_reads_as_seconds_then_minutes():
    assert time_text(12.34, 10.0, 1) == "12.3"
    assert time_text(125.0, 130.0, 0) == "2:05"
    assert time_text(3725.0, 700.0, 0) == "1:02:05"
    assert time_text(float("nan")) == "–"
    assert time_text(75.25, 200.0, 1) == "1:15.2"


def test_the_time_axis_names_the_phone_clock_on_hover(panel):
    panel.set_time_origin(282_545_123)
    axis = panel.plots["mag"].getAxis("bottom")
    assert "282545.123 s on the phone's clock" in axis.toolTip()
    assert panel.plots["mag"].getAxis("left").labelText == "mag"


def test_peak_downsample_keeps_every_peak_with_stable_bins():
    t = np.arange(10_000) / 500.0
    values = np.column_stack([np.sin(t), np.zeros_like(t)])
    values[4321, 1] = 7.0                                  # a one-sample spike
    values[8765, 1] = -3.0
    shown_t, shown = peak_downsample(t, values, first_index=0, max_points=1000)
    assert len(shown_t) <= 1100 and np.all(np.diff(shown_t) >= 0)
    assert shown[:, 1].max() == 7.0 and shown[:, 1].min() == -3.0
    later_t, later = peak_downsample(t[1:], values[1:], first_index=1, max_points=1000)
    assert len(np.intersect1d(shown_t, later_t)) > 0.9 * len(shown_t)
    np.testing.assert_array_equal(peak_downsample(t[:500], values[:500], 0, 1000)[1], values[:500])


def test_all_plots_share_one_time_range(panel):
    panel.append(make_chunk(0.0, count=300))
    panel.refresh()
    ranges = {key: plot.getViewBox().viewRange()[0] for key, plot in panel.plots.items()}
    assert all(r == pytest.approx(ranges["acc"]) for r in ranges.values())
    panel.set_paused(True)
    panel.plots["mag"].getViewBox().setXRange(1.0, 2.0, padding=0.0)   # e.g. dragged by hand
    for plot in panel.plots.values():
        assert plot.getViewBox().viewRange()[0] == pytest.approx([1.0, 2.0])
    xs = {key: panel.plots[key].getViewBox().mapViewToScene(QtCore.QPointF(1.5, 0.0)).x()
          for key in ("acc", "gyr", "mag")}
    assert max(xs.values()) - min(xs.values()) < 1.0
