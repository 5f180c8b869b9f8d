"""Texts cut to their room with "…", the whole text in their tooltip, so a growing text (a
recording's size, a peer's address, a file name, a long message) never widens the panel or the
window it sits in:

* ElidedLabel: a one-line label that may be narrower than its text: it shows what fits, cut
  at the end or in the middle (or a shorter form of it). Its minimum width is a few characters.
* ElidingStatusBar: the main window's status bar; its message is cut to the room the permanent
  texts (connection, time, rates, frames per second) leave it, so it never runs into them; the
  whole message is its tooltip and what currentMessage() gives.
"""

from __future__ import annotations

from PySide6 import QtCore, QtGui, QtWidgets

MIN_CHARACTERS = "…"
MESSAGE_MARGIN_PX = 18
"""The room kept between the message and the first permanent text (and the left edge)."""
MIN_ROOM_PX = 40


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


class ElidingStatusBar(QtWidgets.QStatusBar):
    """A QStatusBar whose temporary message is elided to the room left of its permanent
    widgets, again whenever that room changes."""

    def __init__(self, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self._message = ""
        self._permanent: list[QtWidgets.QWidget] = []
        self._timer = QtCore.QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.timeout.connect(self.clearMessage)
        self.messageChanged.connect(self._on_changed)

    def addPermanentWidget(self, widget: QtWidgets.QWidget, stretch: int = 0) -> None:
        super().addPermanentWidget(widget, stretch)
        self._permanent.append(widget)

    def showMessage(self, text: str, timeout: int = 0) -> None:
        self._message = text
        self.setToolTip(text)
        self._timer.stop()
        super().showMessage(self._elided(text), 0)
        if timeout > 0:
            self._timer.start(timeout)

    def currentMessage(self) -> str:
        return self._message if super().currentMessage() else ""

    def message_room(self) -> int:
        """The pixels the message may use: up to the first permanent text that is shown."""
        shown = [widget for widget in self._permanent if widget.isVisible()]
        if shown and self.isVisible():
            right = min(widget.geometry().left() for widget in shown)
        else:
            right = self.width() - sum(widget.sizeHint().width() + 6 for widget in shown)
        return max(0, right - MESSAGE_MARGIN_PX)

    def _elided(self, text: str) -> str:
        room = self.message_room()
        if room < MIN_ROOM_PX:
            return text         # not laid out yet: cut once it is
        return self.fontMetrics().elidedText(text, QtCore.Qt.TextElideMode.ElideRight,
                                             room)

    def _on_changed(self, shown: str) -> None:
        if not shown:
            self._timer.stop()
            self._message = ""
            self.setToolTip("")

    def resizeEvent(self, event) -> None:
        super().resizeEvent(event)
        self._refit()

    def event(self, event: QtCore.QEvent) -> bool:
        handled = super().event(event)
        if event.type() == QtCore.QEvent.Type.LayoutRequest:
            self._refit()
        return handled

    def _refit(self) -> None:
        """The current message again to the room there is now (a permanent text grew)."""
        if not self._message or not super().currentMessage():
            return
        elided = self._elided(self._message)
        if elided != super().currentMessage():
            super().showMessage(elided, 0)
