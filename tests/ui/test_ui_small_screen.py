"""The window on a 1280x720 screen with everything running (issue 51): a live stream from the
phone emulator (or the demo replaying: its time slider was squeezed to 25 px), a recording, a filter of yours that failed, every workspace and every dock
shown in turn. The window stays within the screen (it used to grow from 1177 to 1262 px while
streaming and recording, and stay so) and nothing is cut (tests/ui/clipping.py).

The screen's size belongs to the process, so the window runs in a child process
(tests/ui/small_screen_window.py): offscreen with a 1280x720 screen, and under Xvfb at
1280x720 (marked gl: `make test` runs it, with its own X server).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = Path(__file__).with_name("small_screen_window.py")
WIDTH, HEIGHT = 1280, 720
BROKEN_FILTER = '''
class Filter:
    def step(self, t, gyr, acc, mag):
        raise ValueError("a long message from the student's own code, " * 8)
'''


@pytest.fixture(scope="module")
def phone_log(tmp_path_factory) -> Path:
    from app.stream.demo import write_session
    from ekf.simulate import simulate
    path = tmp_path_factory.mktemp("small_screen") / "walk.txt"
    write_session(simulate(duration_s=20.0, seed=3), path)
    return path


def _window_report(tmp_path: Path, phone_log: Path, env: dict[str, str],
                   prefix: list[str], source: str = "live") -> dict:
    broken = tmp_path / "broken.py"
    broken.write_text(BROKEN_FILTER)
    out = tmp_path / "out"
    out.mkdir()
    env = {**env, "PYTHONPATH": str(ROOT), "ORIENTATION_LAB_DATA": str(tmp_path / "data")}
    done = subprocess.run([*prefix, sys.executable, str(SCRIPT), str(phone_log), str(broken),
                           str(out), source], env=env, cwd=ROOT, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def _check(report: dict) -> None:
    assert report["screen"] == [WIDTH, HEIGHT]
    assert max(report["widths"]) <= WIDTH, report["widths"]
    assert max(report["right_edges"]) < WIDTH, report["right_edges"]     # not off the screen
    assert report["minimum_width"] <= WIDTH
    assert report["findings"] == []


@pytest.mark.parametrize("source", ["live", "demo"])
def test_the_window_fits_a_1280x720_screen_while_streaming_and_recording(tmp_path, phone_log,
                                                                        source):
    screen = tmp_path / "screen.json"
    screen.write_text(json.dumps({"synchronousWindowSystem": False, "windowFrameMargins": False,
                                  "screens": [{"name": "screen0", "x": 0, "y": 0,
                                               "width": WIDTH, "height": HEIGHT,
                                               "logicalDpi": 96, "logicalBaseDpi": 96,
                                               "dpr": 1}]}))
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["QT_QPA_PLATFORM"] = f"offscreen:configfile={screen}"
    _check(_window_report(tmp_path, phone_log, env, [], source))


@pytest.mark.gl
def test_the_window_fits_a_1280x720_x_server_while_streaming_and_recording(tmp_path,
                                                                          phone_log):
    if shutil.which("xvfb-run") is None:
        pytest.skip("xvfb-run not found (apt-get install xvfb)")
    env = {k: v for k, v in os.environ.items()
           if k not in ("QT_QPA_PLATFORM", "DISPLAY", "WAYLAND_DISPLAY")}
    _check(_window_report(tmp_path, phone_log, env,
                          ["xvfb-run", "-a", "-s", f"-screen 0 {WIDTH}x{HEIGHT}x24"]))
