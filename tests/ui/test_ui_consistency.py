"""The consistency view: innovations with sigma bands, NIS against chi^2 bounds and the fraction
inside, the histogram against N(0, 1), rejected updates marked; it asks the engine for our
EKF's innovations only while shown."""

from __future__ import annotations

import numpy as np
import pytest

from app.engine.commands import SetConsistencyEnabled
from app.engine.snapshot import PlotChunk, Snapshot, UserFilterStatus
from app.ui.consistency import CHI2_95, ConsistencyView, consistency


def _chunk(n: int = 4000, source: int = 0, sensor: int = 0, k: int = 3, seed: int = 1,
           scale: float = 1.0) -> PlotChunk:
    """n innovations nu ~ N(0, scale^2 S) with S = diag(4, 1, 0.25)[:k]; every 20th rejected."""
    rng = np.random.default_rng(seed)
    S = np.full((n, 3, 3), np.nan)
    S[:, :k, :k] = np.diag([4.0, 1.0, 0.25][:k])
    nu = np.full((n, 3), np.nan)
    nu[:, :k] = rng.standard_normal((n, k)) * np.sqrt([4.0, 1.0, 0.25][:k]) * scale
    accepted = np.arange(n) % 20 != 0
    return PlotChunk(t_innovation=np.arange(n) * 0.01,
                     innovation_source=np.full(n, source, np.int8),
                     innovation_sensor=np.full(n, sensor, np.int8), innovation=nu,
                     innovation_cov=S, innovation_accepted=accepted)


@pytest.fixture
def view(qtbot):
    sent = []
    widget = ConsistencyView(sent.append)
    widget.sent = sent
    qtbot.addWidget(widget)
    return widget


def test_a_consistent_filter_is_about_95_percent_inside(view):
    view.add_chunk(_chunk())
    view.refresh()
    stats = view.stats
    assert stats["k"] == 3 and stats["n"] == 4000 and stats["rejected"] == 200
    assert stats["bounds"] == CHI2_95[3]
    assert stats["inside"] == pytest.approx(0.95, abs=0.015)
    assert stats["mean_nis"] == pytest.approx(3.0, abs=0.15)
    assert np.std(stats["z"]) == pytest.approx(1.0, abs=0.03)       # normalised: N(0, 1)
    assert "4000 updates, 200 rejected" in view.summary.text()
    x, _ = view.component_items[0]["+2"].getData()
    _, band = view.component_items[0]["+2"].getData()
    assert len(x) == 4000 and band[0] == pytest.approx(4.0)          # 2 sigma of S_xx = 4
    rejected_x, _ = view.component_items[0]["rejected"].getData()
    assert len(rejected_x) == 200
    assert [line.value() for line in view.nis_bounds] == list(CHI2_95[3])


def test_an_overconfident_filter_shows_it(view):
    view.add_chunk(_chunk(scale=2.0))        # innovations twice the size S claims
    view.refresh()
    assert view.stats["inside"] < 0.5 and view.stats["mean_nis"] > 10


def test_sources_sensors_and_a_one_dimensional_innovation(view):
    view.add_chunk(_chunk(source=1, sensor=1, k=1))
    view.refresh()
    assert view.stats["n"] == 0 and "no innovations yet" in view.summary.text()
    view.source_combo.setCurrentIndex(1)
    view.sensor_combo.setCurrentIndex(1)
    assert view.stats["k"] == 1 and view.stats["bounds"] == CHI2_95[1]
    shown = [plot.isVisible() for plot in view.component_plots]
    assert shown == [True, False, False]                 # one component: one plot


def test_a_reloaded_filter_starts_yours_afresh_and_the_ring_is_bounded(qtbot):
    view = ConsistencyView(capacity=1000)
    qtbot.addWidget(view)
    snapshot = Snapshot(plot=_chunk(3000, source=1), user=UserFilterStatus(generation=1))
    view.apply_snapshot(snapshot)
    assert view.series[(1, 0)].size == 1000
    t, *_ = view.series[(1, 0)].arrays()
    assert t[0] == pytest.approx(20.0) and np.all(np.diff(t) > 0)     # the latest, in order
    view.apply_snapshot(Snapshot(user=UserFilterStatus(generation=2)))
    assert view.series[(1, 0)].size == 0


def test_it_asks_for_our_innovations_only_while_shown(view):
    view.show()
    view.hide()
    assert view.sent == [SetConsistencyEnabled(True), SetConsistencyEnabled(False)]


def test_statistics_of_nothing():
    stats = consistency(np.empty((0, 3)), np.empty((0, 3, 3)), np.empty(0, bool))
    assert stats["n"] == 0 and np.isnan(stats["inside"])


@pytest.mark.parametrize("width", [420, 700, 1100])
def test_the_summary_keeps_all_its_lines_in_a_short_view(qtbot, width):
    """The plots give up height to the summary's lines, whatever its text and width (a
    1280x720 window's Consistency dock, shorter than the view would like, cut the summary's
    second line while streaming)."""
    from PySide6 import QtWidgets
    holder = QtWidgets.QWidget()              # a dock that is shorter than the view would like
    qtbot.addWidget(holder)
    view = ConsistencyView(lambda command: None)
    QtWidgets.QVBoxLayout(holder).addWidget(view)
    holder.setFixedSize(width, 100)
    holder.show()
    qtbot.waitExposed(holder)
    view.add_chunk(_chunk())
    view.refresh()
    needed = view.summary.heightForWidth(view.summary.width())
    assert needed > view.fontMetrics().height()                     # more than one line
    qtbot.waitUntil(lambda: view.summary.height() >= view.summary.heightForWidth(
        view.summary.width()))
