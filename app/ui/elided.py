"""A one-line label that may be narrower than its text: it shows what fits, cut with "…" (at
the end or in the middle), and the whole text in its tooltip. Its minimum width is a few
characters, so a growing text (a recording's size, a peer's address, a file name) never widens
the panel or the window it sits in."""

from __future__ import annotations

from PySide6 import QtCore, QtGui, QtWidgets

MIN_CHARACTERS = "…"


class ElidedLabel(QtWidgets.QLabel):
    """QLabel for one line of plain text: text() is the whole text, shown_text() what is drawn
    at the current width (elided with `mode`). sizeHint is the whole text (at most
    maximumWidth); minimumSizeHint `minimum_text`'s width."""

    def __init__(self, text: str = "", parent: QtWidgets.QWidget | None = None,
                 mode: QtCore.Qt.TextElideMode = QtCore.Qt.TextElideMode.ElideRight,
                 minimum_text: str = MIN_CHARACTERS) -> None:
        super().__init__(text, parent)
        self._mode = mode
        self._minimum_text = minimum_text
        self._shorter: tuple[str, ...] = ()
        self.setSizePolicy(QtWidgets.QSizePolicy.Policy.Preferred,
                           QtWidgets.QSizePolicy.Policy.Preferred)
        self.setToolTip(text)

    def minimumSizeHint(self) -> QtCore.QSize:  # noqa: N802 (Qt name)
        margins = self.contentsMargins()
        width = (self.fontMetrics().horizontalAdvance(self._minimum_text) + 4
                 + margins.left() + margins.right())
        return QtCore.QSize(min(width, self.maximumWidth()), super().minimumSizeHint().height())

    def sizeHint(self) -> QtCore.QSize:  # noqa: N802 (Qt name)
        margins = self.contentsMargins()
        width = (self.fontMetrics().horizontalAdvance(self.text()) + 4 + margins.left()
                 + margins.right())
        return QtCore.QSize(max(min(width, self.maximumWidth()), self.minimumSizeHint().width()),
                            super().sizeHint().height())

    def setText(self, text: str, shorter: tuple[str, ...] = ()) -> None:  # noqa: N802
        """`text`, and `shorter` forms of it to show, in order, when it does not fit (the
        last one is cut with "…" when none fits)."""
        self._shorter = tuple(shorter)
        if text == self.text():
            return
        super().setText(text)
        self.setToolTip(text)
        self.updateGeometry()

    def shown_text(self) -> str:
        """The text as drawn at the label's width now."""
        room = max(self.contentsRect().width(), 0)
        metrics = self.fontMetrics()
        for text in (self.text(), *self._shorter):
            if metrics.horizontalAdvance(text) <= room:
                return text
        last = self._shorter[-1] if self._shorter else self.text()
        return metrics.elidedText(last, self._mode, room)

    def paintEvent(self, event: QtGui.QPaintEvent) -> None:  # noqa: N802 (Qt name)
        painter = QtGui.QPainter(self)
        painter.setPen(self.palette().color(QtGui.QPalette.ColorRole.WindowText))
        painter.drawText(self.contentsRect(), int(self.alignment()
                                                  | QtCore.Qt.AlignmentFlag.AlignVCenter),
                         self.shown_text())
