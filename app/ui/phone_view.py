"""A 3D view of one orientation estimate: a phone model over an East-North-Up ground grid.

The phone is drawn in its own sensor frame (x right, y up the screen, z out of the screen)
and rotated into the world with p_world = Q(q) p_sensor. The camera looks from the south
with z up, as in the course kit. Without OpenGL (offscreen tests, headless CI) the view is a
plain text label with the same public API, so the window still builds.
"""

from __future__ import annotations

import math
import os

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from app.ui.uncertainty import (attitude_covariance, axis_tip_ellipses, ellipse_points,
                                quat_to_matrix)

# Phone size in scene units (about a 7.5 x 15 x 1.6 cm phone, 1 unit = 10 cm).
PHONE_WIDTH = 0.75
PHONE_HEIGHT = 1.5
PHONE_THICKNESS = 0.16
AXIS_LENGTH = 1.15
GRID_LEVEL = -1.0          # the ground grid sits below the phone so they never intersect
AXIS_COLORS = ((1.0, 0.25, 0.25, 1.0), (0.25, 0.9, 0.3, 1.0), (0.35, 0.55, 1.0, 1.0))
CAMERA = {"distance": 4.8, "elevation": 22.0, "azimuth": -90.0}   # azimuth -90: from the south

_gl_available: bool | None = None


def opengl_available() -> bool:
    """Whether a 3D view can be made here, decided without touching GL when it is unsafe.

    Offscreen Qt has no OpenGL and pyqtgraph's GL paths can crash there, so that platform
    never gets a GL widget. Elsewhere a throwaway context is created and made current.
    """
    global _gl_available
    if _gl_available is not None:
        return _gl_available
    platform = os.environ.get("QT_QPA_PLATFORM", "")
    app = QtGui.QGuiApplication.instance()
    if platform.startswith("offscreen") or platform.startswith("minimal") or app is None:
        _gl_available = False
        return False
    if app.platformName() in ("offscreen", "minimal"):
        _gl_available = False
        return False
    try:
        context = QtGui.QOpenGLContext()
        surface = QtGui.QOffscreenSurface()
        surface.create()
        ok = context.create() and surface.isValid() and context.makeCurrent(surface)
        if ok:
            context.doneCurrent()
        _gl_available = bool(ok)
    except Exception:  # any failure here means "no 3D", never a crash
        _gl_available = False
    return _gl_available


def _box_mesh(size: tuple[float, float, float], center: tuple[float, float, float]
              ) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (8, 3) and triangle faces (12, 3) of an axis-aligned box."""
    sx, sy, sz = (s / 2.0 for s in size)
    cx, cy, cz = center
    vertices = np.array([[cx + dx * sx, cy + dy * sy, cz + dz * sz]
                         for dz in (-1, 1) for dy in (-1, 1) for dx in (-1, 1)])
    # Indices: bit0 = +x, bit1 = +y, bit2 = +z. Two triangles per face, outward winding.
    faces = np.array([
        [0, 2, 1], [1, 2, 3],        # -z (back)
        [4, 5, 6], [5, 7, 6],        # +z (screen side)
        [0, 1, 4], [1, 5, 4],        # -y (bottom)
        [2, 6, 3], [3, 6, 7],        # +y (top)
        [0, 4, 2], [2, 4, 6],        # -x (left)
        [1, 3, 5], [3, 7, 5],        # +x (right)
    ])
    return vertices, faces


def _rotation_matrix4(rotation: np.ndarray) -> QtGui.QMatrix4x4:
    r = rotation
    return QtGui.QMatrix4x4(r[0, 0], r[0, 1], r[0, 2], 0.0,
                            r[1, 0], r[1, 1], r[1, 2], 0.0,
                            r[2, 0], r[2, 1], r[2, 2], 0.0,
                            0.0, 0.0, 0.0, 1.0)


def _lit_shader(name: str):
    """Diffuse lighting from behind the camera, upper left (pyqtgraph's "shaded" lights faces
    that point away from the viewer, which leaves the screen face nearly black).

    pyqtgraph compiles a ShaderProgram once, in whichever GL context draws it first, so each
    view gets its own program object: windows that do not share contexts must not share it.
    """
    from pyqtgraph.opengl import shaders
    program = shaders.ShaderProgram(name, [
        shaders.VertexShader("""
            uniform mat4 u_mvp;
            uniform mat3 u_normal;
            attribute vec4 a_position;
            attribute vec3 a_normal;
            attribute vec4 a_color;
            varying vec4 v_color;
            varying vec3 v_normal;
            void main() {
                v_normal = normalize(u_normal * a_normal);
                v_color = a_color;
                gl_Position = u_mvp * a_position;
            }
        """),
        shaders.FragmentShader("""
            #ifdef GL_ES
            precision mediump float;
            #endif
            varying vec4 v_color;
            varying vec3 v_normal;
            void main() {
                float p = dot(normalize(v_normal), normalize(vec3(-0.35, 0.5, 1.0)));
                p = p < 0. ? 0. : p;
                vec3 rgb = v_color.rgb * (0.35 + 0.65 * p);
                gl_FragColor = vec4(rgb, v_color.a);
            }
        """),
    ])
    shaders.ShaderProgram.names.pop(name, None)   # used by object, not looked up by name
    return program


class _PhoneScene:
    """The GL items of one view: grid, compass labels, and the phone group that rotates."""

    count = 0

    def __init__(self, view) -> None:
        import pyqtgraph.opengl as gl

        self.view = view
        _PhoneScene.count += 1
        self.shader = _lit_shader(f"orientation_lab_lit_{_PhoneScene.count}")
        grid = gl.GLGridItem()
        grid.setSize(5, 5)
        grid.setSpacing(0.5, 0.5)
        grid.setColor((150, 160, 175, 110))
        grid.translate(0, 0, GRID_LEVEL)
        view.addItem(grid)
        # Everything below is a child of `phone` and rotates with it.
        self.phone = gl.GLGraphicsItem.GLGraphicsItem()
        view.addItem(self.phone)
        self._add_box(gl, (PHONE_WIDTH, PHONE_HEIGHT, PHONE_THICKNESS), (0, 0, 0),
                      (0.78, 0.80, 0.84, 1.0))
        # Screen: a dark glass panel just above the +z face, with a bezel left around it.
        self._add_box(gl, (PHONE_WIDTH * 0.86, PHONE_HEIGHT * 0.88, 0.01),
                      (0, -0.01, PHONE_THICKNESS / 2 + 0.006), (0.16, 0.38, 0.75, 1.0))
        # Earpiece slot at the top of the screen side: says which end is up from the front.
        self._add_box(gl, (PHONE_WIDTH * 0.3, 0.035, 0.01),
                      (0, PHONE_HEIGHT * 0.47, PHONE_THICKNESS / 2 + 0.006), (0.1, 0.1, 0.1, 1.0))
        # Camera bump at the top back (-z), left of centre as seen from behind.
        self._add_box(gl, (0.26, 0.34, 0.06),
                      (PHONE_WIDTH * 0.22, PHONE_HEIGHT * 0.36, -PHONE_THICKNESS / 2 - 0.03),
                      (0.18, 0.18, 0.2, 1.0))
        for dy in (0.07, -0.07):
            self._add_box(gl, (0.11, 0.11, 0.02),
                          (PHONE_WIDTH * 0.22, PHONE_HEIGHT * 0.36 + dy,
                           -PHONE_THICKNESS / 2 - 0.065), (0.05, 0.05, 0.07, 1.0))

        center = QtCore.Qt.AlignmentFlag.AlignHCenter | QtCore.Qt.AlignmentFlag.AlignVCenter
        self.axes = []
        self.rings = []
        for i, name in enumerate("xyz"):
            tip = np.zeros(3)
            tip[i] = AXIS_LENGTH
            line = gl.GLLinePlotItem(parentItem=self.phone, pos=np.array([np.zeros(3), tip]),
                                     color=AXIS_COLORS[i], width=4, antialias=True,
                                     glOptions="opaque")
            label = gl.GLTextItem(parentItem=self.phone, pos=tip * 1.1, text=name,
                                  font=QtGui.QFont("Sans Serif", 12, QtGui.QFont.Weight.Bold),
                                  color=tuple(int(c * 255) for c in AXIS_COLORS[i]),
                                  alignment=center)
            ring = gl.GLLinePlotItem(parentItem=self.phone, pos=np.zeros((2, 3)),
                                     color=AXIS_COLORS[i][:3] + (0.9,), width=2,
                                     antialias=True, mode="line_strip", glOptions="translucent")
            ring.setVisible(False)
            self.axes.append((line, label))
            self.rings.append(ring)
        self._add_compass(gl)

    def _add_compass(self, gl) -> None:
        """A compass rose on the ground in the front-left corner, where the phone never hides it.

        Added last so its labels paint over the scene.
        """
        origin = np.array([-1.7, -1.3, GRID_LEVEL])
        arrow_length = 0.9
        center = QtCore.Qt.AlignmentFlag.AlignHCenter | QtCore.Qt.AlignmentFlag.AlignVCenter
        font = QtGui.QFont("Sans Serif", 14, QtGui.QFont.Weight.Bold)
        for text, direction in (("N", np.array([0.0, 1.0, 0.0])), ("E", np.array([1.0, 0.0, 0.0]))):
            tip = origin + arrow_length * direction
            side = np.cross(direction, [0.0, 0.0, 1.0]) * 0.08
            head = np.array([tip - 0.18 * direction + side, tip, tip - 0.18 * direction - side])
            for points in (np.array([origin, tip]), head):
                self.view.addItem(gl.GLLinePlotItem(pos=points, color=(1.0, 0.92, 0.47, 1.0),
                                                    width=3, antialias=True, mode="line_strip"))
            self.view.addItem(gl.GLTextItem(pos=tip + 0.22 * direction, text=text, font=font,
                                            color=(255, 235, 120), alignment=center))

    def _add_box(self, gl, size, center, color) -> None:
        vertices, faces = _box_mesh(size, center)
        mesh = gl.MeshData(vertexes=vertices, faces=faces,
                           faceColors=np.tile(np.array(color, float), (len(faces), 1)))
        item = gl.GLMeshItem(parentItem=self.phone, meshdata=mesh, smooth=False,
                             shader=self.shader, glOptions="opaque", drawEdges=False,
                             edgeColor=(0.25, 0.25, 0.28, 1.0))
        del item  # owned by its parent item

    def set_rotation(self, rotation: np.ndarray) -> None:
        self.phone.setTransform(_rotation_matrix4(rotation))

    def set_uncertainty(self, ellipses: list[tuple[np.ndarray, np.ndarray]] | None) -> None:
        for i, ring in enumerate(self.rings):
            if ellipses is None:
                ring.setVisible(False)
                continue
            semi_axes, directions = ellipses[i]
            tip = np.zeros(3)
            tip[i] = AXIS_LENGTH
            ring.setData(pos=ellipse_points(tip, semi_axes, directions))
            ring.setVisible(True)


VERTICAL_FOV_DEG = 42.0


def _make_gl_view():
    """A GLViewWidget whose vertical field of view stays fixed as it is resized.

    pyqtgraph's `fov` is horizontal, so a wide, short view would crop the phone at the top and
    bottom; here the horizontal fov follows the aspect ratio instead.
    """
    import pyqtgraph.opengl as gl

    class _GLView(gl.GLViewWidget):
        def paintGL(self, *args, **kwargs):  # noqa: N802 (Qt name)
            aspect = max(self.width(), 1) / max(self.height(), 1)
            half = math.atan(math.tan(math.radians(VERTICAL_FOV_DEG) / 2) * aspect)
            self.opts["fov"] = min(math.degrees(2 * half), 150.0)
            return super().paintGL(*args, **kwargs)

    return _GLView()


class PhoneView(QtWidgets.QFrame):
    """One titled 3D view (OWN or PHONE). Falls back to a text label without OpenGL.

    Public API: set_orientation(quat, cov), set_uncertainty_visible(bool), reset_camera(),
    `gl_view` (the pyqtgraph GLViewWidget, None without OpenGL).
    """

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

        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.setSpacing(2)
        header = QtWidgets.QHBoxLayout()
        self.title_label = QtWidgets.QLabel(f"<b>{title}</b>")
        self.title_label.setStyleSheet("font-size: 15px;")
        self.detail_label = QtWidgets.QLabel("no data")
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
        self._scene: _PhoneScene | None = None
        if use_gl:
            self.gl_view = _make_gl_view()
            self.gl_view.setBackgroundColor((34, 38, 46))
            self.gl_view.setMinimumSize(200, 180)
            self._scene = _PhoneScene(self.gl_view)
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

    def set_uncertainty_visible(self, visible: bool) -> None:
        self.uncertainty_visible = bool(visible)
        self._update_uncertainty()

    def set_orientation(self, quat: np.ndarray | None, cov: np.ndarray | None = None) -> None:
        """Show orientation `quat` (w-first, sensor -> ENU) and, if given, its 4x4 covariance."""
        if quat is None or not np.all(np.isfinite(quat)) or np.linalg.norm(quat) < 1e-9:
            self.quat = None
            self.cov = None
            self.detail_label.setText("no data")
            self._update_placeholder()
            self._update_uncertainty()
            return
        quat = np.asarray(quat, dtype=float)
        quat = quat / np.linalg.norm(quat)
        # An unchanged pose (a paused replay, a phone at rest) needs no new 3D frame.
        moved = self.quat is None or float(np.abs(quat - self.quat).max()) > 1e-6
        self.quat = quat
        self.cov = None if cov is None else np.asarray(cov, dtype=float)
        self.detail_label.setText("")
        if self._scene is not None and moved:
            self._scene.set_rotation(quat_to_matrix(self.quat))
        self._update_uncertainty()
        self._update_placeholder()

    def attitude_std_deg(self) -> np.ndarray | None:
        """1-sigma attitude error about body x, y, z in degrees, or None without a covariance."""
        if self.quat is None or self.cov is None or self.cov.shape[0] < 4:
            return None
        theta_cov = attitude_covariance(self.quat, self.cov)
        return np.degrees(np.sqrt(np.clip(np.diag(theta_cov), 0.0, None)))

    def _update_uncertainty(self) -> None:
        std = self.attitude_std_deg()
        if std is not None and np.all(np.isfinite(std)):
            self.detail_label.setText(
                "σ (x, y, z) = " + ", ".join(f"{s:.1f}°" for s in std)
                + (f"   rings: {self.n_sigma:g}σ × {self.ring_gain:g}"
                   if self.uncertainty_visible and self._scene is not None else ""))
        if self._scene is None:
            return
        if not self.uncertainty_visible or std is None or not np.all(np.isfinite(std)):
            self._scene.set_uncertainty(None)
            return
        theta_cov = attitude_covariance(self.quat, self.cov)
        self._scene.set_uncertainty(axis_tip_ellipses(theta_cov * self.ring_gain ** 2, AXIS_LENGTH,
                                                      self.n_sigma))

    def _update_placeholder(self) -> None:
        if self.placeholder is None:
            return
        if self.quat is None:
            body = "no orientation yet"
        else:
            w, x, y, z = self.quat
            body = f"q = ({w:+.3f}, {x:+.3f}, {y:+.3f}, {z:+.3f})"
        self.placeholder.setText(f"{self.title}\n(3D view needs OpenGL)\n{body}")

    def grab_image(self) -> QtGui.QImage:
        """The view's current pixels (the GL framebuffer when 3D, else the widget)."""
        if self.gl_view is not None:
            return self.gl_view.grabFramebuffer()
        return self.placeholder.grab().toImage()
