"""The live plots' construction: the toolbar, one tab per group with its legend toggles above
its plots, each plot's axes, cursor, band and gate lines, and the curves.

A mixin of PlotPanel: its methods fill the panel's dictionaries of plots, curves and items.
"""

from __future__ import annotations

import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets

from app.ui.elided import ElidedLabel
from app.ui.no_data import NoDataText
from app.ui.plot_items import Curve, PlotGroup, TimeAxis, cache_painting, legend_icon
from app.ui.plot_specs import (DEFAULT_WINDOW_S, FOLLOW_NOTE_STYLE, GATE_COLOR, LEFT_AXIS_WIDTH,
                               LEGEND_TIPS, LEGENDS, MAX_WINDOW_S, OFF_COLOR, PLOTS,
                               REJECTED_COLOR, CurveSpec, PlotSpec)


class PlotPanelBuild:
    """Builds the PlotPanel's toolbar, tabs, plots and curves."""

    def _build_toolbar(self) -> QtWidgets.QHBoxLayout:
        toolbar = QtWidgets.QHBoxLayout()
        toolbar.setContentsMargins(2, 0, 2, 0)
        toolbar.addWidget(QtWidgets.QLabel("Window"))
        self.window_spin = QtWidgets.QDoubleSpinBox()
        self.window_spin.setRange(1.0, MAX_WINDOW_S)
        self.window_spin.setDecimals(0)
        self.window_spin.setSingleStep(5.0)
        self.window_spin.setSuffix(" s")
        self.window_spin.setValue(DEFAULT_WINDOW_S)
        self.window_spin.setToolTip("Length of the rolling window while following")
        self.window_spin.valueChanged.connect(self._mark_dirty)
        self.pause_button = QtWidgets.QPushButton("Pause")
        self.pause_button.setCheckable(True)
        self.pause_button.setToolTip("Freeze the view to inspect it; samples keep being stored "
                                     "(Space when live)")
        self.pause_button.toggled.connect(lambda checked: self.set_paused(checked))
        self.follow_button = QtWidgets.QPushButton("Follow")
        self.follow_button.setObjectName("follow_button")
        self.follow_button.setToolTip("Show the newest samples again (a replay: its position; "
                                      "a seek, Home or Play follows it too)")
        self.follow_button.clicked.connect(self.follow)
        self.follow_button.setEnabled(False)        # following already
        # While not following: what the plots show instead, in a colour that stands out
        self.follow_note = ElidedLabel("", minimum_text="not following…")
        self.follow_note.setObjectName("follow_note")
        self.follow_note.setStyleSheet(FOLLOW_NOTE_STYLE)
        self.follow_note.setVisible(False)
        self.cursor_checkbox = QtWidgets.QCheckBox("Cursor")
        self.cursor_checkbox.setToolTip("A draggable line reading every visible curve")
        self.cursor_checkbox.toggled.connect(self.set_cursor_visible)
        self.unwrap_checkbox = QtWidgets.QCheckBox("Unwrap angles")
        self.unwrap_checkbox.setToolTip("Euler angles continuous over whole turns (OWN and PHONE "
                                        "in the same turn) instead of wrapped to ±180°")
        self.unwrap_checkbox.toggled.connect(self.set_unwrapped)
        self.clear_button = QtWidgets.QPushButton("Clear")
        self.clear_button.setToolTip("Forget the plotted samples (Ctrl+L)")
        self.clear_button.clicked.connect(self.clear)
        for widget in (self.window_spin, self.pause_button, self.follow_button,
                       self.cursor_checkbox, self.unwrap_checkbox, self.clear_button):
            toolbar.addWidget(widget)
        toolbar.addWidget(self.follow_note)
        toolbar.addStretch(1)
        return toolbar

    def _build_group(self, key: str) -> PlotGroup:
        widget = QtWidgets.QWidget()
        widget.setObjectName(f"plot_group_{key}")
        box = QtWidgets.QVBoxLayout(widget)
        box.setContentsMargins(0, 0, 0, 0)
        box.setSpacing(0)
        legend = QtWidgets.QWidget()
        legend.setObjectName(f"legend_{key}")
        row = QtWidgets.QHBoxLayout(legend)
        row.setContentsMargins(LEFT_AXIS_WIDTH, 0, 0, 0)
        row.setSpacing(4)
        graphics = pg.GraphicsLayoutWidget()
        graphics.setBackground((250, 250, 252))
        # Every curve moves on every frame: keeping Qt's spatial index (a BSP tree) of the
        # items up to date costs more than it saves.
        graphics.scene().setItemIndexMethod(QtWidgets.QGraphicsScene.ItemIndexMethod.NoIndex)
        group = PlotGroup(key, widget, graphics, legend)
        for name, color, style in LEGENDS[key]:
            button = QtWidgets.QToolButton()
            button.setText(name)
            button.setIcon(legend_icon(color, style))
            button.setToolButtonStyle(QtCore.Qt.ToolButtonStyle.ToolButtonTextBesideIcon)
            button.setCheckable(True)
            button.setChecked(True)
            button.setAutoRaise(True)
            button.setToolTip(f"Show or hide {LEGEND_TIPS.get(name, name)}")
            button.toggled.connect(lambda checked, g=key, n=name: self.set_shown(g, n, checked))
            row.addWidget(button)
            group.toggles[name] = button
        row.addStretch(1)
        box.addWidget(legend)
        box.addWidget(graphics, 1)
        specs = [spec for spec in PLOTS if spec.group == key]
        for index, spec in enumerate(specs):
            self._new_plot(group, spec, last=index == len(specs) - 1)
        return group

    def _new_plot(self, group: PlotGroup, spec: PlotSpec, last: bool) -> pg.PlotItem:
        axis = TimeAxis("bottom")
        plot = group.graphics.addPlot(row=len(group.plots), col=0, axisItems={"bottom": axis})
        plot.setLabel("left", spec.title, units=spec.units)
        left = plot.getAxis("left")
        left.enableAutoSIPrefix(False)
        left.setWidth(LEFT_AXIS_WIDTH)
        left.setToolTip(spec.tooltip)
        for name in ("left", "bottom"):
            # Fewer tick levels: the time axis is regenerated on every frame while following.
            plot.getAxis(name).setStyle(maxTickLevel=1, maxTextLevel=1)
        # The y axis changes only when the y range does: paint it from a cached pixmap.
        cache_painting(left)
        # Clipping and peak downsampling are done here, in numpy, once per stream and frame;
        # y follows the visible samples (computed in refresh()).
        plot.setClipToView(False)
        plot.setDownsampling(ds=1, auto=False, mode="peak")
        plot.disableAutoRange()
        plot.getViewBox().setMouseEnabled(x=True, y=False)
        plot.setMenuEnabled(True)
        if last:
            plot.setLabel("bottom", "time since start", units="s")
        else:
            # Only the bottom plot of a tab shows time: the others share it.
            plot.hideAxis("bottom")
        cursor = pg.InfiniteLine(angle=90, movable=True, pen=pg.mkPen((120, 60, 160), width=1.5))
        cursor.setVisible(False)
        cursor.sigPositionChanged.connect(self._on_cursor_moved)
        plot.addItem(cursor, ignoreBounds=True)
        self.cursors[spec.key] = cursor
        view_box = plot.getViewBox()
        view_box.sigRangeChangedManually.connect(self._on_manual_range)
        view_box.sigXRangeChanged.connect(self._on_x_range_changed)
        if spec.key in ("acc", "mag"):
            band = Curve(pen=pg.mkPen(REJECTED_COLOR, width=4), antialias=False)
            plot.addItem(band, ignoreBounds=True)
            self.bands[spec.key] = band
            off = Curve(pen=pg.mkPen(OFF_COLOR, width=4, style=QtCore.Qt.PenStyle.DashLine),
                        antialias=False)
            plot.addItem(off, ignoreBounds=True)
            self.off_bands[spec.key] = off
            pen = pg.mkPen(GATE_COLOR, width=1, style=QtCore.Qt.PenStyle.DashLine)
            lines = (pg.InfiniteLine(angle=0, pen=pen), pg.InfiniteLine(angle=0, pen=pen))
            for line in lines:
                line.setVisible(False)
                plot.addItem(line, ignoreBounds=True)
            self.gate_lines[spec.key] = lines
        group.plots.append(spec.key)
        self.plots[spec.key] = plot
        self.no_data_items[spec.key] = NoDataText(view_box)
        return plot

    def _add_curve(self, spec: CurveSpec) -> None:
        # 1-px pens without antialiasing: Qt's fast line path (dashes cost more: PHONE and
        # YOURS only).
        style = (QtCore.Qt.PenStyle.DashLine if spec.dashed else
                 QtCore.Qt.PenStyle.DotLine if spec.dotted else QtCore.Qt.PenStyle.SolidLine)
        curve = Curve(pen=pg.mkPen(spec.color, width=1, style=style), antialias=False)
        self.plots[spec.plot].addItem(curve)
        self.curves.append((spec, curve))
