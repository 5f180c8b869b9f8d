"""What a user sees cut in the window: widgets pushed past the edge of what holds them, texts
and buttons squeezed below the size they need, tables whose columns do not all show, a window
wider than its screen. Each finding is one line naming the widget (empty list: nothing cut).

Used by the small-screen test (tests/ui/small_screen_window.py, a whole window on a 1280x720
screen with a live stream and a recording) and by widget tests.
"""

from __future__ import annotations

from PySide6 import QtCore, QtWidgets

from app.ui.elided import ElidedLabel

CHECKED = (QtWidgets.QLabel, QtWidgets.QAbstractButton, QtWidgets.QComboBox,
           QtWidgets.QLineEdit, QtWidgets.QAbstractSpinBox, QtWidgets.QSlider,
           QtWidgets.QProgressBar)
SLACK_PX = 1


def describe(widget: QtWidgets.QWidget) -> str:
    """"QPushButton 'Reset filter' in filter_dock" (its text, or its object name)."""
    text = ""
    if hasattr(widget, "text") and callable(widget.text):
        text = str(widget.text())[:40]
    name = widget.objectName() or text
    holder = widget.parentWidget()
    while holder is not None and not holder.objectName():
        holder = holder.parentWidget()
    where = f" in {holder.objectName()}" if holder is not None else ""
    return f"{type(widget).__name__} {name!r}{where}"


def _ancestor(widget: QtWidgets.QWidget, kind: type) -> QtWidgets.QWidget | None:
    parent = widget.parentWidget()
    while parent is not None:
        if isinstance(parent, kind):
            return parent
        parent = parent.parentWidget()
    return None


def _behind_a_tab(widget: QtWidgets.QWidget) -> bool:
    """Whether the widget is in a dock tabbed behind another (shown when its tab is chosen)."""
    dock = _ancestor(widget, QtWidgets.QDockWidget)
    return dock is not None and dock.visibleRegion().isEmpty()


def _squeezed(widget: QtWidgets.QWidget) -> str:
    """Why the widget has less room than it needs ("" when it has enough)."""
    if isinstance(widget, ElidedLabel):
        return ""                    # cuts its text on purpose, whole in its tooltip
    hint = widget.minimumSizeHint()
    if isinstance(widget, QtWidgets.QLabel):
        if widget.wordWrap():
            needed = widget.heightForWidth(widget.width())
            if needed > widget.height() + SLACK_PX:
                return f"text needs {needed} px of height, has {widget.height()}"
            return ""
        hint = widget.sizeHint()     # a label's whole text
    if widget.width() + SLACK_PX < hint.width():
        return f"needs {hint.width()} px of width, has {widget.width()}"
    if widget.height() + SLACK_PX < hint.height():
        return f"needs {hint.height()} px of height, has {widget.height()}"
    return ""


def clipped(window: QtWidgets.QWidget,
            whole: tuple[QtWidgets.QScrollArea, ...] = ()) -> list[str]:
    """Everything cut in the window as it is shown now.

    A widget in a scroll area may be cut at the top or bottom (the area scrolls) unless that
    area is one of `whole` (e.g. the Filter dock's, which must show its switches without
    scrolling); cut at the side it is always a finding (the docks never scroll sideways)."""
    findings = []
    for widget in window.findChildren(QtWidgets.QWidget):
        if not isinstance(widget, CHECKED) or not widget.isVisible():
            continue
        if widget.width() <= 0 or widget.height() <= 0 or _behind_a_tab(widget):
            continue
        if isinstance(widget.parentWidget(), (QtWidgets.QAbstractSpinBox,
                                               QtWidgets.QComboBox)):
            continue                 # a spin box's or combo box's own line edit
        if isinstance(widget, QtWidgets.QAbstractButton) and isinstance(
                widget.parentWidget(), (QtWidgets.QTabBar, QtWidgets.QScrollBar,
                                        QtWidgets.QDockWidget)):
            continue                 # tab scrollers, a dock's float and close buttons
        seen = widget.visibleRegion().boundingRect()
        area = _ancestor(widget, QtWidgets.QScrollArea)
        if seen.isEmpty() and area is not None:        # scrolled out of the view
            if area in whole:
                findings.append(f"{describe(widget)}: out of view in a panel that must show "
                                "it whole")
        elif seen.width() + SLACK_PX < widget.width():
            findings.append(f"{describe(widget)}: cut at the side ({seen.width()} of "
                            f"{widget.width()} px shown)")
        elif seen.height() + SLACK_PX < widget.height() and (area is None or area in whole):
            findings.append(f"{describe(widget)}: cut at the top or bottom ({seen.height()} of "
                            f"{widget.height()} px shown)")
        why = _squeezed(widget)
        if why:
            findings.append(f"{describe(widget)}: {why}")
    return findings


def hidden_columns(table: QtWidgets.QTableView) -> list[str]:
    """The columns of a shown table that do not fit its viewport (it would scroll sideways)."""
    if not table.isVisible():
        return []
    header = table.horizontalHeader()
    right = max((header.sectionViewportPosition(c) + header.sectionSize(c)
                 for c in range(header.count()) if not header.isSectionHidden(c)), default=0)
    if right <= table.viewport().width() + SLACK_PX and header.offset() == 0:
        return []
    model = table.model()
    return [str(model.headerData(c, QtCore.Qt.Orientation.Horizontal))
            for c in range(header.count())
            if header.sectionViewportPosition(c) + header.sectionSize(c)
            > table.viewport().width() + SLACK_PX or header.sectionViewportPosition(c) < 0]


def scrolls(scroll: QtWidgets.QScrollArea) -> bool:
    """Whether a scroll area's content is taller than what it shows (it scrolls)."""
    content = scroll.widget()
    return content is not None and content.sizeHint().height() > scroll.viewport().height()
