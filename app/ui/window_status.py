"""The main window's slow text and its frame count: the status bar (connection state, time,
rates, frames per second, the newest warning) and the panels that follow the latest snapshot
at PANEL_INTERVAL_S (the comparison table, the connection, your filter); the frames counted
are frames actually painted, not timer ticks.

A mixin of MainWindow: its methods use the window's panels, plots and views.
"""

from __future__ import annotations

import time

from PySide6 import QtCore, QtWidgets

from app.engine.snapshot import Snapshot
from app.stream.protocol import FILTER_TAGS
from app.ui.connection import connection_text
from app.ui.status_bar import ElidingStatusBar


class WindowStatus:
    """The status bar, the slow panels and the painted-frame counter."""

    def _build_status_bar(self) -> None:
        bar = ElidingStatusBar()
        self.setStatusBar(bar)
        self.state_status = QtWidgets.QLabel("waiting")
        self.time_status = QtWidgets.QLabel("t = –")
        self.rates_status = QtWidgets.QLabel("")
        self.fps_status = QtWidgets.QLabel("")
        # the texts that change every refresh keep the width of their widest value, so the
        # status bar's layout does not jump (nor cut the last one) as they change
        metrics = self.fps_status.fontMetrics()
        self.fps_status.setMinimumWidth(metrics.horizontalAdvance("888 fps") + 4)
        self.time_status.setMinimumWidth(metrics.horizontalAdvance("t = 8888.8 s") + 4)
        for label in (self.state_status, self.time_status, self.rates_status, self.fps_status):
            bar.addPermanentWidget(label)


    def refresh_panels(self) -> None:
        """Show the latest snapshot in the comparison table, connection panel and status bar
        (called from tick() at most every PANEL_INTERVAL_S)."""
        snapshot = self._panel_snapshot
        self._panel_snapshot = None
        self._panels_shown_at = time.monotonic()
        _set_text(self.fps_status, f"{self.frames_per_second():.0f} fps")
        if snapshot is None:
            return
        self.comparison.update_comparisons(snapshot.comparisons, snapshot.comparison_estimator,
                                           self._absent)
        self.connection.update_health(snapshot.health)
        self.user_panel.update_status(snapshot.user)
        self._update_status_bar(snapshot)

    def _update_status_bar(self, snapshot: Snapshot) -> None:
        health = snapshot.health
        _set_text(self.state_status, connection_text(health))
        if snapshot.t_ms is None or snapshot.t0_ms is None:
            _set_text(self.time_status, "t = –")
        else:
            _set_text(self.time_status, f"t = {(snapshot.t_ms - snapshot.t0_ms) / 1000.0:.1f} s")
            self.time_status.setToolTip(f"time since the session's start; the phone's clock: "
                                        f"{snapshot.t_ms / 1000.0:.3f} s")
        _set_text(self.rates_status, "  ".join(f"{tag} {rate:.0f} Hz"
                                               for tag, rate in sorted(health.rates_hz.items())
                                               if tag in FILTER_TAGS and rate > 0))
        if health.warnings and health.warnings[-1] != self._last_warning:
            self._last_warning = health.warnings[-1]
            self.statusBar().showMessage(self._last_warning, 8000)


    # ---- frame counting -------------------------------------------------------------------

    def _drawn_widgets(self) -> list[QtWidgets.QWidget]:
        """The widgets that change every frame: their paint events are the frames."""
        widgets = [group.graphics.viewport() for group in self.plots.groups.values()]
        for view in self.views():
            widgets.append(view.gl_view if view.gl_view is not None else view.placeholder)
        return widgets

    def _on_paint(self) -> None:
        # Qt paints all widgets changed in one event-loop pass together: count one frame
        # per display tick that got painted, however many widgets it repainted.
        if self._painted_tick == self.ticks:
            return
        self._painted_tick = self.ticks
        self.frames_painted += 1
        now = time.monotonic()
        self._frame_times.append(now)
        while self._frame_times and now - self._frame_times[0] > 1.0:
            self._frame_times.popleft()

    def frames_per_second(self) -> float:
        """Frames painted in the last second."""
        now = time.monotonic()
        while self._frame_times and now - self._frame_times[0] > 1.0:
            self._frame_times.popleft()
        return float(len(self._frame_times))


def _set_text(label: QtWidgets.QLabel, text: str) -> None:
    """Change a label only when its text changes (setText re-lays out and repaints)."""
    if label.text() != text:
        label.setText(text)


class PaintCounter(QtCore.QObject):
    """Event filter calling `on_paint()` for every paint event of the widgets it watches."""

    def __init__(self, on_paint) -> None:
        super().__init__()
        self._on_paint = on_paint

    def eventFilter(self, watched: QtCore.QObject, event: QtCore.QEvent) -> bool:  # noqa: N802
        if event.type() == QtCore.QEvent.Type.Paint:
            self._on_paint()
        return False
