"""The transport bar under the plots, in the style of Foxglove and PlotJuggler: record, step one
sample back, play/pause, step forward, speed (0.1× … 10×, max), loop, a time slider with the
markers on it (click one to jump there) and the position as m:ss.s since the session's start.
(What of a replayed recording's set-up is yours, and the way back to it, is in the Filter dock
and the Replay menu.)

Recording works whatever the source (the phone, a replay, the demo); the replay controls are
greyed out (saying why) when the source is not a replay. The bar only forwards intent
(commands) and follows the engine's state from the snapshots: Snapshot.replay (position_s,
duration_s, speed, paused, loop, finished, indexed, index_progress), Snapshot.recording and
Snapshot.markers. The window's keys (Space, ←/→ 1 s, Shift+←/→ 10 s, Ctrl+←/→ one sample,
Home/End) call :meth:`TransportBar.jump_by`,
:meth:`step`, :meth:`seek_to`.
"""

from __future__ import annotations

import math
from typing import Any, Callable

from PySide6 import QtCore, QtGui, QtWidgets

from app.engine.commands import ReplayControl, StartRecording, StopRecording
from app.ui.elided import ElidedLabel
from app.ui.plots import time_text

SEEK_STEPS = 10_000
SPEEDS = ((0.1, "0.1×"), (0.25, "0.25×"), (0.5, "0.5×"), (1.0, "1×"), (2.0, "2×"), (5.0, "5×"),
          (10.0, "10×"), (0.0, "max"))
MARKER_COLOR = (230, 120, 0)
SLIDER_MIN_WIDTH = 160      # px: the time slider stays usable however much else the bar shows
SLIDER_MIN_WIDTH_LIVE = 40  # px: no replay to move through
MARKER_HIT_PX = 6


def clock_text(seconds: float) -> str:
    """m:ss.s (h:mm:ss.s from an hour on)."""
    if seconds is None or not math.isfinite(seconds):
        return "–"
    return time_text(max(0.0, seconds), 300.0, 1) if seconds >= 60.0 else \
        f"0:{max(0.0, seconds):04.1f}"


def position_text(position_s: float, duration_s: float) -> str:
    """"m:ss.s / m:ss.s" since the session's start."""
    return f"{clock_text(position_s)} / {clock_text(duration_s)}"


def size_text(size: int) -> str:
    return f"{size / 2**20:.1f} MB" if size >= 2**20 else f"{size / 2**10:.0f} KB"


class MarkerSlider(QtWidgets.QSlider):
    """A time slider that draws the markers as ticks above its groove; a click on a tick
    emits marker_clicked(t_s), a click elsewhere on the groove jumps there."""

    marker_clicked = QtCore.Signal(float)

    def __init__(self) -> None:
        super().__init__(QtCore.Qt.Orientation.Horizontal)
        self.markers: list[tuple[float, str]] = []      # (fraction 0..1, title)
        self._times: list[float] = []
        self.setMinimumHeight(22)
        self.setMouseTracking(True)

    def set_markers(self, markers: list[Any], duration_s: float) -> None:
        ticks = []
        times = []
        for marker in markers:
            if marker.t_s is None or duration_s <= 0:
                continue
            ticks.append((min(max(marker.t_s / duration_s, 0.0), 1.0), marker.title))
            times.append(float(marker.t_s))
        if ticks != self.markers:
            self.markers, self._times = ticks, times
            self.update()

    def marker_x(self, fraction: float) -> int:
        """Where a marker at `fraction` of the way is drawn (px)."""
        option = QtWidgets.QStyleOptionSlider()
        self.initStyleOption(option)
        handle = self.style().subControlRect(QtWidgets.QStyle.ComplexControl.CC_Slider, option,
                                             QtWidgets.QStyle.SubControl.SC_SliderHandle, self)
        span = self.width() - handle.width()
        return int(round(handle.width() / 2 + fraction * span))

    def marker_at(self, x: float) -> int | None:
        best = None
        for index, (fraction, _) in enumerate(self.markers):
            distance = abs(self.marker_x(fraction) - x)
            if distance <= MARKER_HIT_PX and (best is None or distance < best[0]):
                best = (distance, index)
        return None if best is None else best[1]

    def paintEvent(self, event: QtGui.QPaintEvent) -> None:  # noqa: N802 (Qt name)
        super().paintEvent(event)
        if not self.markers:
            return
        painter = QtGui.QPainter(self)
        painter.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing)
        color = QtGui.QColor(*MARKER_COLOR)
        painter.setPen(QtGui.QPen(color, 2))
        painter.setBrush(color)
        for fraction, _ in self.markers:
            x = self.marker_x(fraction)
            painter.drawLine(x, 2, x, self.height() - 3)
            painter.drawPolygon(QtGui.QPolygon([QtCore.QPoint(x - 4, 0), QtCore.QPoint(x + 4, 0),
                                                QtCore.QPoint(x, 5)]))
        painter.end()

    def mousePressEvent(self, event: QtGui.QMouseEvent) -> None:  # noqa: N802 (Qt name)
        if event.button() == QtCore.Qt.MouseButton.LeftButton:
            index = self.marker_at(event.position().x())
            if index is not None:
                self.marker_clicked.emit(self._times[index])
                event.accept()
                return
            option = QtWidgets.QStyleOptionSlider()
            self.initStyleOption(option)
            handle = self.style().subControlRect(QtWidgets.QStyle.ComplexControl.CC_Slider,
                                                 option,
                                                 QtWidgets.QStyle.SubControl.SC_SliderHandle,
                                                 self)
            if not handle.contains(event.position().toPoint()):
                value = QtWidgets.QStyle.sliderValueFromPosition(
                    self.minimum(), self.maximum(),
                    int(event.position().x() - handle.width() / 2),
                    self.width() - handle.width())
                self.setValue(value)        # a click on the groove jumps there
                event.accept()
                return
        super().mousePressEvent(event)

    def event(self, event: QtCore.QEvent) -> bool:  # noqa: D102
        if event.type() == QtCore.QEvent.Type.ToolTip:
            index = self.marker_at(event.pos().x())
            if index is not None:
                QtWidgets.QToolTip.showText(event.globalPos(),
                                            f"marker {self.markers[index][1]} (click to jump)")
                return True
        return super().event(event)


class TransportBar(QtWidgets.QFrame):
    """Replay and recording controls. `send(command)` forwards commands. `navigated` is
    emitted when the user moves the replay somewhere (a seek: the slider, a key, a marker, Home
    or End) or plays it: the plots follow the replay again."""

    navigated = QtCore.Signal()

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
        self._recording: dict[str, Any] | None = None
        layout = QtWidgets.QHBoxLayout(self)
        layout.setContentsMargins(4, 2, 4, 2)
        layout.setSpacing(4)
        self._build_record(layout)
        self._build_replay(layout)
        self.update_replay(None)

    def _build_record(self, layout: QtWidgets.QHBoxLayout) -> None:
        self.record_button = QtWidgets.QToolButton()
        self.record_button.setObjectName("record_button")
        self.record_button.setCheckable(True)
        self.record_button.setText("● Rec")
        self.record_button.setToolTip("Start / stop recording a session (Ctrl+Shift+R): raw.txt, "
                                      "session.json, estimates.csv in the data folder's sessions")
        self.record_button.setStyleSheet("QToolButton { color: #c01818; font-weight: bold; }")
        self.record_button.clicked.connect(self.toggle_recording)
        # "REC 1:12 · 3.0 MB · 12,345 lines", cut to the room there is (never wider: the
        # window would grow off a small screen), whole in its tooltip
        self.record_label = ElidedLabel("", minimum_text="REC 0:00")
        self.record_label.setObjectName("record_label")
        layout.addWidget(self.record_button)
        layout.addWidget(self.record_label)

    def _button(self, icon: QtWidgets.QStyle.StandardPixmap, tip: str, slot) -> QtWidgets.QToolButton:
        button = QtWidgets.QToolButton()
        button.setIcon(self.style().standardIcon(icon))
        button.setToolTip(tip)
        button.clicked.connect(slot)
        return button

    def _build_replay(self, layout: QtWidgets.QHBoxLayout) -> None:
        pixmap = QtWidgets.QStyle.StandardPixmap
        self.step_back_button = self._button(pixmap.SP_MediaSkipBackward,
                                             "One sample back (Ctrl+←)", lambda: self.step(-1))
        self.play_button = QtWidgets.QToolButton()
        self.play_button.setObjectName("play_button")
        self.play_button.setToolButtonStyle(QtCore.Qt.ToolButtonStyle.ToolButtonTextBesideIcon)
        self.play_button.setMinimumWidth(76)
        self._icons = {"Play": self.style().standardIcon(pixmap.SP_MediaPlay),
                       "Pause": self.style().standardIcon(pixmap.SP_MediaPause)}
        self._show_play(True)
        self.play_button.setToolTip("Play / pause the replay (Space)")
        self.play_button.clicked.connect(self.toggle_paused)
        self.step_button = self._button(pixmap.SP_MediaSkipForward,
                                        "One sample forward (Ctrl+→)", lambda: self.step(1))
        self.speed_combo = QtWidgets.QComboBox()
        for speed, label in SPEEDS:
            self.speed_combo.addItem(label, speed)
        self.speed_combo.setCurrentIndex(3)
        self.speed_combo.setToolTip("Replay speed (max: as fast as possible)")
        self.speed_combo.activated.connect(
            lambda index: self._send(ReplayControl(speed=float(self.speed_combo.itemData(index)))))
        self.loop_checkbox = QtWidgets.QCheckBox("Loop")
        self.loop_checkbox.setToolTip("Start again at the end (each pass shows the same "
                                      "estimates)")
        self.loop_checkbox.clicked.connect(lambda checked: self._send(ReplayControl(loop=checked)))
        self.slider = MarkerSlider()
        self.slider.setObjectName("seek_slider")
        self.slider.setMinimumWidth(SLIDER_MIN_WIDTH)
        self.slider.setRange(0, SEEK_STEPS)
        self.slider.setToolTip("Drag or click to jump; the markers are ticks (click one to "
                               "jump to it)")
        self.slider.sliderPressed.connect(self._on_seek_pressed)
        self.slider.sliderReleased.connect(self._on_seek_released)
        self.slider.valueChanged.connect(self._on_seek_value_changed)
        self.slider.marker_clicked.connect(self.seek_to)
        self.position_label = QtWidgets.QLabel("–")
        self.position_label.setObjectName("position_label")
        self.position_label.setMinimumWidth(118)
        self.position_label.setAlignment(QtCore.Qt.AlignmentFlag.AlignRight
                                         | QtCore.Qt.AlignmentFlag.AlignVCenter)
        self.source_label = ElidedLabel("", mode=QtCore.Qt.TextElideMode.ElideMiddle,
                                        minimum_text="live…")
        self.source_label.setObjectName("source_label")
        self.source_label.setStyleSheet("color: #666;")
        self.source_label.setMaximumWidth(260)
        for widget in (self.step_back_button, self.play_button, self.step_button,
                       self.speed_combo, self.loop_checkbox):
            layout.addWidget(widget)
        layout.addWidget(self.slider, 1)
        layout.addWidget(self.position_label)
        layout.addWidget(self.source_label)

    @property
    def replaying(self) -> bool:
        return self._replay is not None

    @property
    def replay_widgets(self) -> tuple[QtWidgets.QWidget, ...]:
        return (self.step_back_button, self.play_button, self.step_button, self.speed_combo,
                self.loop_checkbox, self.slider)

    # ---- snapshot -> widgets --------------------------------------------------------------

    def update_replay(self, replay: dict[str, Any] | None, source: str = "") -> None:
        """Follow the replay's state (every frame: only changed widgets are touched)."""
        self._replay = replay
        enabled = replay is not None
        for widget in self.replay_widgets:
            if widget.isEnabled() != enabled:
                widget.setEnabled(enabled)
        # a replay's slider keeps its room; live, the recording's figures and the peer get it
        minimum = SLIDER_MIN_WIDTH if enabled else SLIDER_MIN_WIDTH_LIVE
        if self.slider.minimumWidth() != minimum:
            self.slider.setMinimumWidth(minimum)
        if replay is None:
            _set_text(self.position_label, "live")
            _set_text(self.source_label, source or "not a replay")
            return
        if not replay.get("indexed", True):
            source = f"indexing {100 * float(replay.get('index_progress', 0.0)):.0f} %"
        _set_text(self.source_label, source)
        finished = bool(replay.get("finished", False))
        self._show_play(bool(replay.get("paused", False)) or finished)
        self._show_speed(float(replay.get("speed", 1.0)))
        if self.loop_checkbox.isChecked() != bool(replay.get("loop", False)):
            self.loop_checkbox.setChecked(bool(replay.get("loop", False)))
        position = float(replay.get("position_s", 0.0))
        duration = float(replay.get("duration_s", 0.0))
        dragging = self._seeking or self.slider.isSliderDown()
        if not dragging and duration > 0:
            value = int(round(SEEK_STEPS * min(position / duration, 1.0)))
            if value != self.slider.value():
                self.slider.blockSignals(True)
                self.slider.setValue(value)
                self.slider.blockSignals(False)
        if not dragging:      # while dragging the label shows where the slider is
            _set_text(self.position_label, position_text(position, duration))

    def _show_speed(self, speed: float) -> None:
        index = self.speed_combo.findData(speed)
        if index < 0:
            self.speed_combo.addItem(f"{speed:g}×", speed)
            index = self.speed_combo.count() - 1
        if index != self.speed_combo.currentIndex():
            self.speed_combo.setCurrentIndex(index)

    def update_markers(self, markers: tuple | list) -> None:
        duration = float(self._replay.get("duration_s", 0.0)) if self._replay else 0.0
        self.slider.set_markers(list(markers), duration)

    def update_recording(self, recording: dict[str, Any] | None) -> None:
        """Elapsed time, size and line count while recording; why it stopped."""
        self._recording = recording
        active = bool(recording and recording.get("active"))
        if self.record_button.isChecked() != active:
            self.record_button.setChecked(active)
        _set_text(self.record_button, "■ Stop" if active else "● Rec")
        if recording is None:
            _set_text(self.record_label, "")
            return
        error = recording.get("error")
        if error:
            text = error if error.startswith("cannot record") else f"recording stopped: {error}"
            style = "color: #c01818; font-weight: bold;"
        elif active:
            elapsed = f"REC {clock_text(recording.get('elapsed_s', 0.0))[:-2]}"
            size = size_text(int(recording.get("bytes", 0)))
            text = f"{elapsed} · {size} · {int(recording.get('lines', 0)):,} lines"
            shorter = (f"{elapsed} · {size}", elapsed)       # what fits, the time first
            style = "color: #c01818;"
        else:
            text = "saved"
            style = "color: #666;"
        if not active or error:
            shorter = ()
        self.record_label.setText(text, shorter)
        folder = str(recording.get("folder", ""))
        tooltip = f"{text}\n{folder}" if folder else text
        if self.record_label.toolTip() != tooltip:
            self.record_label.setToolTip(tooltip)
        if self.record_label.styleSheet() != style:
            self.record_label.setStyleSheet(style)

    # ---- user intent -> commands ----------------------------------------------------------

    def toggle_recording(self) -> None:
        """Start or stop recording (the button shows the engine's state at the next frame)."""
        active = bool(self._recording and self._recording.get("active"))
        self._send(StopRecording() if active else StartRecording())
        self._recording = {**(self._recording or {}), "active": not active, "error": None}

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
        if not paused:
            self.navigated.emit()

    def _show_play(self, paused: bool) -> None:
        """The button offers what a click does: Play when paused (or at the end), else Pause."""
        text = "Play" if paused else "Pause"
        if self.play_button.text() != text:
            self.play_button.setText(text)
            self.play_button.setIcon(self._icons[text])

    def position_s(self) -> float:
        return float(self._replay.get("position_s", 0.0)) if self._replay else 0.0

    def duration_s(self) -> float:
        return float(self._replay.get("duration_s", 0.0)) if self._replay else 0.0

    def seek_to(self, seconds: float) -> None:
        """Jump to `seconds` since the start (clamped to the replay)."""
        if self._replay is None:
            return
        target = max(0.0, min(float(seconds), self.duration_s()))
        self._send(ReplayControl(seek_s=target))
        self._replay = {**self._replay, "position_s": target, "finished": False}
        self.navigated.emit()

    def jump_by(self, seconds: float) -> None:
        self.seek_to(self.position_s() + seconds)

    def step(self, lines: int) -> None:
        """One sample (line) forward or back; the replay pauses there."""
        if self._replay is None:
            return
        self._send(ReplayControl(paused=True, step=int(lines)))
        self._replay = {**self._replay, "paused": True}
        self._show_play(True)

    def _on_seek_pressed(self) -> None:
        self._seeking = True

    def _on_seek_released(self) -> None:
        self._seeking = False
        self.seek_to_fraction(self.slider.value() / SEEK_STEPS)

    def _on_seek_value_changed(self, value: int) -> None:
        if not self._seeking and not self.slider.isSliderDown():
            self.seek_to_fraction(value / SEEK_STEPS)
        elif self._replay is not None:
            duration = self.duration_s()
            _set_text(self.position_label,
                      position_text(value / SEEK_STEPS * duration, duration))

    def seek_to_fraction(self, fraction: float) -> None:
        if self._replay is None:
            return
        self.seek_to(max(0.0, min(fraction, 1.0)) * self.duration_s())


def _set_text(widget, text: str) -> None:
    if widget.text() != text:
        widget.setText(text)
