"""A plot's no-data message ("no gyroscope in this stream"), centred over the plot instead of
an empty axis."""

from __future__ import annotations

import pyqtgraph as pg
from PySide6 import QtGui, QtWidgets


class NoDataText(QtWidgets.QGraphicsSimpleTextItem):
    """A plot's no-data message, centred in its view box (in the box's own pixels, so it stays
    put whatever range the plot shows)."""

    def __init__(self, view_box: pg.ViewBox) -> None:
        super().__init__(view_box)
        self.setBrush(QtGui.QBrush(QtGui.QColor(110, 112, 118)))
        font = self.font()
        if font.pointSizeF() > 0:
            font.setPointSizeF(font.pointSizeF() * 1.15)
            self.setFont(font)
        self.setZValue(1000)
        self.setVisible(False)
        self._view_box = view_box
        view_box.sigResized.connect(self._centre)

    def set_text(self, text: str) -> None:
        if text == self.text():
            return
        self.setText(text)
        self.setVisible(bool(text))
        self._centre()

    def _centre(self, *args) -> None:
        box = self._view_box.boundingRect()
        own = self.boundingRect()
        self.setPos(box.center().x() - own.width() / 2, box.center().y() - own.height() / 2)
