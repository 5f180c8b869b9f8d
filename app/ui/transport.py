"""The transport bar under the plots: play/pause, speed, loop, a time slider and the position
as time since the session's start. Always visible; greyed out (and saying why) when the source
is not a replay.

It only forwards intent (ReplayControl commands) and follows the replay's state from the
snapshots (Snapshot.replay: position_s, duration_s, speed, paused, loop, finished).
"""

from __future__ import annotations

from typing import Any, Callable

from PySide6 import QtCore, QtWidgets

from app.engine.commands import ReplayControl
from app.ui.plot_data import time_text

SEEK_STEPS = 10_000
SPEEDS = ((0.1, "0.1×"), (0.25, "0.25×"), (0.5, "0.5×"), (1.0, "1×"), (2.0, "2×"), (5.0, "5×"),
          (10.0, "10×"), (0.0, "max"))


def position_text(position_s: float, duration_s: float) -> str:
    """"m:ss.s / m:ss.s" (or seconds for short logs)."""
    span = max(duration_s, position_s)
    long = span >= 60.0
    return (f"{time_text(position_s, 300.0 if long else 0.0, 1)} / "
            f"{time_text(duration_s, 300.0 if long else 0.0, 1)}" + ("" if long else " s"))


class TransportBar(QtWidgets.QFrame):
    """Replay controls. `send(command)` forwards ReplayControl commands."""

    def __init__(self, send: Callable[[object], None],
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName("transport_bar")
        self.setFrameShape(QtWidgets.QFrame.Shape.StyledPanel)
        self.setSizePolicy(QtWidgets.QSizePolicy.Policy.Preferred,
                           QtWidgets.QSizePolicy.Policy.Fixed)
        self._send = send
        self._seeking = False
        self._replay: dict[str, Any] | None = None
        layout = QtWidgets.QHBoxLayout(self)
        layout.setContentsMargins(4, 2, 4, 2)
        self.play_button = QtWidgets.QToolButton()
        self.play_button.setObjectName("play_button")
        self.play_button.setToolButtonStyle(QtCore.Qt.ToolButtonStyle.ToolButtonTextBesideIcon)
        self.play_button.setMinimumWidth(84)
        self._icons = {"Play": self.style().standardIcon(
            QtWidgets.QStyle.StandardPixmap.SP_MediaPlay), "Pause": self.style().standardIcon(
            QtWidgets.QStyle.StandardPixmap.SP_MediaPause)}
        self._show_play(True)
        self.play_button.setToolTip("Play / pause the replay (Space)")
        self.play_button.clicked.connect(self.toggle_paused)
        self.speed_combo = QtWidgets.QComboBox()
        for speed, label in SPEEDS:
            self.speed_combo.addItem(label, speed)
        self.speed_combo.setCurrentIndex(3)
        self.speed_combo.setToolTip("Replay speed (max: as fast as possible)")
        self.speed_combo.activated.connect(
            lambda index: self._send(ReplayControl(speed=float(self.speed_combo.itemData(index)))))
        self.loop_checkbox = QtWidgets.QCheckBox("Loop")
        self.loop_checkbox.clicked.connect(lambda checked: self._send(ReplayControl(loop=checked)))
        self.slider = QtWidgets.QSlider(QtCore.Qt.Orientation.Horizontal)
        self.slider.setObjectName("seek_slider")
        self.slider.setRange(0, SEEK_STEPS)
        self.slider.setToolTip("Drag or click to jump (the filter is re-run up to there)")
        self.slider.sliderPressed.connect(self._on_seek_pressed)
        self.slider.sliderReleased.connect(self._on_seek_released)
        # Clicks on the groove and arrow keys change the value without a drag.
        self.slider.valueChanged.connect(self._on_seek_value_changed)
        self.position_label = QtWidgets.QLabel("–")
        self.position_label.setObjectName("position_label")
        self.position_label.setMinimumWidth(130)
        self.position_label.setAlignment(QtCore.Qt.AlignmentFlag.AlignRight
                                         | QtCore.Qt.AlignmentFlag.AlignVCenter)
        self.source_label = QtWidgets.QLabel("")
        self.source_label.setStyleSheet("color: #666;")
        for widget in (self.play_button, self.speed_combo, self.loop_checkbox):
            layout.addWidget(widget)
        layout.addWidget(self.slider, 1)
        layout.addWidget(self.position_label)
        layout.addWidget(self.source_label)
        self.update_replay(None)

    @property
    def replaying(self) -> bool:
        return self._replay is not None

    # ---- snapshot -> widgets --------------------------------------------------------------

    def update_replay(self, replay: dict[str, Any] | None, source: str = "") -> None:
        """Follow the replay's state (every frame: only changed widgets are touched)."""
        self._replay = replay
        enabled = replay is not None
        for widget in (self.play_button, self.speed_combo, self.loop_checkbox, self.slider):
            if widget.isEnabled() != enabled:
                widget.setEnabled(enabled)
        if replay is None:
            _set_text(self.position_label, "live")
            _set_text(self.source_label, source or "not a replay")
            return
        _set_text(self.source_label, source)
        finished = bool(replay.get("finished", False))
        paused = bool(replay.get("paused", False)) or finished
        self._show_play(paused)
        speed = float(replay.get("speed", 1.0))
        index = self.speed_combo.findData(speed)
        if index < 0:
            self.speed_combo.addItem(f"{speed:g}×", speed)
            index = self.speed_combo.count() - 1
        if index != self.speed_combo.currentIndex():
            self.speed_combo.setCurrentIndex(index)
        if self.loop_checkbox.isChecked() != bool(replay.get("loop", False)):
            self.loop_checkbox.setChecked(bool(replay.get("loop", False)))
        position = float(replay.get("position_s", 0.0))
        duration = float(replay.get("duration_s", 0.0))
        if not self._seeking and duration > 0:
            value = int(round(SEEK_STEPS * min(position / duration, 1.0)))
            if value != self.slider.value():
                self.slider.blockSignals(True)
                self.slider.setValue(value)
                self.slider.blockSignals(False)
        _set_text(self.position_label, position_text(position, duration))

    # ---- user intent -> commands ----------------------------------------------------------

    def toggle_paused(self) -> None:
        if self._replay is None:
            return
        finished = bool(self._replay.get("finished", False))
        paused = not bool(self._replay.get("paused", False))
        if finished:          # at the end: Play starts again from the beginning
            self._send(ReplayControl(seek_s=0.0, paused=False))
            paused = False
        else:
            self._send(ReplayControl(paused=paused))
        self._replay = {**self._replay, "paused": paused, "finished": False}
        self._show_play(paused)

    def _show_play(self, paused: bool) -> None:
        """The button offers what a click does: Play when paused (or at the end), else Pause."""
        text = "Play" if paused else "Pause"
        if self.play_button.text() != text:
            self.play_button.setText(text)
            self.play_button.setIcon(self._icons[text])

    def _on_seek_pressed(self) -> None:
        self._seeking = True

    def _on_seek_released(self) -> None:
        self._seeking = False
        self.seek_to_fraction(self.slider.value() / SEEK_STEPS)

    def _on_seek_value_changed(self, value: int) -> None:
        if not self._seeking and not self.slider.isSliderDown():
            self.seek_to_fraction(value / SEEK_STEPS)

    def seek_to_fraction(self, fraction: float) -> None:
        if self._replay is None:
            return
        duration = float(self._replay.get("duration_s", 0.0))
        self._send(ReplayControl(seek_s=max(0.0, min(fraction, 1.0)) * duration))


def _set_text(widget, text: str) -> None:
    if widget.text() != text:
        widget.setText(text)
