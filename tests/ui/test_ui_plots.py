"""Live plots: bounded buffers, following window, pause-and-inspect, cursor, legend, clear."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6 import QtCore

from app.engine.snapshot import FilterStatus
from app.ui.plots import PlotPanel, SampleBuffer, peak_downsample, same_turn

from ui_helpers import status_of, make_chunk


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


def _curve(panel: PlotPanel, key: str, label: str):
    return next(curve for name, curve, _ in panel.streams[key].curves if name == label)


def test_following_shows_the_last_window_of_phone_time(panel):
    panel.set_window_s(5.0)
    for k in range(20):                       # 10 s of samples at 100 Hz
        panel.append(make_chunk(1000.0 + 0.5 * k, count=50))
        panel.refresh()
    low, high = panel.x_range()
    assert high == pytest.approx(1000.0 + 9.99)
    assert high - low == pytest.approx(5.0)
    x, y = _curve(panel, "acc", "norm").getData()
    assert x[0] <= low + 0.02 and x[-1] == pytest.approx(high)
    assert len(x) < 600                        # only the visible window is handed to the curve
    np.testing.assert_allclose(y, np.linalg.norm(panel.streams["acc"].buffer.values[-len(y):, :3],
                                                 axis=1))
    x_angle, y_angle = _curve(panel, "angle", "∠(OWN, PHONE)").getData()
    np.testing.assert_allclose(y_angle, np.sqrt(3.0))


def test_pause_keeps_the_view_while_data_keeps_arriving_then_follow(panel, qtbot):
    panel.set_window_s(2.0)
    panel.append(make_chunk(0.0, count=300))
    panel.refresh()
    qtbot.mouseClick(panel.pause_button, QtCore.Qt.MouseButton.LeftButton)
    assert panel.paused
    frozen = panel.x_range()
    size_before = panel.streams["gyr"].buffer.size
    for k in range(5):
        panel.append(make_chunk(3.0 + k, count=100))
        panel.refresh()
    assert panel.x_range() == pytest.approx(frozen)
    assert panel.streams["gyr"].buffer.size == size_before + 500     # still stored
    qtbot.mouseClick(panel.follow_button, QtCore.Qt.MouseButton.LeftButton)
    panel.refresh()
    assert not panel.paused
    assert panel.x_range()[1] == pytest.approx(7.99)


def test_zooming_a_plot_by_hand_pauses(panel):
    panel.append(make_chunk(0.0, count=300))
    panel.refresh()
    view_box = panel.plots["gyr"].getViewBox()
    view_box.sigRangeChangedManually.emit([True, False])
    assert panel.paused


def test_rejected_samples_and_gate_lines_on_the_acc_norm(panel):
    panel.append(make_chunk(0.0, count=100, acc_rejected_every=10))
    panel.set_status(status_of(g=9.81, acc_gate=0.5, mag_expected=50.0, mag_gate=float("nan")))
    panel.refresh()
    x, y = panel.streams["acc"].rejected_scatter.getData()
    np.testing.assert_allclose(x, np.arange(0, 100, 10) / 100.0)
    upper, lower = panel.gate_lines["acc"]
    assert upper.isVisible() and upper.value() == pytest.approx(10.31)
    assert lower.value() == pytest.approx(9.31)
    assert not panel.gate_lines["mag"][0].isVisible()       # no gate known yet


def test_legend_click_hides_a_curve(panel):
    legend = panel.plots["euler"].legend
    sample, _ = legend.items[0]

    class Click:
        def button(self):
            return QtCore.Qt.MouseButton.LeftButton

        def accept(self):
            pass

    curve = _curve(panel, "euler", "OWN yaw")
    assert curve.isVisible()
    sample.mouseClickEvent(Click())
    assert not curve.isVisible()
    panel.set_cursor_visible(True)
    assert "euler/OWN yaw" not in panel.cursor_values()
    sample.mouseClickEvent(Click())
    assert curve.isVisible()


def test_cursor_reads_every_visible_curve(panel):
    panel.append(make_chunk(10.0, count=200))
    panel.refresh()
    panel.cursor_checkbox.setChecked(True)
    assert all(cursor.isVisible() for cursor in panel.cursors.values())
    panel.set_cursor_time(10.5)
    values = panel.cursor_values()
    assert values["acc/z"] == pytest.approx(9.81)
    assert values["mag/y"] == pytest.approx(15.0)
    assert values["euler/PHONE pitch"] == pytest.approx(6.0)
    assert values["gyr/x"] == pytest.approx(0.1 * np.sin(2 * np.pi * 0.5 * 10.5), abs=1e-9)
    assert len(values) == 4 + 4 + 4 + 6 + 1
    assert "t = 10.500 s" in panel.readout_label.text()
    # All plots share one cursor: dragging one moves the others.
    panel.cursors["mag"].setValue(11.0)
    assert panel.cursor_time() == pytest.approx(11.0)
    assert panel.cursors["euler"].value() == pytest.approx(11.0)


def test_clear_and_time_going_backwards_start_afresh(panel, qtbot):
    panel.append(make_chunk(100.0, count=100))
    panel.append(make_chunk(5.0, count=10))           # a looped replay restarts phone time
    assert panel.streams["acc"].buffer.size == 10
    qtbot.mouseClick(panel.clear_button, QtCore.Qt.MouseButton.LeftButton)
    assert all(stream.buffer.size == 0 for stream in panel.streams.values())
    x, _ = _curve(panel, "acc", "x").getData()
    assert x is None or len(x) == 0


def test_phone_angles_may_be_missing(panel):
    chunk = make_chunk(0.0, count=20)
    chunk.phone_euler_deg = np.full((20, 3), np.nan)
    chunk.angle_deg = np.empty(0)                      # nothing to compare with yet
    panel.append(chunk)
    panel.refresh()
    assert np.isnan(panel.streams["angle"].buffer.values).all()
    assert panel.streams["euler"].buffer.size == 20


def test_phone_yaw_is_drawn_in_the_same_turn_as_own(panel):
    # OWN turns steadily through three turns; PHONE agrees within a few degrees, but its own
    # unwrapping went astray twice (a jump of more than 180° between samples), so its
    # unwrapped yaw ends up two turns (720°) away from OWN's.
    chunk = make_chunk(0.0, count=200)
    own_yaw = np.linspace(0.0, 1080.0, 200)
    phone_yaw = own_yaw + 3.0 + np.where(np.arange(200) >= 60, 360.0, 0.0) \
        + np.where(np.arange(200) >= 140, 360.0, 0.0)
    chunk.own_euler_deg[:, 0] = own_yaw
    chunk.phone_euler_deg[:, 0] = phone_yaw
    chunk.phone_euler_deg[:10] = np.nan                 # no ORI at first
    panel.append(chunk)
    panel.refresh()
    stored = panel.streams["euler"].buffer.values
    np.testing.assert_allclose(stored[:, 0], own_yaw)
    np.testing.assert_allclose(stored[10:, 3], own_yaw[10:] + 3.0)
    assert np.isnan(stored[:10, 3:]).all()
    np.testing.assert_allclose(stored[10:, 4:], chunk.phone_euler_deg[10:, 1:])   # pitch, roll
    x, y = _curve(panel, "euler", "PHONE yaw").getData()
    assert np.nanmax(np.abs(y - np.interp(x, chunk.t_est, own_yaw))) < 3.5


def test_same_turn_picks_the_nearest_turn_and_keeps_nan():
    reference = np.array([0.0, 350.0, -725.0, 10.0, np.nan])
    angles = np.array([719.0, -5.0, 0.0, np.nan, 40.0])
    np.testing.assert_allclose(same_turn(angles, reference)[:3], [-1.0, 355.0, -720.0])
    assert np.isnan(same_turn(angles, reference)[3])
    assert same_turn(angles, reference)[4] == 40.0          # no OWN: left as it came


def test_peak_downsample_keeps_every_peak_with_stable_bins():
    t = np.arange(10_000) / 500.0
    values = np.column_stack([np.sin(t), np.zeros_like(t)])
    values[4321, 1] = 7.0                                  # a one-sample spike
    values[8765, 1] = -3.0
    shown_t, shown = peak_downsample(t, values, first_index=0, max_points=1000)
    assert len(shown_t) <= 1100 and np.all(np.diff(shown_t) >= 0)
    assert shown[:, 1].max() == 7.0 and shown[:, 1].min() == -3.0
    assert shown[:, 0].max() == pytest.approx(values[:, 0].max())
    # One sample later the window has scrolled by one: the bins are the same samples.
    later_t, later = peak_downsample(t[1:], values[1:], first_index=1, max_points=1000)
    common = np.intersect1d(shown_t, later_t)
    assert len(common) > 0.9 * len(shown_t)
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
    # The views line up: the same time is at the same x on the screen in every plot.
    xs = {key: plot.getViewBox().mapViewToScene(QtCore.QPointF(1.5, 0.0)).x()
          for key, plot in panel.plots.items()}
    assert max(xs.values()) - min(xs.values()) < 1.0
