"""The 3D scene behind each phone view: meshes, shaders, one shared offscreen GL context.

The phone is drawn in its own sensor frame (x right, y up the screen, z out of the screen)
and rotated into the world with p_world = Q(q) p_sensor, over an East-North-Up ground grid.
Both views render offscreen in one shared OpenGL context and are shown as images in raster
widgets (no QOpenGLWidget, so Qt never composites the whole window through GL), only when
their scene changed, with a handful of draw calls each (see PhoneScene). OpenGL itself is
imported only where a context exists.

The uncertainty rings: the filter's quaternion covariance turned into shapes to draw, in numpy
(drawing geometry, not filtering: it only re-expresses the covariance the engine computed).
Convention (the course's): q = (q0, q1, q2, q3), w first, sensor -> ENU. A small rotation
error dtheta (rad, in the sensor/body frame) changes the quaternion by dq = 1/2 S̄(q) dtheta,
so on the unit sphere dtheta ≈ 2 S̄(q)^T dq and P_theta = 4 S̄(q)^T P_q S̄(q).
"""

from __future__ import annotations

import ctypes
import os

import numpy as np
from PySide6 import QtGui

# Phone size in scene units (about a 7.5 x 15 x 1.6 cm phone, 1 unit = 10 cm).
PHONE_WIDTH = 0.75
PHONE_HEIGHT = 1.5
PHONE_THICKNESS = 0.16
AXIS_LENGTH = 1.15
GRID_LEVEL = -1.0          # the ground grid sits below the phone so they never intersect
AXIS_COLORS = ((1.0, 0.25, 0.25, 1.0), (0.25, 0.9, 0.3, 1.0), (0.35, 0.55, 1.0, 1.0))
# The σ text in the header changes at most this often (s); rings are redrawn only when the
# attitude covariance changed by more than this fraction of its largest entry.
DETAIL_INTERVAL_S = 0.2
RING_REDRAW_CHANGE = 0.02
# The phone is turned (and the view rendered again) only when a quaternion component changed
# by more than this: about 0.01 degrees, far below a pixel.
REDRAW_QUAT_CHANGE = 1e-4
CAMERA = {"distance": 4.8, "elevation": 22.0, "azimuth": -90.0}   # azimuth -90: from the south


# ---- the uncertainty rings' geometry (numpy) -----------------------------------------------

def s_bar(quat: np.ndarray) -> np.ndarray:
    """The course's S̄(q), shape (4, 3): dq/dt = 1/2 S̄(q) omega for a body-frame rate omega."""
    q0, q1, q2, q3 = (float(v) for v in quat)
    return np.array([
        [-q1, -q2, -q3],
        [q0, -q3, q2],
        [q3, q0, -q1],
        [-q2, q1, q0],
    ])


def attitude_covariance(quat: np.ndarray, quat_cov: np.ndarray) -> np.ndarray:
    """Map a 4x4 quaternion covariance to the 3x3 covariance of the body-frame rotation error.

    Args:
        quat: (4,) unit quaternion, w first.
        quat_cov: (4, 4) covariance of the quaternion state (only the top-left 4x4 block is
            used when a larger state covariance is given, e.g. with gyro bias).
    Returns:
        (3, 3) symmetric covariance of dtheta in rad^2, body frame.
    """
    quat = np.asarray(quat, dtype=float)
    quat = quat / np.linalg.norm(quat)
    cov = np.asarray(quat_cov, dtype=float)[:4, :4]
    jac = 2.0 * s_bar(quat).T          # dtheta = jac @ dq
    theta_cov = jac @ cov @ jac.T
    return 0.5 * (theta_cov + theta_cov.T)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def axis_tip_ellipses(theta_cov: np.ndarray, axis_length: float = 1.0, n_sigma: float = 1.0,
                      max_angle_rad: float = np.radians(35.0)) -> list[tuple[np.ndarray, np.ndarray]]:
    """Where each body axis tip may be: one ellipse per axis, in the body frame.

    A rotation error dtheta moves the tip of body axis e_i by dtheta x (L e_i) = -L [e_i]x dtheta,
    so the tip displacement covariance is L^2 [e_i]x P_theta [e_i]x^T (rank 2, perpendicular to e_i).

    Args:
        theta_cov: (3, 3) attitude-error covariance, rad^2, body frame.
        axis_length: length L of the drawn axes (scene units).
        n_sigma: how many standard deviations the ellipse shows.
        max_angle_rad: cap on the drawn half-angle so a diverged filter stays drawable.
    Returns:
        For axes x, y, z: (semi_axes (2,), directions (2, 3)) with semi-axis lengths in scene
        units and unit directions (body frame) perpendicular to that axis.
    """
    theta_cov = np.asarray(theta_cov, dtype=float)
    result = []
    for i in range(3):
        axis = np.zeros(3)
        axis[i] = 1.0
        skew = _skew(axis)
        tip_cov = skew @ theta_cov @ skew.T
        eigenvalues, eigenvectors = np.linalg.eigh(0.5 * (tip_cov + tip_cov.T))
        # The largest two eigenvalues span the plane perpendicular to the axis.
        order = np.argsort(eigenvalues)[::-1][:2]
        std = np.sqrt(np.clip(eigenvalues[order], 0.0, None))
        angles = np.minimum(n_sigma * std, max_angle_rad)
        semi_axes = axis_length * np.tan(np.minimum(angles, np.radians(80.0)))
        result.append((semi_axes, eigenvectors[:, order].T))
    return result


def ellipse_points(center: np.ndarray, semi_axes: np.ndarray, directions: np.ndarray,
                   segments: int = 32) -> np.ndarray:
    """Closed polyline (segments + 1, 3) of an ellipse in 3D."""
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    return (np.asarray(center, dtype=float)[None, :]
            + np.cos(phi)[:, None] * semi_axes[0] * directions[0][None, :]
            + np.sin(phi)[:, None] * semi_axes[1] * directions[1][None, :])


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """Q(q), (3, 3): p_world = Q(q) p_sensor, for a w-first quaternion (normalised here)."""
    q = np.asarray(quat, dtype=float)
    q0, q1, q2, q3 = q / np.linalg.norm(q)
    return np.array([
        [q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
        [2 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2 * (q2 * q3 - q0 * q1)],
        [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3],
    ])


# ---- the scene ------------------------------------------------------------------------------

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


VERTEX_SHADER = """
uniform mat4 u_mvp;
uniform mat3 u_normal;
uniform float u_lit;
attribute vec3 a_position;
attribute vec3 a_normal;
attribute vec4 a_color;
varying vec4 v_color;
void main() {
    // Diffuse light from behind the camera, upper left (the faces are flat, so lighting per
    // vertex is lighting per face). Lines are drawn unlit (u_lit = 0).
    float p = max(dot(normalize(u_normal * a_normal), normalize(vec3(-0.35, 0.5, 1.0))), 0.0);
    float shade = mix(1.0, 0.35 + 0.65 * p, u_lit);
    v_color = vec4(a_color.rgb * shade, a_color.a);
    gl_Position = u_mvp * vec4(a_position, 1.0);
}
"""
FRAGMENT_SHADER = """
#ifdef GL_ES
precision mediump float;
#endif
varying vec4 v_color;
void main() {
    gl_FragColor = v_color;
}
"""
FLOATS_PER_VERTEX = 10          # position (3), normal (3), colour RGBA (4)


def _merged_boxes(boxes: list[tuple[tuple[float, float, float], tuple[float, float, float],
                                     tuple[float, float, float, float]]]) -> np.ndarray:
    """Triangles of several (size, center, color) boxes as vertex rows (36 n, 10): position,
    face normal, colour. One array is one draw call instead of one per box."""
    rows = []
    for size, center, color in boxes:
        vertices, faces = _box_mesh(size, center)
        corners = vertices[faces]                                   # (12, 3, 3)
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        block = np.empty((len(faces), 3, FLOATS_PER_VERTEX))
        block[..., 0:3] = corners
        block[..., 3:6] = normals[:, None, :]
        block[..., 6:10] = color
        rows.append(block.reshape(-1, FLOATS_PER_VERTEX))
    return np.vstack(rows)


def _line_rows(points: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """Vertex rows (n, 10) for line vertices `points` (n, 3) with colours (n, 4) or (4,)."""
    rows = np.zeros((len(points), FLOATS_PER_VERTEX))
    rows[:, 0:3] = points
    rows[:, 5] = 1.0
    rows[:, 6:10] = colors
    return rows


RING_SEGMENTS = 32


class _RingSet:
    """The three uncertainty rings: shown or hidden together (the scene draws them)."""

    def __init__(self) -> None:
        self._visible = False

    def visible(self) -> bool:
        return self._visible


class PhoneScene:
    """Everything one view draws, as one vertex buffer and a dozen GL calls per frame.

    World part: the East-North-Up ground grid and a compass (N and E arrows). Phone part,
    turned by the orientation: the body (six boxes: body, screen, earpiece, camera bump and
    two lenses) as lit triangles, the body axes x red, y green, z blue, and the uncertainty
    rings at the axis tips. Text labels (x, y, z, N, E) are painted with QPainter over the
    rendered image by the view (`labels()`).

    Why not pyqtgraph's GL items: each costs ~30 OpenGL calls per frame from Python, and
    every call through PyOpenGL releases and re-takes the GIL, which a busy engine thread
    then holds for up to a switch interval. Here a new orientation only changes a matrix; the
    vertices are uploaded once, the rings again only when the covariance visibly changed.
    """

    def __init__(self) -> None:
        self.rotation = np.eye(3)
        self.phone_matrix = QtGui.QMatrix4x4()
        self.rings = [_RingSet()]
        self._ring_rows = np.zeros((6 * RING_SEGMENTS, FLOATS_PER_VERTEX))
        self._ring_dirty = False
        self.changed = lambda: None          # set by the view: asks for a new render

        half = 2.5
        ticks = np.arange(-half, half + 1e-9, 0.5)
        grid = []
        for value in ticks:
            grid += [[value, -half, GRID_LEVEL], [value, half, GRID_LEVEL],
                     [-half, value, GRID_LEVEL], [half, value, GRID_LEVEL]]
        grid_rows = _line_rows(np.array(grid), np.array([150, 160, 175, 110]) / 255.0)
        origin = np.array([-1.7, -1.3, GRID_LEVEL])
        arrow_length = 0.9
        compass = []
        self.world_labels: list[tuple[np.ndarray, str, tuple[int, int, int], int]] = []
        for text, direction in (("N", np.array([0.0, 1.0, 0.0])), ("E", np.array([1.0, 0.0, 0.0]))):
            tip = origin + arrow_length * direction
            side = np.cross(direction, [0.0, 0.0, 1.0]) * 0.08
            back = tip - 0.18 * direction
            compass += [origin, tip, back + side, tip, tip, back - side]
            self.world_labels.append((tip + 0.22 * direction, text, (255, 235, 120), 14))
        compass_rows = _line_rows(np.array(compass), (1.0, 0.92, 0.47, 1.0))
        lens = (PHONE_WIDTH * 0.22, PHONE_HEIGHT * 0.36)
        body_rows = _merged_boxes([
            ((PHONE_WIDTH, PHONE_HEIGHT, PHONE_THICKNESS), (0, 0, 0), (0.78, 0.80, 0.84, 1.0)),
            # Screen: a dark glass panel just above the +z face, with a bezel left around it.
            ((PHONE_WIDTH * 0.86, PHONE_HEIGHT * 0.88, 0.01),
             (0, -0.01, PHONE_THICKNESS / 2 + 0.006), (0.16, 0.38, 0.75, 1.0)),
            # Earpiece slot at the top of the screen side: says which end is up from the front.
            ((PHONE_WIDTH * 0.3, 0.035, 0.01),
             (0, PHONE_HEIGHT * 0.47, PHONE_THICKNESS / 2 + 0.006), (0.1, 0.1, 0.1, 1.0)),
            # Camera bump at the top back (-z), left of centre as seen from behind, two lenses.
            ((0.26, 0.34, 0.06), (lens[0], lens[1], -PHONE_THICKNESS / 2 - 0.03),
             (0.18, 0.18, 0.2, 1.0)),
            ((0.11, 0.11, 0.02), (lens[0], lens[1] + 0.07, -PHONE_THICKNESS / 2 - 0.065),
             (0.05, 0.05, 0.07, 1.0)),
            ((0.11, 0.11, 0.02), (lens[0], lens[1] - 0.07, -PHONE_THICKNESS / 2 - 0.065),
             (0.05, 0.05, 0.07, 1.0)),
        ])
        tips = np.eye(3) * AXIS_LENGTH
        axis_rows = _line_rows(np.vstack([[np.zeros(3), tip] for tip in tips]),
                               np.repeat(np.array(AXIS_COLORS), 2, axis=0))
        self.phone_labels = [(tip * 1.1, name, tuple(int(c * 255) for c in AXIS_COLORS[i]), 12)
                             for i, (tip, name) in enumerate(zip(tips, "xyz"))]
        self._ring_colors = np.repeat(np.array([color[:3] + (0.9,) for color in AXIS_COLORS]),
                                      2 * RING_SEGMENTS, axis=0)
        # (first vertex, count, primitive, line width) of each part, in buffer order.
        parts = [("grid", grid_rows), ("compass", compass_rows), ("body", body_rows),
                 ("axes", axis_rows), ("rings", self._ring_rows)]
        self.ranges: dict[str, tuple[int, int]] = {}
        first = 0
        for name, rows in parts:
            self.ranges[name] = (first, len(rows))
            first += len(rows)
        self.vertices = np.vstack([rows for _, rows in parts]).astype(np.float32)
        self._buffer = None
        self._program = None

    # -- state -----------------------------------------------------------------------------

    def set_rotation(self, rotation: np.ndarray) -> None:
        self.rotation = np.asarray(rotation, dtype=float)
        self.phone_matrix = _rotation_matrix4(self.rotation)
        self.changed()

    def set_uncertainty(self, ellipses: list[tuple[np.ndarray, np.ndarray]] | None) -> None:
        if ellipses is None:
            if self.rings[0]._visible:          # hiding again would ask for a new render
                self.rings[0]._visible = False
                self.changed()
            return
        pieces = []
        for i, (semi_axes, directions) in enumerate(ellipses):
            tip = np.zeros(3)
            tip[i] = AXIS_LENGTH
            points = ellipse_points(tip, semi_axes, directions, RING_SEGMENTS)
            # As separate segments (GL_LINES) so the three rings are one draw call.
            pieces.append(np.repeat(points, 2, axis=0)[1:-1])
        self._ring_rows = _line_rows(np.vstack(pieces), self._ring_colors)
        self._ring_dirty = True
        self.rings[0]._visible = True
        self.changed()

    def labels(self) -> list[tuple[QtGui.QMatrix4x4 | None, np.ndarray, str,
                                   tuple[int, int, int], int]]:
        """(model transform or None for world, position, text, colour, size) of every label."""
        return ([(self.phone_matrix, *label) for label in self.phone_labels]
                + [(None, *label) for label in self.world_labels])

    # -- drawing (the shared GL context is current) -----------------------------------------

    def has_buffer(self) -> bool:
        """Whether the scene's vertex buffer exists in the shared GL context."""
        return self._buffer is not None

    def release_buffer(self, GL) -> None:
        """Delete the scene's vertex buffer (the shared context current); the next render makes
        it again."""
        if self._buffer is not None:
            GL.glDeleteBuffers(1, [self._buffer])
            self._buffer = None

    def _prepare(self, GL) -> None:
        from OpenGL.GL import shaders
        if self._program is None:
            self._program = _shared_program(GL, shaders)
            self._locations = {name: GL.glGetUniformLocation(self._program, name)
                               for name in ("u_mvp", "u_normal", "u_lit")}
            self._attributes = [GL.glGetAttribLocation(self._program, name)
                                for name in ("a_position", "a_normal", "a_color")]
        if self._buffer is None:
            self._buffer = GL.glGenBuffers(1)
            GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self._buffer)
            GL.glBufferData(GL.GL_ARRAY_BUFFER, self.vertices.nbytes, self.vertices,
                            GL.GL_DYNAMIC_DRAW)
            self._ring_dirty = self.rings[0]._visible
        else:
            GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self._buffer)
        if self._ring_dirty:
            first, _ = self.ranges["rings"]
            rows = self._ring_rows.astype(np.float32)
            GL.glBufferSubData(GL.GL_ARRAY_BUFFER, first * FLOATS_PER_VERTEX * 4, rows.nbytes,
                               rows)
            self._ring_dirty = False

    def draw(self, GL, projection: QtGui.QMatrix4x4, view: QtGui.QMatrix4x4) -> None:
        """Draw into the bound framebuffer (cleared by the caller) with this camera."""
        self._prepare(GL)
        GL.glUseProgram(self._program)
        stride = FLOATS_PER_VERTEX * 4
        for location, (offset, size) in zip(self._attributes, ((0, 3), (3, 3), (6, 4))):
            GL.glEnableVertexAttribArray(location)
            GL.glVertexAttribPointer(location, size, GL.GL_FLOAT, False, stride,
                                     ctypes.c_void_p(offset * 4))
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glEnable(GL.GL_BLEND)
        GL.glBlendFunc(GL.GL_SRC_ALPHA, GL.GL_ONE_MINUS_SRC_ALPHA)
        world = projection * view
        phone = world * self.phone_matrix
        normal = np.array((view * self.phone_matrix).normalMatrix().data(), dtype=np.float32)
        GL.glUniformMatrix4fv(self._locations["u_mvp"], 1, False,
                              np.array(world.data(), dtype=np.float32))
        GL.glUniform1f(self._locations["u_lit"], 0.0)
        self._draw_part(GL, "grid", GL.GL_LINES, 1.0)
        self._draw_part(GL, "compass", GL.GL_LINES, 3.0)
        GL.glUniformMatrix4fv(self._locations["u_mvp"], 1, False,
                              np.array(phone.data(), dtype=np.float32))
        GL.glUniformMatrix3fv(self._locations["u_normal"], 1, False, normal)
        GL.glUniform1f(self._locations["u_lit"], 1.0)
        self._draw_part(GL, "body", GL.GL_TRIANGLES, None)
        GL.glUniform1f(self._locations["u_lit"], 0.0)
        self._draw_part(GL, "axes", GL.GL_LINES, 4.0)
        if self.rings[0]._visible:
            self._draw_part(GL, "rings", GL.GL_LINES, 2.0)
        for location in self._attributes:
            GL.glDisableVertexAttribArray(location)
        GL.glUseProgram(0)
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, 0)

    def _draw_part(self, GL, name: str, primitive, line_width: float | None) -> None:
        first, count = self.ranges[name]
        if line_width is not None:
            GL.glLineWidth(line_width)
        GL.glDrawArrays(primitive, first, count)


_program = None


def _shared_program(GL, shaders):
    """The scenes' shader program, compiled once in the shared context."""
    global _program
    if _program is None:
        _program = shaders.compileProgram(
            shaders.compileShader(VERTEX_SHADER, GL.GL_VERTEX_SHADER),
            shaders.compileShader(FRAGMENT_SHADER, GL.GL_FRAGMENT_SHADER),
            validate=False)
    return _program


class RenderContext:
    """The process's one OpenGL context and an offscreen surface to make it current on.

    Every 3D view renders into its own framebuffer object in this context and shows the
    pixels as an image in an ordinary (raster) widget. An on-screen GL widget would instead
    make Qt composite the whole top-level window through OpenGL on every frame, which in
    software GL (llvmpipe) costs more than drawing the scenes themselves.
    """

    _instance: RenderContext | None = None

    def __init__(self) -> None:
        self.surface = QtGui.QOffscreenSurface()
        self.surface.setFormat(QtGui.QSurfaceFormat.defaultFormat())
        self.surface.create()
        self.context = QtGui.QOpenGLContext()
        self.context.setFormat(QtGui.QSurfaceFormat.defaultFormat())
        if not self.context.create() or not self.surface.isValid():
            raise RuntimeError("cannot create an OpenGL context")
        self.vertex_array = None
        self.software = False

    @classmethod
    def get(cls) -> RenderContext:
        if cls._instance is None:
            cls._instance = cls()
            cls._instance._first_use()
        return cls._instance

    def _first_use(self) -> None:
        from OpenGL import GL
        from PySide6 import QtOpenGL
        self.make_current()
        renderer = (GL.glGetString(GL.GL_RENDERER) or b"").decode(errors="replace").lower()
        self.software = any(name in renderer for name in SOFTWARE_RENDERERS)
        if self.context.format().profile() == QtGui.QSurfaceFormat.OpenGLContextProfile.CoreProfile:
            self.vertex_array = QtOpenGL.QOpenGLVertexArrayObject()
            self.vertex_array.create()
            self.vertex_array.bind()

    def make_current(self) -> bool:
        return bool(self.context.makeCurrent(self.surface))

    def done_current(self) -> None:
        self.context.doneCurrent()


# Substrings of GL_RENDERER for drivers that rasterise on the CPU.
SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swrast", "software", "swiftshader")


def software_gl() -> bool:
    """Whether the 3D views render with a CPU rasteriser (Mesa llvmpipe and the like);
    False where there is no OpenGL at all."""
    if not opengl_available():
        return False
    try:
        return RenderContext.get().software
    except RuntimeError:
        return False


VERTICAL_FOV_DEG = 42.0
