"""Live plots in time since the session's start, in three tabs.

* Sensors: accelerometer, gyroscope and magnetometer (x, y, z, norm), the gates on the norms,
  the samples the filter rejected as a thin red band of ticks along the bottom and, where the
  sensor was switched off (its samples not used, no gate asked), a grey dashed band instead;
* Orientation: yaw, pitch and roll (z-y-x) of OWN (solid) and PHONE (dashed, same colour),
  wrapped to ±180° (±90° for pitch) with the line broken at a wrap, or unwrapped in one turn;
* Error vs PHONE: total angle, heading and inclination of OWN against PHONE, compared at
  PHONE's time stamps.

With your own filter loaded (YOURS) its Euler angles and errors join the last two tabs, dotted
in the same colours, with a YOURS toggle in their legends (shown only while YOURS has data).

Samples arrive in PlotChunks (one per display frame) and go into preallocated numpy buffers
of bounded size; the current tab's curves are redrawn at most once per display frame, only
over the visible window, peak-downsampled to the plot's width. Following shows the last
`window_s` seconds; pausing (button, Space, or dragging/zooming a plot) freezes the view while
samples keep being stored, and a note in the toolbar says so with the times shown; Follow
resumes (the window also calls follow() on a replay's seek or Play). The legend of each tab is a row of toggles above
its plots (never over the data); the cursor reads every visible curve into a small table.
A sensor the stream does not deliver has its plot say so ("no gyroscope in this stream").

What is drawn (the plots, curves, legends, the readout's table) is declared in plot_specs.py,
the graphics items are in plot_items.py, and the panel's construction is in plot_build.py.
"""

from __future__ import annotations

import math

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets

from app.engine.snapshot import FilterStatus, PlotChunk
from app.ui.no_data import NoDataText
from app.ui.plot_build import PlotPanelBuild
from app.ui.plot_data import (OffSpans, SampleBuffer, break_at_wraps, peak_downsample,
                              rejected_spans, time_text, unwrap_deg, unwrap_in_turn)
from app.ui.plot_items import Curve, PlotGroup
from app.ui.plot_specs import (BAND_FRACTION, FIRST_PLOTS, GROUPS, MARKER_COLOR, OFF_JOIN_S,
                               STREAM_COLUMNS, USER_STREAMS, USER_TOGGLES, CurveSpec,
                               curve_specs, readout_table)

class PlotPanel(PlotPanelBuild, QtWidgets.QWidget):
    """Toolbar (window length, Pause/Follow, Cursor, Unwrap, Clear), three tabs of plots and
    the cursor readout."""

    paused_changed = QtCore.Signal(bool)

    def __init__(self, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.following = True
        self.pause_reason = ""          # "paused" or "zoomed" while not following
        self.unwrapped = False
        self._dirty = True
        self._last_range: tuple[float, float] | None = None
        self._setting_range = False
        self._syncing_cursor = False
        self.origin_ms: int | None = None
        # the rolling buffers the snapshots fill; `buffers` is what is drawn: these, or a
        # replay's whole session (set_session)
        self.live_buffers = {key: SampleBuffer(columns)
                             for key, columns in STREAM_COLUMNS.items()}
        self.buffers = self.live_buffers
        self.session = None
        self._position: float | None = None
        self._marker_lines: dict[str, list[pg.InfiniteLine]] = {}
        self._markers_shown: tuple = ()
        self.plots: dict[str, pg.PlotItem] = {}
        self.curves: list[tuple[CurveSpec, Curve]] = []
        self.bands: dict[str, Curve] = {}
        self.off_bands: dict[str, Curve] = {}
        # per banded sensor: the stretches in which its samples arrived while it was switched
        # off (said by each snapshot's status)
        self.off_spans = {"acc": OffSpans(OFF_JOIN_S), "mag": OffSpans(OFF_JOIN_S)}
        self._off_band_spans: dict[str, np.ndarray] = {}
        self.gate_lines: dict[str, tuple[pg.InfiniteLine, pg.InfiniteLine]] = {}
        self.cursors: dict[str, pg.InfiniteLine] = {}
        self.groups: dict[str, PlotGroup] = {}
        self._band_spans: dict[str, np.ndarray] = {}
        self.no_data_items: dict[str, NoDataText] = {}
        self.user_present = False

        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(2)
        layout.addLayout(self._build_toolbar())
        self.readout_label = QtWidgets.QLabel("")
        self.readout_label.setObjectName("cursor_readout")
        self.readout_label.setTextFormat(QtCore.Qt.TextFormat.RichText)
        self.readout_label.setTextInteractionFlags(
            QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        self.readout_label.setVisible(False)
        layout.addWidget(self.readout_label)
        self.tabs = QtWidgets.QTabWidget()
        self.tabs.setObjectName("plot_tabs")
        self.tabs.setDocumentMode(True)
        for key, title in GROUPS:
            group = self._build_group(key)
            self.groups[key] = group
            self.tabs.addTab(group.widget, title)
        self.tabs.currentChanged.connect(self._on_tab_changed)
        layout.addWidget(self.tabs, 1)
        for spec in curve_specs():
            self._add_curve(spec)
        self.set_user_present(False)

    # ---- data in ---------------------------------------------------------------------------

    def append(self, chunk: PlotChunk, enabled: dict[str, bool] | None = None) -> None:
        """Store the new samples; drawing waits for the next refresh(). enabled: the sensor
        switches these samples were filtered with (FilterStatus.sensors_enabled): the samples
        of a switched-off sensor are drawn as "off", not as rejected."""
        for key, t, values, rejected in (("acc", chunk.t_acc, chunk.acc, chunk.acc_rejected),
                                         ("gyr", chunk.t_gyr, chunk.gyr, None),
                                         ("mag", chunk.t_mag, chunk.mag, chunk.mag_rejected)):
            if not len(t):
                continue
            values = np.asarray(values, float).reshape(len(t), 3)
            columns = [values, np.linalg.norm(values, axis=1, keepdims=True)]
            if rejected is not None:
                flags = np.asarray(rejected, float).reshape(-1, 1)
                columns.append(flags if len(flags) == len(values) else np.zeros((len(t), 1)))
            self._append(key, t, np.hstack(columns))
        for key, t, values in (("own", chunk.t_est, chunk.own_euler_deg),
                               ("phone", chunk.t_ori, chunk.phone_euler_deg),
                               ("error", chunk.t_err, chunk.error_deg),
                               ("user", chunk.t_user, chunk.user_euler_deg),
                               ("user_error", chunk.t_user_err, chunk.user_error_deg)):
            if len(t):
                self._append(key, t, np.asarray(values, float).reshape(len(t), 3))
        for key, t in (("acc", chunk.t_acc), ("mag", chunk.t_mag)):
            if enabled is not None and enabled.get(key) is False and len(t):
                self.off_spans[key].add(float(t[0]), float(t[-1]))
                self._dirty = True

    def set_user_present(self, present: bool) -> None:
        """YOURS loaded or not: its legend toggles (and OWN's beside it in the error tab) show
        only while there is a YOURS to tell apart; unloading forgets its curves."""
        present = bool(present)
        if not present:
            for key in USER_STREAMS:
                self.live_buffers[key].clear()
        self.user_present = present
        for group, name in USER_TOGGLES:
            self.groups[group].toggles[name].setVisible(present)
        self.plots["error"].setLabel("left", "vs PHONE" if present else "OWN vs PHONE",
                                     units="°")
        self._dirty = True

    def replace_user_history(self, t_s: np.ndarray, euler_deg: np.ndarray, t_err_s: np.ndarray,
                             error_deg: np.ndarray) -> None:
        """YOURS re-run over the session after a reload: its curves drawn so far replaced."""
        for key, t, values in (("user", t_s, euler_deg), ("user_error", t_err_s, error_deg)):
            buffer = self.live_buffers[key]
            buffer.clear()
            t = np.asarray(t, np.float64)
            if len(t):
                buffer.append(t, np.asarray(values, float).reshape(len(t), 3))
        self._dirty = True

    def _append(self, key: str, t: np.ndarray, values: np.ndarray) -> None:
        t = np.asarray(t, dtype=np.float64)
        buffer = self.live_buffers[key]
        if key in USER_STREAMS:
            # After a re-run's history the live rows may overlap it: keep only the newer ones.
            newer = t > buffer.last_time() + 1e-9
            if not newer.all():
                if buffer.size and t[0] < buffer.last_time() - 5.0:
                    buffer.clear()     # far earlier: a new session (the others clear too)
                else:
                    t, values = t[newer], values[newer]
            if not len(t):
                return
        # A new session (a new connection, a replay that loops or seeks back) restarts the
        # time since the start: start the rolling plots afresh.
        if t[0] < buffer.last_time() - 1e-6:
            for other in self.live_buffers.values():
                other.clear()
            if self.session is None:
                self._clear_off_spans()
            self._dirty = self._dirty or self.session is None
        buffer.append(t, values)
        # While paused, samples after the frozen view change nothing on screen; a replay's
        # whole session is drawn from its own data.
        if self.session is None and (self.following or t[0] <= self.x_range()[1]):
            self._dirty = True

    def set_session(self, session) -> None:
        """Draw a replay's whole session (app.engine.sessions.index.SessionPlot: its arrays,
        not copied) instead of the rolling buffers; None: back to the rolling buffers. Paused,
        the user scrolls and zooms over the whole recording."""
        if session is self.session:
            return
        self.session = session
        if session is None:
            self.buffers = self.live_buffers
            self._position = None
        else:
            # YOURS is not in the session's index (it is the user's code, re-run on reload):
            # its curves stay the rolling ones.
            self.buffers = {key: SampleBuffer.from_arrays(*session.streams[key])
                            if key in session.streams else self.live_buffers[key]
                            for key in STREAM_COLUMNS}
        self._dirty = True

    def set_position(self, t_s: float | None) -> None:
        """The replay's position (s since the start): a whole session's plots follow it."""
        if t_s != self._position:
            self._position = t_s
            if self.session is not None and self.following:
                self._dirty = True

    def set_markers(self, markers) -> None:
        """Markers (app.engine.sessions.session.Marker) as labelled vertical lines in every plot."""
        shown = tuple((m.id, m.t_s, m.title) for m in markers if m.t_s is not None)
        if shown == self._markers_shown:
            return
        self._markers_shown = shown
        pen = pg.mkPen(MARKER_COLOR, width=1, style=QtCore.Qt.PenStyle.DashLine)
        for key, plot in self.plots.items():
            for line in self._marker_lines.pop(key, []):
                plot.removeItem(line)
            lines = []
            for number, t_s, title in shown:
                line = pg.InfiniteLine(pos=t_s, angle=90, movable=False, pen=pen,
                                       label=title if key in FIRST_PLOTS else None,
                                       labelOpts={"position": 0.95, "color": MARKER_COLOR})
                line.setToolTip(f"marker {title} at {time_text(t_s, 600.0, 1)}")
                plot.addItem(line, ignoreBounds=True)
                lines.append(line)
            self._marker_lines[key] = lines

    def set_no_data(self, key: str, text: str) -> None:
        """Say why a plot is empty ("no gyroscope in this stream"), centred over it instead of
        an empty axis (its y values hidden); "" when it has data to show."""
        item = self.no_data_items[key]
        if text != item.text():
            item.set_text(text)
            self.plots[key].getAxis("left").setStyle(showValues=not text)

    def no_data_text(self, key: str) -> str:
        """The plot's no-data text ("" when none is shown)."""
        return self.no_data_items[key].text()

    def set_status(self, status: FilterStatus) -> None:
        """Draw the gate limits on the norms: g ± acc_gate and L ± mag_gate."""
        diagnostics = status.diagnostics
        for key, center, gate in (("acc", diagnostics.g, diagnostics.acc_gate),
                                  ("mag", diagnostics.mag_expected, diagnostics.mag_gate)):
            shown = self.groups["sensors"].toggles["gates"].isChecked()
            valid = math.isfinite(center) and math.isfinite(gate) and shown
            for line, sign in zip(self.gate_lines[key], (1.0, -1.0)):
                line.setVisible(valid)
                if valid and abs(line.value() - (center + sign * gate)) > 1e-9:
                    line.setValue(center + sign * gate)

    def set_time_origin(self, origin_ms: int | None) -> None:
        """The phone's clock at time 0 (shown when hovering over the time axis)."""
        if origin_ms == self.origin_ms:
            return
        self.origin_ms = origin_ms
        for plot in self.plots.values():
            plot.getAxis("bottom").set_origin(origin_ms)

    # ---- view state ------------------------------------------------------------------------

    @property
    def paused(self) -> bool:
        return not self.following

    @property
    def window_s(self) -> float:
        return float(self.window_spin.value())

    def set_window_s(self, seconds: float) -> None:
        self.window_spin.setValue(float(seconds))

    def current_group(self) -> str:
        return GROUPS[self.tabs.currentIndex()][0]

    def set_current_group(self, key: str) -> None:
        self.tabs.setCurrentIndex([k for k, _ in GROUPS].index(key))

    def set_paused(self, paused: bool, reason: str = "paused") -> None:
        """Pause: the view stays where it is while samples keep being stored. `reason` ("paused"
        or "zoomed": a plot dragged or zoomed by hand) is said in the toolbar's note, with the
        time range shown, until the plots follow again (Follow; a replay's seek, Home or
        Play)."""
        paused = bool(paused)
        if paused:
            self.pause_reason = reason
        if paused == self.paused:
            self._show_follow_state()
            return
        self.following = not paused
        self.pause_button.blockSignals(True)
        self.pause_button.setChecked(paused)
        self.pause_button.blockSignals(False)
        self.pause_button.setText("Paused" if paused else "Pause")
        self.follow_button.setEnabled(paused)
        self._dirty = True
        self._show_follow_state()
        self.paused_changed.emit(paused)

    def follow_text(self) -> str:
        """The toolbar's note: "" while following, else why not and which times are shown."""
        if self.following:
            return ""
        low, high = self.x_range()
        span = high - low
        why = "zoomed by hand" if self.pause_reason == "zoomed" else "paused"
        low_text, high_text = time_text(low, span, 1), time_text(high, span, 1)
        unit = "" if ":" in high_text else " s"
        return f"not following ({why}): showing {low_text} – {high_text}{unit}"

    def _show_follow_state(self) -> None:
        text = self.follow_text()
        if self.follow_note.text() != text:
            self.follow_note.setText(text, (text.split(": showing ")[0],))
            self.follow_note.setToolTip(
                f"{text}\nThe plots stay on these times while samples keep arriving; Follow "
                "(or, in a replay, a seek, Home or Play) shows the newest again" if text else "")
        if self.follow_note.isVisible() != bool(text):
            self.follow_note.setVisible(bool(text))

    def follow(self) -> None:
        self.set_paused(False)

    def toggle_paused(self) -> None:
        self.set_paused(not self.paused)

    def set_unwrapped(self, unwrapped: bool) -> None:
        self.unwrapped = bool(unwrapped)
        if self.unwrap_checkbox.isChecked() != self.unwrapped:
            self.unwrap_checkbox.setChecked(self.unwrapped)
        self._dirty = True

    def set_shown(self, group: str, name: str, shown: bool) -> None:
        """A legend toggle: show or hide every curve (or the band, the gates) it names."""
        toggle = self.groups[group].toggles[name]
        if toggle.isChecked() != bool(shown):
            toggle.setChecked(bool(shown))
            return
        if name == "rejected":
            for band in self.bands.values():
                band.setVisible(bool(shown))
        elif name == "off":
            for band in self.off_bands.values():
                band.setVisible(bool(shown))
        elif name == "gates" and not shown:     # shown again with the next status
            for lines in self.gate_lines.values():
                for line in lines:
                    line.setVisible(False)
        toggles = self.groups[group].toggles
        for spec, curve in self.curves:
            if name in spec.tags and self.plots[spec.plot] in self._group_plots(group):
                # shown when every toggle naming it is on (a YOURS heading: YOURS and heading)
                curve.setVisible(all(toggles[tag].isChecked() for tag in spec.tags
                                     if tag in toggles))
        self._dirty = True

    def _group_plots(self, group: str) -> list[pg.PlotItem]:
        return [self.plots[key] for key in self.groups[group].plots]

    def clear(self) -> None:
        for buffer in self.live_buffers.values():
            buffer.clear()
        self._clear_off_spans()
        self._dirty = True
        self.refresh()

    def _clear_off_spans(self) -> None:
        for spans in self.off_spans.values():
            spans.clear()
        self._dirty = True

    def latest_time(self) -> float:
        if self.session is not None and self._position is not None:
            return self._position
        return max(buffer.last_time() for buffer in self.buffers.values())

    def x_range(self) -> tuple[float, float]:
        plot = self.plots[self.groups[self.current_group()].plots[0]]
        low, high = plot.getViewBox().viewRange()[0]
        return float(low), float(high)

    def _on_tab_changed(self, index: int) -> None:
        low, high = self._last_range or self.x_range_of_any()
        self.set_x_range(low, high)
        self._dirty = True
        if self.cursor_checkbox.isChecked():
            self.set_cursor_time(self.cursor_time())

    def x_range_of_any(self) -> tuple[float, float]:
        low, high = self.plots["acc"].getViewBox().viewRange()[0]
        return float(low), float(high)

    def _on_manual_range(self, *args) -> None:
        # The user dragged or zoomed a plot: they want to look at it, so stop following.
        if not self._setting_range:
            self.set_paused(True, "zoomed")

    def _on_x_range_changed(self, view_box, x_range) -> None:
        """A plot's time range changed by hand (drag, zoom, its menu): the others follow."""
        if self._setting_range:
            return
        self.set_x_range(*x_range, source=view_box)
        self._dirty = True

    def set_x_range(self, low: float, high: float, source=None) -> None:
        """Show times low..high (s since the start) in every plot (but `source`)."""
        self._setting_range = True
        try:
            for plot in self.plots.values():
                view_box = plot.getViewBox()
                if view_box is not source:
                    view_box.setXRange(low, high, padding=0.0)
        finally:
            self._setting_range = False

    def _mark_dirty(self, *args) -> None:
        self._dirty = True

    # ---- drawing ---------------------------------------------------------------------------

    def refresh(self) -> None:
        """Redraw the current tab's visible window if anything changed (once per frame)."""
        latest = self.latest_time()
        if self.following and math.isfinite(latest):
            x_range = (latest - self.window_s, latest)
            if x_range != self._last_range:
                self.set_x_range(*x_range)
                self._dirty = True
        if not self._dirty:
            return
        self._dirty = False
        t_start, t_end = self.x_range()
        self._last_range = (t_start, t_end) if self.following else None
        if not self.following:
            self._show_follow_state()
        group = self.current_group()
        bounds: dict[str, list[tuple[float, float]]] = {key: [] for key in self.groups[group].plots}
        for stream in self._streams_of(group):
            self._draw_stream(stream, t_start, t_end, bounds)
        for key, spans in bounds.items():
            finite = [(low, high) for low, high in spans if math.isfinite(low)
                      and math.isfinite(high)]
            if finite:
                self._fit_y(key, min(low for low, _ in finite), max(high for _, high in finite))
        for key in self.bands:
            if key in bounds:
                self._draw_band(key)
        # Apply the new ranges now: pyqtgraph would do it lazily at the start of the paint,
        # which moves every item once more and so asks for a second paint of each frame.
        for key in self.groups[group].plots:
            self.plots[key].getViewBox().prepareForPaint()
        if self.cursor_checkbox.isChecked():
            self._update_readout()

    @staticmethod
    def _streams_of(group: str) -> tuple[str, ...]:
        return {"sensors": ("acc", "gyr", "mag"), "orientation": ("own", "phone", "user"),
                "error": ("error", "user_error")}[group]

    def _display_window(self, stream: str, t_start: float, t_end: float
                        ) -> tuple[np.ndarray, np.ndarray, int]:
        """The stream's samples in view as they are drawn (Euler: wrapped with breaks, or
        unwrapped; PHONE in OWN's turn) and the running index of the first."""
        buffer = self.buffers[stream]
        window = buffer.window(t_start, t_end)
        t, values = buffer.t[window], buffer.values[window]
        first = buffer.first_index + window.start
        if stream in ("own", "phone", "user") and len(t):
            if self.unwrapped:
                own = self.buffers["own"]
                own_window = own.window(t_start, t_end)
                own_t = own.t[own_window]
                own_values = unwrap_deg(own.values[own_window])
                values = own_values if stream == "own" else unwrap_in_turn(
                    own_t, own_values, t, values)
            else:
                t, values = break_at_wraps(t, values)
        return t, values, first

    def _draw_stream(self, stream: str, t_start: float, t_end: float,
                     bounds: dict[str, list[tuple[float, float]]]) -> None:
        """Hand one stream's visible window, peak-downsampled to the plot's width, to its
        curves; collect each plot's y span."""
        t, values, first = self._display_window(stream, t_start, t_end)
        curves = [(spec, curve) for spec, curve in self.curves if spec.stream == stream]
        width = max(int(self.plots[curves[0][0].plot].getViewBox().width()), 1)
        shown_t, shown = peak_downsample(t, values, first, width)
        for spec, curve in curves:
            if not curve.isVisible():
                continue    # a hidden curve gets the current points when shown (dirty)
            column = shown[:, spec.column] if len(shown_t) else np.empty(0)
            low = float(np.fmin.reduce(column)) if len(column) else math.nan
            high = float(np.fmax.reduce(column)) if len(column) else math.nan
            finite = bool(np.isfinite(column).all())
            valid = math.isfinite(low) and math.isfinite(high)
            curve.set_curve(shown_t, column, finite, (low, high) if valid else None)
            if valid:
                bounds[spec.plot].append((low, high))
        if stream in self.bands:
            off = self.off_spans[stream].mask(t)
            rejected = (values[:, 4] > 0.5) & ~off if len(t) else np.zeros(0, bool)
            self._band_spans[stream] = rejected_spans(t, rejected)
            self._off_band_spans[stream] = rejected_spans(t, off)

    def _draw_band(self, key: str) -> None:
        """The rejected samples as ticks along the bottom of the plot (the curves stay
        visible above them), and where the sensor was switched off a grey dashed band at the
        same height."""
        low, high = self.plots[key].getViewBox().viewRange()[1]
        level = low + BAND_FRACTION * (high - low)
        for bands, spans in ((self.bands, self._band_spans),
                             (self.off_bands, self._off_band_spans)):
            x = spans.get(key, np.empty((0, 2))).reshape(-1)
            bands[key].set_curve(x, np.full(len(x), level), True,
                                 (level, level) if len(x) else None, connect="pairs")

    def off_band_spans(self, key: str) -> np.ndarray:
        """The "off" stretches drawn in the plot's visible window, (n, 2) [start, end] s."""
        return self._off_band_spans.get(key, np.empty((0, 2)))

    def rejected_band_spans(self, key: str) -> np.ndarray:
        """The rejected stretches drawn in the plot's visible window, (n, 2) [start, end] s."""
        return self._band_spans.get(key, np.empty((0, 2)))

    def _fit_y(self, key: str, low: float, high: float) -> None:
        """Fit the y range to the visible curves' span (and gate lines), with hysteresis so the
        axis does not rescale, and re-layout, on every frame."""
        for line in self.gate_lines.get(key, ()):
            if line.isVisible():
                low, high = min(low, line.value()), max(high, line.value())
        if key in ("yaw", "roll") and not self.unwrapped:
            low, high = min(low, -180.0), max(high, 180.0)
        elif key == "pitch" and not self.unwrapped:
            low, high = min(low, -90.0), max(high, 90.0)
        span = max(high - low, 1e-6 * max(abs(high), 1.0), 1e-9)
        margin = 0.08 * span
        if key in self.bands:
            margin = max(margin, 1.5 * BAND_FRACTION * span)   # room for the band below
        low, high = low - margin, high + 0.08 * span
        view_low, view_high = self.plots[key].getViewBox().viewRange()[1]
        if low < view_low or high > view_high or (view_high - view_low) > 2.0 * (high - low):
            self.plots[key].setYRange(low, high, padding=0.0)

    # ---- cursor ----------------------------------------------------------------------------

    def set_cursor_visible(self, visible: bool) -> None:
        if visible:
            t_start, t_end = self.x_range()
            self.set_cursor_time(0.5 * (t_start + t_end))
        for cursor in self.cursors.values():
            cursor.setVisible(bool(visible))
        self.readout_label.setVisible(bool(visible))
        if self.cursor_checkbox.isChecked() != bool(visible):
            self.cursor_checkbox.setChecked(bool(visible))
        if visible:
            self._update_readout()

    def cursor_time(self) -> float:
        return float(self.cursors["acc"].value())

    def set_cursor_time(self, t: float) -> None:
        self._syncing_cursor = True
        for cursor in self.cursors.values():
            cursor.setValue(t)
        self._syncing_cursor = False
        self._update_readout()

    def _on_cursor_moved(self, line: pg.InfiniteLine) -> None:
        if self._syncing_cursor:
            return
        self.set_cursor_time(float(line.value()))

    def cursor_values(self) -> dict[str, float]:
        """Value of every visible curve at the cursor (nearest stored sample, as drawn), by
        its label ("acc x", "OWN yaw", "total", ...); NaN where a stream has no samples."""
        t_cursor = self.cursor_time()
        values: dict[str, float] = {}
        for stream in STREAM_COLUMNS:
            if stream in USER_STREAMS and not self.user_present:
                continue
            buffer = self.buffers[stream]
            t = buffer.t
            index = None
            if len(t):
                index = int(np.clip(np.searchsorted(t, t_cursor), 0, len(t) - 1))
                if index > 0 and abs(t[index - 1] - t_cursor) <= abs(t[index] - t_cursor):
                    index -= 1
            for spec, curve in self.curves:
                if spec.stream == stream and curve.isVisible():
                    values[spec.label] = (float(buffer.values[index, spec.column])
                                          if index is not None else math.nan)
        return values

    def _update_readout(self) -> None:
        if not self.cursor_checkbox.isChecked():
            return
        values = self.cursor_values()
        span = self.x_range()[1] - self.x_range()[0]
        self.readout_label.setText(readout_table(values, self.cursor_time(), span,
                                                 self.current_group()))
