"""A 3D view of one orientation estimate: a phone model over an East-North-Up ground grid.

The camera looks from the south with z up, as in the course kit. The scene and its shared
offscreen GL context are in app/ui/scene.py, the widget that shows it in app/ui/scene_view.py
(imported only with OpenGL). Without OpenGL (offscreen tests, headless CI) the view is a plain
text label with the same public API, so the window still builds.
"""

from __future__ import annotations

import math
import time

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from app.ui.elided import ElidedLabel
from app.ui.scene import (AXIS_LENGTH, CAMERA, DETAIL_INTERVAL_S, REDRAW_QUAT_CHANGE,
                          RING_REDRAW_CHANGE, PhoneScene, attitude_covariance,
                          axis_tip_ellipses, opengl_available, quat_to_matrix, software_gl)

__all__ = ["PhoneView", "opengl_available", "software_gl"]


def _make_gl_view():
    """A new offscreen-rendered 3D scene widget (see app.ui.scene_view.SceneView)."""
    from app.ui.scene_view import SceneView
    return SceneView()


class PhoneView(QtWidgets.QFrame):
    """One titled 3D view (OWN or PHONE). Falls back to a text label without OpenGL.

    Public API: set_orientation(quat, cov), set_no_data(text) (the view greys out and says why:
    "waiting for data", "no ORI in this stream"), set_uncertainty_visible(bool), reset_camera(),
    camera() / set_camera(opts) and the `camera_changed` signal (to link views), `gl_view` (the
    offscreen-rendered 3D scene widget, None without OpenGL; its `frames_painted` counts the
    frames it painted).
    """

    camera_changed = QtCore.Signal()

    def __init__(self, title: str, parent: QtWidgets.QWidget | None = None,
                 use_gl: bool | None = None) -> None:
        super().__init__(parent)
        self.setObjectName(f"phone_view_{title.lower()}")
        self.setFrameShape(QtWidgets.QFrame.Shape.StyledPanel)
        self.title = title
        self.quat: np.ndarray | None = None
        self.cov: np.ndarray | None = None
        self.uncertainty_visible = True
        # A converged filter has a few tenths of a degree of uncertainty, invisible at true
        # scale; the rings show n_sigma standard deviations magnified by ring_gain (and say so).
        self.n_sigma = 2.0
        self.ring_gain = 10.0
        self._detail_changed_at = -math.inf
        self._drawn_theta_cov: np.ndarray | None = None
        self._drawn_quat: np.ndarray | None = None
        self.pose_changes = 0           # visible pose changes handed to the 3D scene
        self.no_data_text = "waiting for data"

        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.setSpacing(2)
        header = QtWidgets.QHBoxLayout()
        self.title_label = QtWidgets.QLabel(f"<b>{title}</b>")
        self.title_label.setStyleSheet("font-size: 15px;")
        self.detail_label = ElidedLabel("no data")
        self.detail_label.setStyleSheet("color: gray;")
        self.reset_camera_button = QtWidgets.QToolButton()
        self.reset_camera_button.setText("Reset view")
        self.reset_camera_button.setToolTip("Look from the south with z up again")
        self.reset_camera_button.clicked.connect(self.reset_camera)
        header.addWidget(self.title_label)
        header.addWidget(self.detail_label, 1)
        header.addWidget(self.reset_camera_button)
        layout.addLayout(header)

        if use_gl is None:
            use_gl = opengl_available()
        self.gl_view = None
        self._scene: PhoneScene | None = None
        if use_gl:
            self.gl_view = _make_gl_view()
            self.gl_view.setBackgroundColor((34, 38, 46))
            self.gl_view.setMinimumSize(200, 180)
            self._scene = PhoneScene()
            self._scene.changed = self.gl_view.update
            self.gl_view.scene = self._scene
            self.gl_view.camera_changed.connect(self.camera_changed)
            self.gl_view.set_overlay(self.no_data_text)
            self.reset_camera()
            layout.addWidget(self.gl_view, 1)
            self.placeholder = None
        else:
            self.placeholder = QtWidgets.QLabel()
            self.placeholder.setAlignment(QtCore.Qt.AlignmentFlag.AlignCenter)
            self.placeholder.setMinimumSize(200, 120)
            self.placeholder.setStyleSheet("background: #22262e; color: #c8ccd4;")
            layout.addWidget(self.placeholder, 1)
            self._update_placeholder()

    def reset_camera(self) -> None:
        """Back to the course kit's view: from the south, slightly above, z up."""
        if self.gl_view is None:
            return
        self.gl_view.opts["center"] = QtGui.QVector3D(0, 0, -0.2)
        self.gl_view.setCameraPosition(**CAMERA)

    def camera(self) -> dict:
        """The camera: distance, elevation, azimuth [deg] and the centre it looks at."""
        if self.gl_view is None:
            return {}
        opts = self.gl_view.opts
        center = opts["center"]
        return {"distance": float(opts["distance"]), "elevation": float(opts["elevation"]),
                "azimuth": float(opts["azimuth"]),
                "center": (center.x(), center.y(), center.z())}

    def set_camera(self, camera: dict) -> None:
        """Look from `camera` (as camera() gives it); nothing without OpenGL."""
        if self.gl_view is None or not camera:
            return
        if camera == self.camera():
            return
        self.gl_view.opts["center"] = QtGui.QVector3D(*camera["center"])
        self.gl_view.setCameraPosition(distance=camera["distance"],
                                       elevation=camera["elevation"],
                                       azimuth=camera["azimuth"])

    def set_no_data(self, text: str) -> None:
        """Grey the view out and say why there is nothing to show ("" : show the phone)."""
        self.no_data_text = text
        if self.gl_view is not None:
            self.gl_view.set_overlay(text)
        if text:
            self._set_detail(text, urgent=True)
        self._update_placeholder()

    def set_uncertainty_visible(self, visible: bool) -> None:
        self.uncertainty_visible = bool(visible)
        self._update_uncertainty()

    def set_orientation(self, quat: np.ndarray | None, cov: np.ndarray | None = None) -> None:
        """Show orientation `quat` (w-first, sensor -> ENU) and, if given, its 4x4 covariance."""
        if quat is None or not np.all(np.isfinite(quat)) or np.linalg.norm(quat) < 1e-9:
            self.quat = None
            self.cov = None
            self.set_no_data(self.no_data_text or "waiting for data")
            self._update_uncertainty()
            return
        if self.no_data_text:
            self.set_no_data("")
        quat = np.asarray(quat, dtype=float)
        quat = quat / np.linalg.norm(quat)
        self.quat = quat
        self.cov = None if cov is None else np.asarray(cov, dtype=float)
        # A pose that did not visibly change (a paused replay, a phone at rest with a little
        # noise) needs no new 3D frame.
        drawn = self._drawn_quat
        if self._scene is not None and (drawn is None or float(np.abs(quat - drawn).max())
                                        > REDRAW_QUAT_CHANGE):
            self._drawn_quat = quat
            self.pose_changes += 1
            self._scene.set_rotation(quat_to_matrix(quat))
        self._update_uncertainty()
        self._update_placeholder()

    def attitude_std_deg(self) -> np.ndarray | None:
        """1-sigma attitude error about body x, y, z in degrees, or None without a covariance."""
        if self.quat is None or self.cov is None or self.cov.shape[0] < 4:
            return None
        theta_cov = attitude_covariance(self.quat, self.cov)
        return np.degrees(np.sqrt(np.clip(np.diag(theta_cov), 0.0, None)))

    def _set_detail(self, text: str, urgent: bool = False) -> None:
        """Change the header text, at most DETAIL_INTERVAL_S apart unless `urgent` (a label
        re-laid-out on every frame costs more than it tells: nobody reads 60 numbers/s)."""
        if text == self.detail_label.text():
            return
        now = time.monotonic()
        if urgent or now - self._detail_changed_at >= DETAIL_INTERVAL_S:
            self._detail_changed_at = now
            self.detail_label.setText(text)

    def _update_uncertainty(self) -> None:
        if self.quat is None or self.cov is None or self.cov.shape[0] < 4:
            theta_cov = None
        else:
            theta_cov = attitude_covariance(self.quat, self.cov)
        std = (None if theta_cov is None
               else np.degrees(np.sqrt(np.clip(np.diag(theta_cov), 0.0, None))))
        valid = std is not None and bool(np.all(np.isfinite(std)))
        if valid:
            text = ("σ (x, y, z) = " + ", ".join(f"{s:.1f}°" for s in std)
                    + (f"   rings: {self.n_sigma:g}σ × {self.ring_gain:g}"
                       if self.uncertainty_visible and self._scene is not None else ""))
            # The first σ after "no data" (or a switch of the rings) shows at once.
            self._set_detail(text, urgent="σ" not in self.detail_label.text()
                             or ("rings" in text) != ("rings" in self.detail_label.text()))
        elif self.quat is not None:
            self._set_detail("", urgent=True)
        if self._scene is None:
            return
        if not self.uncertainty_visible or not valid:
            self._drawn_theta_cov = None
            self._scene.set_uncertainty(None)
            return
        # New ring geometry only when the covariance changed visibly: the rings are in the
        # phone's frame, so turning the phone needs no new vertices.
        drawn = self._drawn_theta_cov
        if drawn is not None and (np.abs(theta_cov - drawn).max()
                                  <= RING_REDRAW_CHANGE * np.abs(drawn).max()):
            return
        self._drawn_theta_cov = theta_cov
        self._scene.set_uncertainty(axis_tip_ellipses(theta_cov * self.ring_gain ** 2, AXIS_LENGTH,
                                                      self.n_sigma))

    def _update_placeholder(self) -> None:
        if self.placeholder is None:
            return
        if self.quat is None or self.no_data_text:
            body = self.no_data_text or "waiting for data"
        else:
            w, x, y, z = self.quat
            body = f"q = ({w:+.3f}, {x:+.3f}, {y:+.3f}, {z:+.3f})"
        self.placeholder.setText(f"{self.title}\n(3D view needs OpenGL)\n{body}")

    def release_gl(self) -> None:
        """Free the 3D view's GL objects (the window calls this when it shuts down)."""
        if self.gl_view is not None:
            self.gl_view.release()

    def grab_image(self) -> QtGui.QImage:
        """The view's current pixels (the GL framebuffer when 3D, else the widget)."""
        if self.gl_view is not None:
            return self.gl_view.grabFramebuffer()
        return self.placeholder.grab().toImage()
