"""Engine failures, shown: a dialog with the one-line message, the whole traceback on demand and
a "Copy details" button (for a bug report). Non-modal: the window keeps drawing while it is open.
"""

from __future__ import annotations

from pathlib import Path

from PySide6 import QtGui, QtWidgets

from app.engine.errors import EngineFailure


class FailureDialog(QtWidgets.QDialog):
    """Shows the latest engine failure; :meth:`show_failure` replaces what it shows."""

    def __init__(self, parent: QtWidgets.QWidget | None = None,
                 log_path: Path | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("failure_dialog")
        self.setWindowTitle("Orientation Lab: engine error")
        self.setModal(False)
        self.log_path = log_path
        self.failure: EngineFailure | None = None
        self.message = QtWidgets.QLabel()
        self.message.setWordWrap(True)
        self.message.setTextInteractionFlags(
            self.message.textInteractionFlags() | QtGui.Qt.TextInteractionFlag.TextSelectableByMouse)
        self.outcome = QtWidgets.QLabel()
        self.outcome.setWordWrap(True)
        self.details = QtWidgets.QPlainTextEdit()
        self.details.setReadOnly(True)
        self.details.setVisible(False)
        self.details.setMinimumHeight(220)
        self.details_button = QtWidgets.QPushButton("Show details")
        self.details_button.setCheckable(True)
        self.details_button.toggled.connect(self._show_details)
        self.copy_button = QtWidgets.QPushButton("Copy details")
        self.copy_button.clicked.connect(self.copy_details)
        close = QtWidgets.QPushButton("Close")
        close.clicked.connect(self.hide)
        buttons = QtWidgets.QHBoxLayout()
        buttons.addWidget(self.details_button)
        buttons.addWidget(self.copy_button)
        buttons.addStretch(1)
        buttons.addWidget(close)
        layout = QtWidgets.QVBoxLayout(self)
        layout.addWidget(self.message)
        layout.addWidget(self.outcome)
        layout.addWidget(self.details, 1)
        layout.addLayout(buttons)
        self.resize(640, 200)

    def show_failure(self, failure: EngineFailure, total: int) -> None:
        self.failure = failure
        self.message.setText(f"<b>The engine hit an error</b> (#{failure.number}, "
                             f"{failure.when} UTC):<br>{_escape(failure.message)}")
        then = ("The engine stopped: it failed several times in a row. Open the source again "
                "to retry." if failure.fatal else
                "The batch of samples it was working on was skipped; the engine goes on.")
        where = f" Details are also in {self.log_path}." if self.log_path else ""
        more = f" ({total} errors so far.)" if total > 1 else ""
        self.outcome.setText(then + more + where)
        self.details.setPlainText(failure.details)
        self.show()
        self.raise_()

    def copy_details(self) -> None:
        if self.failure is not None:
            QtWidgets.QApplication.clipboard().setText(
                f"{self.failure.message}\n\n{self.failure.details}")

    def _show_details(self, visible: bool) -> None:
        self.details.setVisible(visible)
        self.details_button.setText("Hide details" if visible else "Show details")
        self.adjustSize()


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
