"""The graphics items the live plots are made of: a curve whose bounds come with its data, the
time axis, the legend icons, and one tab's group of plots.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtGui, QtWidgets

from app.ui.plot_data import time_text


class Curve(pg.PlotCurveItem):
    """A PlotCurveItem whose bounds come with the data (computed in numpy by the panel).

    pyqtgraph recomputes a curve's bounds, with pixel padding, every time the view moves,
    i.e. on every frame while following; here they are set once per setData.
    """

    def __init__(self, **options) -> None:
        self._rect = QtCore.QRectF()
        super().__init__(**options)

    def set_curve(self, x: np.ndarray, y: np.ndarray, finite: bool,
                  y_bounds: tuple[float, float] | None, connect: str | None = None) -> None:
        """New points; `finite`: no NaN in y (the fast path); y_bounds: (min, max) of y."""
        if len(x) and y_bounds is not None:
            low, high = y_bounds
            x_pad = 0.01 * max(float(x[-1] - x[0]), 1e-9)
            y_pad = 0.02 * max(high - low, 1e-9)
            self._rect = QtCore.QRectF(float(x[0]) - x_pad, low - y_pad,
                                       float(x[-1] - x[0]) + 2 * x_pad, high - low + 2 * y_pad)
        else:
            self._rect = QtCore.QRectF()
        self.setData(x, y, connect=connect or ("all" if finite else "finite"),
                     skipFiniteCheck=finite)

    def dataBounds(self, ax: int, frac: float = 1.0, orthoRange=None):  # noqa: N802 (pg name)
        if self._rect.isNull():
            return (None, None)
        if ax == 0:
            return (self._rect.left(), self._rect.right())
        return (self._rect.top(), self._rect.bottom())

    def boundingRect(self) -> QtCore.QRectF:  # noqa: N802 (Qt name)
        return self._rect


class TimeAxis(pg.AxisItem):
    """Seconds since the session's start ("m:ss" for long views); the phone's clock on hover."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.origin_ms: int | None = None
        self.enableAutoSIPrefix(False)

    def tickStrings(self, values, scale, spacing):  # noqa: N802 (pg name)
        low, high = self.range
        span = abs(high - low)
        decimals = 0 if spacing >= 1.0 else (1 if spacing >= 0.1 else 2)
        return [time_text(v, span, decimals) for v in values]

    def set_origin(self, origin_ms: int | None) -> None:
        if origin_ms == self.origin_ms:
            return
        self.origin_ms = origin_ms
        self.setToolTip("" if origin_ms is None else
                        f"time since the session's start; 0 is {origin_ms / 1000.0:.3f} s on "
                        "the phone's clock")


def cache_painting(item: QtWidgets.QGraphicsItem) -> None:
    """Paint `item` and its children from pixmaps redrawn only when they call update():
    axis titles are text, and laying out text is the slowest part of a frame."""
    item.setCacheMode(QtWidgets.QGraphicsItem.CacheMode.DeviceCoordinateCache)
    for child in item.childItems():
        cache_painting(child)


def legend_icon(color: tuple[int, int, int], style: str) -> QtGui.QIcon:
    pixmap = QtGui.QPixmap(22, 12)
    pixmap.fill(QtCore.Qt.GlobalColor.transparent)
    painter = QtGui.QPainter(pixmap)
    if style == "band":
        painter.fillRect(QtCore.QRectF(1, 8, 20, 3), QtGui.QColor(*color))
    elif style == "dashed band":
        for x in (1, 9, 17):
            painter.fillRect(QtCore.QRectF(x, 8, 5, 3), QtGui.QColor(*color))
    else:
        pen = QtGui.QPen(QtGui.QColor(*color), 2)
        if style == "dash":
            pen.setStyle(QtCore.Qt.PenStyle.DashLine)
        elif style == "dot":
            pen.setStyle(QtCore.Qt.PenStyle.DotLine)
        painter.setPen(pen)
        painter.drawLine(1, 6, 21, 6)
    painter.end()
    return QtGui.QIcon(pixmap)


@dataclass
class PlotGroup:
    """One tab: its legend toggles and its plots in one graphics view."""

    key: str
    widget: QtWidgets.QWidget
    graphics: pg.GraphicsLayoutWidget
    legend: QtWidgets.QWidget
    toggles: dict[str, QtWidgets.QToolButton] = field(default_factory=dict)
    plots: list[str] = field(default_factory=list)
