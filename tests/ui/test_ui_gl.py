"""3D views under a real OpenGL context (xvfb-run): skipped on the offscreen platform.

Run: cd /work/main && xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python -m pytest -q -m gl tests/ui
"""

from __future__ import annotations

import os
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from PySide6 import QtGui, QtWidgets

from ui_helpers import FakeEngine, make_snapshot, quat_about_z

pytestmark = pytest.mark.gl
REPO = Path(__file__).resolve().parents[2]
BACKGROUND = np.array([34, 38, 46])


@pytest.fixture(autouse=True)
def _need_gl():
    if os.environ.get("QT_QPA_PLATFORM", "").startswith("offscreen"):
        pytest.skip("needs OpenGL: offscreen platform has none (run under xvfb-run)")


def _pixels(image: QtGui.QImage) -> np.ndarray:
    image = image.convertToFormat(QtGui.QImage.Format.Format_RGB888)
    width, height = image.width(), image.height()
    data = np.frombuffer(image.constBits(), np.uint8, count=image.bytesPerLine() * height)
    return data.reshape(height, image.bytesPerLine())[:, :3 * width].reshape(height, width, 3).copy()


def _screen_pixels(pixels: np.ndarray) -> np.ndarray:
    """Mask of the phone's blue screen (nothing else in the scene is that saturated a blue;
    the z axis is lighter and thin)."""
    red, green, blue = (pixels[..., i].astype(int) for i in range(3))
    return (blue > 100) & (blue > red + 60) & (blue > green + 40) & (red < 90) & (green < 125)


@contextmanager
def _painted(qtbot, gl_view):
    """After the block, wait until Qt has painted gl_view (with what the block changed)."""
    before = gl_view.frames_painted
    yield
    qtbot.waitUntil(lambda: gl_view.frames_painted > before, timeout=5000)


def _painted_once(qtbot, *views) -> None:
    """Until Qt has painted each view's 3D scene at least once."""
    qtbot.waitUntil(lambda: all(view.gl_view.frames_painted > 0 for view in views), timeout=5000)


def _render(qtbot, window, quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    snapshot = make_snapshot(1, 0.0)
    snapshot.own_quat = quat
    snapshot.phone_quat = quat
    snapshot.own_cov = None            # no rings: only the phone's outline is compared
    window.engine.snapshots.append(snapshot)
    window.tick()
    images = []
    for view in (window.own_view, window.phone_view):
        with _painted(qtbot, view.gl_view):
            view.gl_view.update()
        images.append(_pixels(view.grab_image()))
    if os.environ.get("ORIENTATION_LAB_DUMP"):
        QtGui.QImage(images[0].data, images[0].shape[1], images[0].shape[0], 3 * images[0].shape[1],
                     QtGui.QImage.Format.Format_RGB888).save(
            f"{os.environ['ORIENTATION_LAB_DUMP']}/gl_{quat[0]:.2f}_{quat[3]:.2f}.png")
    return images[0], images[1]


def test_both_views_draw_a_phone_that_turns_with_the_quaternion(make_window, qtbot):
    window = make_window(FakeEngine(), use_gl=None)
    assert window.own_view.gl_view is not None and window.phone_view.gl_view is not None
    window.resize(1400, 900)
    window.show()
    qtbot.waitExposed(window)
    _painted_once(qtbot, window.own_view, window.phone_view)
    flat = np.array([1.0, 0.0, 0.0, 0.0])
    # Screen towards the camera (south): 90° about x tips the top of the phone up.
    upright = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0])
    first = _render(qtbot, window, flat)
    second = _render(qtbot, window, upright)
    third = _render(qtbot, window, quat_about_z(90.0))
    for before, after, turned in zip(first, second, third):
        assert before.std() > 10                                  # not a blank frame
        phone_before = _screen_pixels(before)
        phone_after = _screen_pixels(after)
        assert phone_before.sum() > 800 and phone_after.sum() > 800
        # Standing up facing the camera, the screen covers a taller region than lying flat.
        # Rows crossing the screen (not the thin z axis, which is also blue).
        rows_before = np.flatnonzero(phone_before.sum(axis=1) > 10)
        rows_after = np.flatnonzero(phone_after.sum(axis=1) > 10)
        assert (rows_after[-1] - rows_after[0]) > 1.5 * (rows_before[-1] - rows_before[0])
        changed = np.abs(before.astype(int) - turned.astype(int)).sum(axis=2) > 60
        assert changed.mean() > 0.01                             # a quarter turn about up shows


def test_uncertainty_rings_appear_and_hide(make_window, qtbot):
    window = make_window(FakeEngine(), use_gl=None)
    window.resize(1400, 900)
    window.show()
    qtbot.waitExposed(window)
    view = window.own_view
    quat = np.array([1.0, 0.0, 0.0, 0.0])
    view.set_orientation(quat, np.eye(4) * 4e-3)
    assert all(ring.visible() for ring in view._scene.rings)
    with _painted(qtbot, view.gl_view):
        view.gl_view.update()
    with_rings = _pixels(view.grab_image())
    with _painted(qtbot, view.gl_view):
        window.controls.uncertainty_checkbox.setChecked(False)
        assert not any(ring.visible() for ring in view._scene.rings)
        view.gl_view.update()
    without_rings = _pixels(view.grab_image())
    assert (np.abs(with_rings.astype(int) - without_rings.astype(int)).sum(axis=2) > 60).sum() > 50


def test_a_view_renders_again_only_when_its_picture_changes(make_window, qtbot):
    window = make_window(FakeEngine(), use_gl=None)
    window.resize(1400, 900)
    window.show()
    qtbot.waitExposed(window)
    view = window.phone_view
    _painted_once(qtbot, view)
    with _painted(qtbot, view.gl_view):
        view.set_orientation(quat_about_z(30.0))
    rendered, painted = view.gl_view.frames_rendered, view.gl_view.frames_painted
    first = _pixels(view.grab_image())
    # The same pose (and noise far below a pixel) repaints from the stored image.
    with _painted(qtbot, view.gl_view):
        view.set_orientation(quat_about_z(30.0 + 1e-4))
        QtWidgets.QWidget.update(view.gl_view)      # a repaint Qt asks for (e.g. an expose)
    assert view.gl_view.frames_rendered == rendered + 0
    assert view.gl_view.frames_painted > painted
    np.testing.assert_array_equal(_pixels(view.grab_image()), first)
    # A visible turn renders once more, and the picture changes.
    with _painted(qtbot, view.gl_view):
        view.set_orientation(quat_about_z(60.0))
    assert view.gl_view.frames_rendered == rendered + 1
    turned = _pixels(view.grab_image())
    assert (np.abs(turned.astype(int) - first.astype(int)).sum(axis=2) > 60).mean() > 0.005


def test_the_camera_orbits_and_resets(make_window, qtbot):
    window = make_window(FakeEngine(), use_gl=None)
    window.resize(1400, 900)
    window.show()
    qtbot.waitExposed(window)
    view = window.own_view
    with _painted(qtbot, view.gl_view):
        view.set_orientation(quat_about_z(0.0))
    home = _pixels(view.grab_image())
    rendered = view.gl_view.frames_rendered
    with _painted(qtbot, view.gl_view):
        view.gl_view.orbit(60.0, 20.0)             # what dragging with the mouse does
    assert view.gl_view.frames_rendered > rendered
    orbited = _pixels(view.grab_image())
    assert (np.abs(orbited.astype(int) - home.astype(int)).sum(axis=2) > 60).mean() > 0.01
    with _painted(qtbot, view.gl_view):
        view.reset_camera_button.click()
    np.testing.assert_array_equal(_pixels(view.grab_image()), home)


def test_linked_cameras_turn_together_and_no_data_greys_the_view_out(make_window, qtbot):
    window = make_window(FakeEngine(), use_gl=None)
    window.resize(1400, 900)
    window.show()
    qtbot.waitExposed(window)
    own, phone = window.own_view, window.phone_view
    window.set_cameras_linked(True)
    own.gl_view.orbit(40.0, 10.0)
    own.gl_view.camera_changed.emit()               # what a mouse drag emits
    assert phone.camera()["azimuth"] == pytest.approx(own.camera()["azimuth"])
    assert phone.camera()["elevation"] == pytest.approx(own.camera()["elevation"])
    window.set_cameras_linked(False)
    with _painted(qtbot, own.gl_view):
        own.gl_view.orbit(40.0, 0.0)
        own.gl_view.camera_changed.emit()
    assert phone.camera()["azimuth"] != pytest.approx(own.camera()["azimuth"])
    # before any data the view is greyed out and says so; a phone appears with the first pose
    assert own.gl_view.overlay_text == "waiting for data"
    waiting = _pixels(own.grab_image())
    with _painted(qtbot, own.gl_view):
        own.set_orientation(quat_about_z(0.0))
    assert own.gl_view.overlay_text == ""
    shown = _pixels(own.grab_image())
    assert shown.std() > waiting.std()


def _region_is_drawn(pixels: np.ndarray, top: float, bottom: float, left: float,
                     right: float) -> bool:
    height, width, _ = pixels.shape
    region = pixels[int(top * height):int(bottom * height), int(left * width):int(right * width)]
    distinct = len(np.unique(region.reshape(-1, 3) // 8, axis=0))
    return region.std() > 15 and distinct > 20


def test_screenshot_of_the_demo_shows_both_phones_and_the_plots(tmp_path):
    output = tmp_path / "demo.png"
    environment = dict(os.environ, HOME=str(tmp_path))          # keep the user's QSettings out
    environment.pop("QT_QPA_PLATFORM", None)
    result = subprocess.run([sys.executable, "-m", "app", "--demo", "--port", "0",
                             "--screenshot", str(output), "--exit-after", "6"],
                            cwd=REPO, env=environment, capture_output=True, text=True, timeout=180)
    assert result.returncode == 0, result.stderr
    image = QtGui.QImage(str(output))
    assert not image.isNull()
    pixels = _pixels(image)
    # The 3D views are on top (left and right halves of the central area), plots below.
    assert _region_is_drawn(pixels, 0.08, 0.40, 0.02, 0.35)
    assert _region_is_drawn(pixels, 0.08, 0.40, 0.38, 0.70)
    assert _region_is_drawn(pixels, 0.50, 0.95, 0.02, 0.70)
    own = _screen_pixels(pixels[int(0.05 * len(pixels)):int(0.45 * len(pixels)),
                               :int(0.36 * pixels.shape[1])])
    phone = _screen_pixels(pixels[int(0.05 * len(pixels)):int(0.45 * len(pixels)),
                                 int(0.36 * pixels.shape[1]):int(0.72 * pixels.shape[1])])
    assert own.sum() > 1000 and phone.sum() > 1000


def test_yours_draws_a_third_phone_turned_by_your_filter(make_window, qtbot):
    from ui_helpers import make_user_snapshot, user_status
    window = make_window(FakeEngine(), use_gl=None)
    window.resize(1280, 720)
    window.show()
    qtbot.waitExposed(window)
    turned = quat_about_z(90.0)
    snapshot = make_user_snapshot(1, 0.0, user=user_status(quat=turned, cov=None))
    snapshot.own_quat = snapshot.phone_quat = quat_about_z(0.0)
    snapshot.own_cov = None
    window.engine.snapshots.append(snapshot)
    window.tick()
    assert window.user_view.isVisible() and window.user_view.gl_view is not None
    images = []
    for view in (window.own_view, window.user_view):
        with _painted(qtbot, view.gl_view):
            view.gl_view.update()
        images.append(_screen_pixels(_pixels(view.grab_image())))
    own, yours = images
    assert own.sum() > 200 and yours.sum() > 200            # both draw the phone's screen
    assert (own != yours).mean() > 0.01                     # turned by 90°: another picture
    # linking the cameras turns YOURS' too
    window.set_cameras_linked(True)
    window.own_view.gl_view.orbit(30.0, 10.0)
    window.own_view.gl_view.camera_changed.emit()     # what a mouse drag emits
    assert window.user_view.camera()["azimuth"] == pytest.approx(
        window.own_view.camera()["azimuth"])
