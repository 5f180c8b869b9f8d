"""The widget of a 3D view: a PhoneScene rendered offscreen, with pyqtgraph's camera and
mouse orbit/zoom. Imported only when OpenGL is available (pyqtgraph.opengl needs it)."""

from __future__ import annotations

import math

import numpy as np
from OpenGL import GL
from pyqtgraph.opengl.GLViewWidget import GLViewMixin
from PySide6 import QtCore, QtGui, QtOpenGL, QtWidgets

from app.ui.scene import VERTICAL_FOV_DEG, PhoneScene, RenderContext


class SceneView(GLViewMixin, QtWidgets.QWidget):
    """A 3D scene (PhoneScene) rendered offscreen, with pyqtgraph's camera and mouse
    orbit/zoom (GLViewMixin).

    Rendering happens in paintEvent and only when something changed (the scene, the
    camera, the size): `update()` marks the scene for rendering and asks Qt for a repaint, and Qt
    merges all repaints of one event-loop pass into one painted frame; `frames_painted`
    counts the frames this widget actually painted. With `overlay_text` set (no data) the
    scene is greyed out and the text says why. Turning or zooming with the mouse emits
    `camera_changed`.
    """

    camera_changed = QtCore.Signal()

    def __init__(self) -> None:
        self.overlay_text = ""
        self._needs_render = True
        self._image: QtGui.QImage | None = None
        self._framebuffer = None
        self._label_painter_fonts: dict[int, QtGui.QFont] = {}
        self.scene: PhoneScene | None = None
        super().__init__()
        self.setFocusPolicy(QtCore.Qt.FocusPolicy.ClickFocus)
        # The widget paints every pixel itself: Qt need not clear or blend below it.
        self.setAttribute(QtCore.Qt.WidgetAttribute.WA_OpaquePaintEvent)
        self.frames_rendered = 0
        self.frames_painted = 0

    # -- what GLViewMixin expects of its widget --------------------------------------------

    def isValid(self) -> bool:  # noqa: N802 (Qt name)
        return False     # GLViewMixin.addItem: no pyqtgraph items are used here

    def update(self, *args) -> None:
        self._needs_render = True
        super().update(*args)

    def resizeEvent(self, event) -> None:  # noqa: N802 (Qt name)
        self._needs_render = True
        super().resizeEvent(event)

    # -- rendering -------------------------------------------------------------------------

    def render_scene(self) -> QtGui.QImage | None:
        """Draw the scene into this view's framebuffer and read it back (device pixels)."""
        ratio = self.devicePixelRatioF()
        width = max(int(self.width() * ratio), 1)
        height = max(int(self.height() * ratio), 1)
        try:
            target = RenderContext.get()
        except RuntimeError:
            return None
        if not target.make_current():
            return None
        try:
            if (self._framebuffer is None or self._framebuffer.width() != width
                    or self._framebuffer.height() != height):
                self._framebuffer = QtOpenGL.QOpenGLFramebufferObject(
                    width, height, QtOpenGL.QOpenGLFramebufferObject.Attachment.Depth)
            self._framebuffer.bind()
            # Vertical field of view fixed (pyqtgraph's fov is horizontal), so a wide,
            # short view does not crop the phone at the top and bottom.
            aspect = width / height
            half = math.atan(math.tan(math.radians(VERTICAL_FOV_DEG) / 2) * aspect)
            self.opts["fov"] = min(math.degrees(2 * half), 150.0)
            GL.glViewport(0, 0, width, height)
            GL.glClearColor(*self.opts["bgcolor"])
            GL.glClear(GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT)
            if self.scene is not None:
                region = (0, 0, self.width(), self.height())
                self.scene.draw(GL, self.projectionMatrix(region, region), self.viewMatrix())
            pixels = np.empty((height, width, 4), np.uint8)
            GL.glReadPixels(0, 0, width, height, GL.GL_BGRA, GL.GL_UNSIGNED_BYTE, pixels)
            self._framebuffer.release()
        finally:
            target.done_current()
        # GL rows run bottom-up; QImage rows top-down.
        flipped = np.ascontiguousarray(pixels[::-1])
        image = QtGui.QImage(flipped.data, width, height, 4 * width,
                             QtGui.QImage.Format.Format_RGB32).copy()
        image.setDevicePixelRatio(ratio)
        self.frames_rendered += 1
        return image

    def _current_image(self) -> QtGui.QImage | None:
        if self._needs_render or self._image is None:
            self._needs_render = False
            self._image = self.render_scene()
        return self._image

    def set_overlay(self, text: str) -> None:
        if text != self.overlay_text:
            self.overlay_text = text
            self.update()

    def mouseMoveEvent(self, event) -> None:  # noqa: N802 (Qt name)
        super().mouseMoveEvent(event)
        if event.buttons():
            self.camera_changed.emit()

    def wheelEvent(self, event) -> None:  # noqa: N802 (Qt name)
        super().wheelEvent(event)
        self.camera_changed.emit()

    def paintEvent(self, event) -> None:  # noqa: N802 (Qt name)
        image = self._current_image()
        painter = QtGui.QPainter(self)
        if self.overlay_text:
            if image is not None:
                painter.drawImage(0, 0, image)
            painter.fillRect(self.rect(), QtGui.QColor(60, 63, 70, 215))
            painter.setPen(QtGui.QColor(225, 228, 235))
            font = painter.font()
            font.setPointSize(13)
            painter.setFont(font)
            painter.drawText(self.rect(), QtCore.Qt.AlignmentFlag.AlignCenter, self.overlay_text)
        elif image is None:
            painter.fillRect(self.rect(), QtGui.QColor(34, 38, 46))
            painter.setPen(QtGui.QColor(200, 204, 212))
            painter.drawText(self.rect(), QtCore.Qt.AlignmentFlag.AlignCenter,
                             "3D view: OpenGL failed")
        else:
            painter.drawImage(0, 0, image)
            self._paint_labels(painter)
        painter.end()
        self.frames_painted += 1

    def _paint_labels(self, painter: QtGui.QPainter) -> None:
        if self.scene is None:
            return
        region = (0, 0, self.width(), self.height())
        to_screen = QtGui.QMatrix4x4()
        to_screen.viewport(0, self.height(), self.width(), -self.height())
        world_to_screen = to_screen * self.projectionMatrix(region, region) * self.viewMatrix()
        metrics_cache = {}
        for transform, position, text, color, size in self.scene.labels():
            matrix = world_to_screen if transform is None else world_to_screen * transform
            point = matrix.map(QtGui.QVector3D(*(float(v) for v in position))).toPointF()
            font = self._label_painter_fonts.get(size)
            if font is None:
                font = QtGui.QFont("Sans Serif", size, QtGui.QFont.Weight.Bold)
                self._label_painter_fonts[size] = font
            painter.setFont(font)
            painter.setPen(QtGui.QColor(*color))
            metrics = metrics_cache.get(size) or QtGui.QFontMetrics(font)
            metrics_cache[size] = metrics
            bounds = metrics.tightBoundingRect(text)
            painter.drawText(QtCore.QPointF(point.x() - bounds.width() / 2,
                                            point.y() + bounds.height() / 2), text)

    def release(self) -> None:
        """Free this view's GL objects (framebuffer, vertex buffer) in the shared context."""
        if self._framebuffer is None and (self.scene is None or not self.scene.has_buffer()):
            return
        try:
            target = RenderContext.get()
        except RuntimeError:
            return
        if not target.make_current():
            return
        try:
            self._framebuffer = None          # deleted while its context is current
            if self.scene is not None:
                self.scene.release_buffer(GL)
        finally:
            target.done_current()
        self._image = None
        self._needs_render = True

    def grabFramebuffer(self) -> QtGui.QImage:  # noqa: N802 (Qt name)
        """The view as it is painted (scene and labels), like QOpenGLWidget's."""
        return self.grab().toImage()
