"""The window at 1280x720 and 1920x1080 (offscreen): nothing overlaps, every legend lies outside
its data, the transport bar is visible, the y-axis titles do not collide, the combination table
shows all seven rows, and a view with no data says so."""

from __future__ import annotations

import itertools

import pytest
from PySide6 import QtCore, QtWidgets

from ui_helpers import make_snapshot, make_user_snapshot

SIZES = [(1280, 720), (1920, 1080)]


def _rect_in_window(window, widget) -> QtCore.QRect:
    return QtCore.QRect(widget.mapTo(window, QtCore.QPoint(0, 0)), widget.size())


def _shown(window, size) -> object:
    window.resize(*size)
    window.arrange_default_layout()
    window.show()
    for _ in range(3):
        QtWidgets.QApplication.processEvents()
    return window


@pytest.mark.parametrize("yours", [False, True], ids=["own-phone", "with-yours"])
@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_main_panels_do_not_overlap_and_the_transport_bar_is_visible(make_window, fake_engine,
                                                                     size, yours):
    window = make_window(fake_engine)
    if yours:       # a third 3D view: the window must still fit the screen
        window.apply_snapshot(make_user_snapshot(1, 0.0))
    window = _shown(window, size)
    assert window.size() == QtCore.QSize(*size)
    panels = {"OWN": window.own_view, "PHONE": window.phone_view, "plots": window.plots,
              "transport": window.transport}
    if yours:
        panels["YOURS"] = window.user_view
    for dock in window.docks():
        if dock.isVisible() and not dock.visibleRegion().isEmpty():
            panels[dock.objectName()] = dock
    rects = {name: _rect_in_window(window, widget) for name, widget in panels.items()}
    frame = window.rect()
    for name, rect in rects.items():
        assert frame.contains(rect), (name, rect, frame)
        assert rect.width() > 100 and rect.height() > 20, (name, rect)
    for (a, ra), (b, rb) in itertools.combinations(rects.items(), 2):
        assert not ra.intersects(rb), (a, ra, b, rb)
    assert window.transport.isVisible() and window.transport.height() >= 24
    assert rects["OWN"].height() >= 150 and rects["plots"].height() >= 250
    assert rects["OWN"].width() >= 190 and rects["PHONE"].width() >= 190
    assert "filter_dock" in rects and ("comparison_dock" in rects or "connection_dock" in rects)


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_legends_outside_the_data_and_axis_titles_apart(make_window, fake_engine, size):
    window = _shown(make_window(fake_engine), size)
    fake_engine.snapshots.append(make_snapshot(1, 0.0, count=200))
    window.tick()
    plots = window.plots
    for key, group in plots.groups.items():
        plots.set_current_group(key)
        plots.refresh()
        QtWidgets.QApplication.processEvents()
        legend = _rect_in_window(window, group.legend)
        titles = []
        for plot_key in group.plots:
            plot = plots.plots[plot_key]
            scene = plot.getViewBox().sceneBoundingRect().toRect()
            data = QtCore.QRect(group.graphics.mapTo(window, group.graphics.mapFromScene(
                scene.topLeft())), scene.size())
            assert data.height() >= 60, (size, plot_key, data)
            assert not legend.intersects(data), (size, plot_key)
            titles.append(plot.getAxis("left").label.sceneBoundingRect())
        for a, b in itertools.combinations(titles, 2):
            assert not a.intersects(b), (size, key)


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_the_combination_table_shows_all_seven_rows(make_window, fake_engine, size):
    window = _shown(make_window(fake_engine), size)
    window.comparison_dock.raise_()
    QtWidgets.QApplication.processEvents()
    table = window.comparison.table
    assert table.viewport().height() >= 7 * table.verticalHeader().defaultSectionSize()


def test_no_data_looks_like_no_data(make_window, fake_engine):
    window = _shown(make_window(fake_engine), (1280, 720))
    # before the first sample
    assert window.lights.states() == {"acc": "no data", "mag": "no data", "standstill": "no data"}
    assert "waiting for data" in window.own_view.placeholder.text()
    assert "waiting for data" in window.phone_view.placeholder.text()
    # samples, but the filter has not started and the log has no ORI
    snapshot = make_snapshot(1, 0.0, phone_quat=None, initialised=False)
    snapshot.t_ms, snapshot.t0_ms = 3000, 0
    fake_engine.snapshots.append(snapshot)
    window.tick()
    assert window.own_view.quat is None
    assert "no ORI in this stream" in window.phone_view.placeholder.text()
    assert set(window.lights.states().values()) == {"no data"}
    # the filter runs
    fake_engine.snapshots.append(make_snapshot(2, 0.5, phone_quat=None))
    window.tick()
    assert window.own_view.quat is not None and window.own_view.no_data_text == ""
    assert "waiting" not in window.own_view.placeholder.text()


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_the_filter_dock_shows_its_switches_and_buttons_whole(make_window, fake_engine, size):
    window = _shown(make_window(fake_engine), size)
    viewport = window.filter_dock.widget().viewport()
    controls = window.controls
    widgets = [*controls.sensor_checkboxes.values(),
               *controls.findChildren(QtWidgets.QPushButton),
               *controls.findChildren(QtWidgets.QGroupBox)]
    assert widgets
    for widget in widgets:
        if not widget.isVisible():
            continue
        right = widget.mapTo(viewport, QtCore.QPoint(widget.width(), 0)).x()
        assert right <= viewport.width(), (widget.objectName() or widget.text(), right,
                                           viewport.width())
        if isinstance(widget, QtWidgets.QAbstractButton):
            assert widget.width() >= widget.minimumSizeHint().width()


def test_a_long_file_name_in_the_transport_bar_is_cut_with_the_whole_name_in_its_tooltip(
        make_window, fake_engine):
    window = _shown(make_window(fake_engine), (1280, 720))
    name = "a_recording_with_a_really_rather_long_name_2026-12-04_21-30-00.txt"
    window.transport.update_replay({"position_s": 1.0, "duration_s": 90.0, "speed": 1.0,
                                 "paused": False, "loop": False, "finished": False}, name)
    label = window.transport.source_label
    assert label.text() == label.toolTip() == name
    assert "…" in label.shown_text()
    assert label.fontMetrics().horizontalAdvance(label.shown_text()) <= label.width() \
        <= label.maximumWidth()


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_the_transport_bar_and_rec_stay_in_every_workspace(make_window, fake_engine, size):
    window = _shown(make_window(fake_engine), size)
    for index in range(window.workspaces.count()):
        window.workspaces.setCurrentIndex(index)
        QtWidgets.QApplication.processEvents()
        assert window.transport.isVisible(), window.workspaces.tabText(index)
        assert window.transport.record_button.isVisible()
        bar = _rect_in_window(window, window.transport)
        assert window.rect().contains(bar)
        assert not bar.intersects(_rect_in_window(window, window.workspaces.currentWidget()))


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory):
    from app.stream.demo import write_session
    from ekf.simulate import simulate
    path = tmp_path_factory.mktemp("layout") / "sim.txt"
    write_session(simulate(duration_s=20.0, seed=3), path)
    return path


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_the_tune_plots_axis_titles_stay_apart(qtbot, make_window, fake_engine, sim_log, size):
    window = _shown(make_window(fake_engine), size)
    tune = window.tune
    assert tune.set_log(sim_log)
    window.workspaces.setCurrentWidget(tune)
    qtbot.waitUntil(lambda: tune.refilterer.current is not None, timeout=20_000)
    for _ in range(3):
        QtWidgets.QApplication.processEvents()
    plots = tune.ab_plots.plots
    titles = {key: plot.getAxis("left").label.sceneBoundingRect() for key, plot in plots.items()}
    for key, plot in plots.items():
        assert titles[key].height() <= plot.getViewBox().sceneBoundingRect().height() + 1, \
            (size, key)
    for (a, first), (b, second) in itertools.combinations(titles.items(), 2):
        assert not first.intersects(second), (size, a, b)
    no_data = tune.ab_plots.no_data           # no ghost yet: its plot says so, the errors do not
    assert no_data["difference"].isVisible() and "ghost" in no_data["difference"].text()
    assert not no_data["total"].isVisible() and not no_data["heading"].isVisible()


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_the_filter_dock_does_not_scroll_even_with_a_note_of_absent_sensors(
        qtbot, make_window, fake_engine, size):
    """Issue 51: the Filter dock scrolled in the default layout, and on an accelerometer-only
    log (its "no gyroscope" note) Reset filter and Align heading were cut in half."""
    from clipping import clipped, scrolls
    window = _shown(make_window(fake_engine), size)
    scroll = window.filter_dock.widget()
    qtbot.waitUntil(lambda: not scrolls(scroll), timeout=2000)
    snapshot = make_snapshot(1, 2.5)
    snapshot.session_samples = {"acc": 250, "ori": 250}            # no gyroscope, no magnetometer
    fake_engine.snapshots.append(snapshot)
    window.tick()
    note = window.controls.sensor_note
    assert note.isVisibleTo(window) and "no gyroscope" in note.text()
    qtbot.waitUntil(lambda: not scrolls(scroll), timeout=2000)
    assert note.text() == "no gyroscope or magnetometer in this stream"     # one short line
    cut = [finding for finding in clipped(window, whole=(scroll,)) if "filter_dock" in finding
           or "Reset filter" in finding or "Align heading" in finding]
    assert cut == []
    for button in (window.controls.reset_button, window.controls.align_button):
        seen = button.visibleRegion().boundingRect()
        assert seen.size() == button.size(), (button.text(), seen, button.size())


def test_an_elided_label_shows_the_longest_form_that_fits_and_never_widens_its_panel(qtbot):
    from app.ui.elided import ElidedLabel
    label = ElidedLabel(minimum_text="REC 0:00")
    qtbot.addWidget(label)
    full, shorter = "REC 1:12 · 3.0 MB · 12,345 lines", ("REC 1:12 · 3.0 MB", "REC 1:12")
    label.setText(full, shorter)
    metrics = label.fontMetrics()
    assert label.minimumSizeHint().width() < metrics.horizontalAdvance(shorter[1]) + 10
    assert label.sizeHint().width() >= metrics.horizontalAdvance(full)
    label.resize(metrics.horizontalAdvance(full) + 8, 20)
    assert label.shown_text() == full and label.toolTip() == full
    label.resize(metrics.horizontalAdvance(shorter[0]) + 8, 20)
    assert label.shown_text() == shorter[0]                # the size, not "3.0 M…"
    label.resize(metrics.horizontalAdvance(shorter[1]) + 8, 20)
    assert label.shown_text() == shorter[1]
    label.resize(metrics.horizontalAdvance("REC") + 8, 20)
    assert label.shown_text().endswith("…")


@pytest.mark.parametrize("first, then", [((1280, 720), (1920, 1080)),
                                         ((1920, 1080), (1280, 720)),
                                         (None, (1920, 1080))],
                         ids=["720-then-1080", "1080-then-720", "built-then-1080"])
def test_a_layout_arranged_again_on_another_screen_leaves_no_stray_tab_bar(make_window,
                                                                           fake_engine,
                                                                           first, then):
    """Arranged at one size and again at another (1280x720: three docks tabbed; 1920x1080:
    the table above, the connection and your filter tabbed): one tab bar, naming the docks
    tabbed together now, right below them."""
    window = make_window(fake_engine)     # arranged once as it is built (restore_settings)
    if first is not None:
        window = _shown(window, first)
    window = _shown(window, then)
    window.user_dock.raise_()
    for _ in range(3):
        QtWidgets.QApplication.processEvents()
    bars = [bar for bar in window.findChildren(QtWidgets.QTabBar)
            if bar.parentWidget() is window and bar.isVisible()]
    tabbed = [window.connection_dock, window.user_dock]
    if then[1] < 950:
        tabbed.append(window.comparison_dock)
    assert [sorted(bar.tabText(i) for i in range(bar.count())) for bar in bars] == \
        [sorted(dock.windowTitle() for dock in tabbed)]
    assert abs(bars[0].geometry().top() - window.user_dock.geometry().bottom()) <= 2
