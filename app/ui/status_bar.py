"""The main window's status bar: its message is cut with "…" to the room the permanent texts
(connection, time, rates, frames per second) leave it, so it never runs into them; the whole
message is its tooltip and what currentMessage() gives."""

from __future__ import annotations

from PySide6 import QtCore, QtWidgets

MESSAGE_MARGIN_PX = 18
"""The room kept between the message and the first permanent text (and the left edge)."""
MIN_ROOM_PX = 40


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
