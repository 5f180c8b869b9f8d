"""The calibration workspace: at rest (task 2), gyroscope noise (Allan), magnetometer hard and
soft iron; Apply, Save profile, Load profile. A self-contained widget for a workspace tab.

Mounting (docs/user-guide.md, "Calibration and tuning"):
``CalibrationWorkspace(send=engine.send, settings=lambda: current_settings)``, then call
:meth:`feed` with every snapshot the window polls (it reads only ``snapshot.plot``:
t_acc/acc, t_gyr/gyr, t_mag/mag). Apply sends ``SetSettings(settings,
calibration=profile_dict, source="calibration")``; the engine records the profile in the
session. A stretch of a loaded log is analysed with :meth:`analyse_log` (or "From log…").

The numbers come from app.engine.tuning.calibration (the one path of `calibrate` and
`calibrate-mag`) and the figures from app.ui.figures (the same drawings as their --plots PNGs).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets

import ekf
from ekf import magcal
from app.engine import config
from app.engine.tuning.calibration import mag_from_log, rest_source
from app.engine.commands import SetSettings
from app.engine.tuning.profiles import Profile, ProfileStore
from app.ui import figures
from app.ui.calibration_rest import RestTab
from app.ui.calibration_rest import label as _label
from app.ui.no_data import NoDataText

NO_MAG_DATA = "no readings"
MAG_FIT_EVERY = 25        # refit the magnetometer after this many new readings
MAG_FIT_POINTS = 3000     # at most this many readings (evenly thinned) in a live fit


class AllanTab(QtWidgets.QWidget):
    """The Allan deviation of the rest recording's gyroscope (any length: a longer Start gives
    the bias instability), with ARW and bias instability read off and drawn."""

    def __init__(self, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.plot_widget = pg.PlotWidget(axisItems=figures.log_axes())
        self.plot_widget.setBackground("w")
        self.plot = self.plot_widget.getPlotItem()
        self.summary = _label("Record at rest (the At rest tab; minutes for the bias "
                              "instability) to see the gyroscope's Allan deviation.")
        layout = QtWidgets.QVBoxLayout(self)
        layout.addWidget(self.summary)
        layout.addWidget(self.plot_widget, 1)
        self.allan = None
        self.no_data = NoDataText(self.plot.getViewBox())
        self.no_data.set_text("no data: record at rest first")

    def show_result(self, allan: Any) -> None:
        self.allan = allan
        figures.draw_allan(self.plot, allan)
        self.no_data.set_text("no gyroscope samples" if allan is None else "")
        if allan is None:
            self.summary.setText("too few gyroscope samples for an Allan deviation")
            return
        lines = []
        for a in allan.axes:
            bound = " (upper bound: record longer)" if a.bias_instability_is_bound else ""
            lines.append(f"{a.axis}: angle random walk {a.arw:.3e} rad/√s "
                         f"({np.degrees(a.arw) * 60:.3f} °/√h), bias instability "
                         f"{a.bias_instability:.3e} rad/s "
                         f"({np.degrees(a.bias_instability) * 3600:.2f} °/h){bound}")
        self.summary.setText("\n".join(lines))


class MagTab(QtWidgets.QWidget):
    """Start collects magnetometer readings while the user turns the phone; the cloud fills a
    sphere live (2D projections; a 3D view too with use_gl), with coverage, fit error and the
    ‖m‖ spread before/after updated as readings come in."""

    fitted = QtCore.Signal(object)          # MagCalibration

    def __init__(self, use_gl: bool = False, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.readings: list[np.ndarray] = []
        self.count = 0
        self._fitted_at = 0
        self.collecting = False
        self.result: magcal.MagCalibration | None = None
        self.start_button = QtWidgets.QPushButton("Start")
        self.start_button.clicked.connect(self.toggle)
        self.clear_button = QtWidgets.QPushButton("Clear")
        self.clear_button.clicked.connect(self.clear)
        self.from_log_button = QtWidgets.QPushButton("From log…")
        self.from_log_button.setToolTip("fit the magnetometer readings of a log in which the "
                                        "phone was turned in every direction")
        self.coverage_bar = QtWidgets.QProgressBar()
        self.coverage_bar.setFormat("coverage %p %")
        self.summary = _label("Press Start and turn the phone slowly in every direction.")
        controls = QtWidgets.QHBoxLayout()
        for w in (self.start_button, self.clear_button, self.from_log_button, self.coverage_bar):
            controls.addWidget(w)
        self.cloud = pg.GraphicsLayoutWidget()
        self.cloud.setBackground("w")
        self.projection_plots = [self.cloud.addPlot(row=0, col=k) for k in range(3)]
        self.no_data = [NoDataText(plot.getViewBox()) for plot in self.projection_plots]
        self._show_no_data(True)
        self.view3d = self._make_3d() if use_gl else None
        layout = QtWidgets.QVBoxLayout(self)
        layout.addLayout(controls)
        layout.addWidget(self.summary)
        if self.view3d is not None:
            layout.addWidget(self.view3d, 2)
        layout.addWidget(self.cloud, 1)

    def _make_3d(self) -> QtWidgets.QWidget:
        import pyqtgraph.opengl as gl     # needs OpenGL: only with use_gl

        view = gl.GLViewWidget()
        view.setCameraPosition(distance=150)
        self.scatter3d = gl.GLScatterPlotItem(pos=np.zeros((1, 3)), size=3.0)
        view.addItem(self.scatter3d)
        return view

    def toggle(self) -> None:
        """Start a new cloud, or stop and fit it."""
        if not self.collecting:
            self.clear()
        self.collecting = not self.collecting
        self.start_button.setText("Stop" if self.collecting else "Start")
        if not self.collecting and self.count >= magcal.MIN_SAMPLES:
            self.refit()

    def clear(self) -> None:
        self.readings, self.count, self._fitted_at, self.result = [], 0, 0, None
        self.coverage_bar.setValue(0)
        figures.draw_projections(self.projection_plots, np.empty((0, 3)), None)
        self._show_no_data(True)
        self.summary.setText("cleared")

    def _show_no_data(self, empty: bool) -> None:
        for text in self.no_data:
            text.set_text(NO_MAG_DATA if empty else "")

    def all_readings(self) -> np.ndarray:
        return np.concatenate(self.readings) if self.readings else np.empty((0, 3))

    def feed(self, chunk: Any) -> None:
        if not self.collecting:
            return
        mag = np.asarray(chunk.mag, dtype=float).reshape(-1, 3)
        mag = mag[np.all(np.isfinite(mag), axis=1)]
        if len(mag) == 0:
            return
        self.readings.append(mag)
        self.count += len(mag)
        if self.count - self._fitted_at >= MAG_FIT_EVERY:
            self.refit()

    def refit(self) -> magcal.MagCalibration | None:
        readings = self.all_readings()
        self._fitted_at = self.count
        thinned = (readings if len(readings) <= MAG_FIT_POINTS else
                   readings[np.linspace(0, len(readings) - 1, MAG_FIT_POINTS).astype(int)])
        try:
            result = magcal.calibrate_magnetometer(thinned)
        except ValueError as error:
            self.summary.setText(str(error))
            return None
        self.show_result(result, readings)
        return result

    def show_result(self, result: magcal.MagCalibration, readings: np.ndarray) -> None:
        self.result = result
        self.coverage_bar.setValue(int(round(100 * result.coverage)))
        figures.draw_projections(self.projection_plots, readings, result)
        self._show_no_data(len(readings) == 0)
        if self.view3d is not None and len(readings):
            self.scatter3d.setData(pos=result.correct(readings))
        offset = ", ".join(f"{v:.1f}" for v in result.offset)
        self.summary.setText(
            f"{self.count} readings, {result.model} fit; coverage {100 * result.coverage:.0f} %; "
            f"fit error {result.fit_error_pct:.2f} %; offset ({offset}) µT; field "
            f"{result.field_strength:.1f} µT; ‖m‖ spread {result.norm_std_before:.2f} → "
            f"{result.norm_std_after:.2f} µT" + (f"\n{result.message}" if result.message else ""))
        self.fitted.emit(result)


class CalibrationWorkspace(QtWidgets.QWidget):
    """The three tabs and the profile bar. send(command): the engine's send; settings(): the
    settings in use (the base Apply completes); store: profiles (None: the data folder);
    use_gl: also a 3D view of the magnetometer cloud (needs OpenGL)."""

    applied = QtCore.Signal(object)      # the ekf.EKFSettings sent by Apply

    def __init__(self, send: Callable[[Any], None],
                 settings: Callable[[], ekf.EKFSettings | None] = lambda: None,
                 store: ProfileStore | None = None, use_gl: bool = False,
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self._send = send
        self._settings = settings
        self.store = store or ProfileStore()
        self.loaded: Profile | None = None
        self.rest = RestTab()
        self.allan = AllanTab()
        self.mag = MagTab(use_gl)
        self.rest.analysed.connect(lambda result: self.allan.show_result(result.allan))
        self.rest.from_log_button.clicked.connect(self._from_log_dialog)
        self.mag.from_log_button.clicked.connect(self._mag_from_log_dialog)
        self.tabs = QtWidgets.QTabWidget()
        self.tabs.addTab(self.rest, "At rest")
        self.tabs.addTab(self.allan, "Gyro noise")
        self.tabs.addTab(self.mag, "Magnetometer")
        self.name = QtWidgets.QLineEdit()
        self.name.setPlaceholderText("profile name, e.g. the phone")
        self.apply_button = QtWidgets.QPushButton("Apply")
        self.apply_button.clicked.connect(self.apply)
        self.save_button = QtWidgets.QPushButton("Save profile")
        self.save_button.clicked.connect(lambda: self.save_profile())
        self.profiles = QtWidgets.QComboBox()
        self.load_button = QtWidgets.QPushButton("Load profile")
        self.load_button.clicked.connect(lambda: self.load_profile(self.profiles.currentText()))
        self.message = _label()
        bar = QtWidgets.QHBoxLayout()
        for w in (QtWidgets.QLabel("Profile"), self.name, self.apply_button, self.save_button,
                  self.profiles, self.load_button):
            bar.addWidget(w)
        layout = QtWidgets.QVBoxLayout(self)
        layout.addWidget(self.tabs, 1)
        layout.addLayout(bar)
        layout.addWidget(self.message)
        self.refresh_profiles()

    # -- data in ------------------------------------------------------------------------------

    def feed(self, snapshot: Any) -> None:
        """Every polled snapshot (only snapshot.plot is read)."""
        if snapshot is None:
            return
        self.rest.feed(snapshot.plot)
        self.mag.feed(snapshot.plot)

    def analyse_log(self, path: str | Path, start_s: float | None = None,
                    end_s: float | None = None, whole: bool = False) -> bool:
        """A stretch of a log (seconds from its start; all of it with `whole`; neither: its
        longest still interval) in the At rest tab, where another stretch can be dragged, and
        its magnetometer readings in the Magnetometer tab."""
        try:
            log = config.open_log(path)
            source = rest_source(log)
        except config.ConfigError as error:
            self.message.setText(str(error))
            return False
        rest = self.rest.load_source(source, start_s, end_s, whole)
        if rest is None:
            self.message.setText(self.rest.status.text())
            return False
        try:
            mag, raw = mag_from_log(log, start_s, end_s)
            self.mag.count = len(raw)
            self.mag.show_result(mag, raw)
        except config.ConfigError:
            pass    # a still stretch is no magnetometer fit (the tab keeps what it had)
        self.message.setText(f"{Path(path).name}: {rest.how}")
        return True

    def analyse_mag_log(self, path: str | Path, start_s: float | None = None,
                        end_s: float | None = None) -> bool:
        """The magnetometer readings of a log (or a stretch of it) fitted in the Magnetometer
        tab; a log in which the phone hardly turned says so there."""
        try:
            mag, raw = mag_from_log(config.open_log(path), start_s, end_s)
        except config.ConfigError as error:
            self.mag.summary.setText(str(error))
            return False
        self.mag.count = len(raw)
        self.mag.show_result(mag, raw)
        self.message.setText(f"{Path(path).name}: magnetometer fitted on {len(raw)} readings")
        return True

    def _mag_from_log_dialog(self) -> None:
        path, _ = QtWidgets.QFileDialog.getOpenFileName(self, "Magnetometer fit from a log", "",
                                                        "Logs (*.txt *.txt.gz *.json)")
        if path:
            self.analyse_mag_log(path)

    def _from_log_dialog(self) -> None:
        path, _ = QtWidgets.QFileDialog.getOpenFileName(self, "Calibrate from a log", "",
                                                        "Logs (*.txt *.txt.gz *.json)")
        if path:
            self.analyse_log(path)

    # -- profiles -----------------------------------------------------------------------------

    def profile(self) -> Profile:
        """What the tabs hold now as a profile (a loaded profile's parts fill the gaps)."""
        base = self.loaded
        name = self.name.text().strip() or (base.name if base else "unnamed phone")
        rest = self.rest.result
        return Profile(
            name,
            rest=rest.analysis.result.to_dict() if rest else (base.rest if base else None),
            allan=(rest.allan.to_dict() if rest and rest.allan else
                   (base.allan if base else None)),
            mag=self.mag.result.to_dict() if self.mag.result else (base.mag if base else None),
            settings=base.settings if base else None, tuning=base.tuning if base else None)

    def apply(self) -> ekf.EKFSettings | None:
        profile = self.profile()
        if not (profile.rest or profile.mag or profile.settings):
            self.message.setText("nothing to apply yet: calibrate first, or load a profile")
            return None
        settings = profile.to_settings(self._settings())
        self._send(SetSettings(settings, calibration=profile.to_dict(), source="calibration"))
        warnings = profile.warnings(settings)
        self.message.setText(f"applied {profile.name!r}: g, m0, gyro bias"
                             + (", magnetometer correction" if profile.mag else "")
                             + "".join(f"; warning: {text}" for text in warnings))
        self.applied.emit(settings)
        return settings

    def save_profile(self, name: str | None = None) -> Path | None:
        if name:
            self.name.setText(name)
        profile = self.profile()
        try:
            path = self.store.save(profile)
        except config.ConfigError as error:
            self.message.setText(str(error))
            return None
        self.refresh_profiles()
        self.message.setText(f"profile {profile.name!r} saved to {path}")
        return path

    def load_profile(self, name: str) -> Profile | None:
        try:
            profile = self.store.load(name)
        except config.ConfigError as error:
            self.message.setText(str(error))
            return None
        self.loaded = profile
        self.name.setText(profile.name)
        self.rest.result = None
        self.mag.result = None
        parts = [p for p in ("rest", "allan", "mag", "settings") if getattr(profile, p)]
        self.message.setText(f"profile {profile.name!r} loaded ({', '.join(parts) or 'empty'}): "
                             "Apply to use it")
        return profile

    def refresh_profiles(self) -> None:
        self.profiles.clear()
        self.profiles.addItems(self.store.names())
