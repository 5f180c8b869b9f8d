"""Frame rate and CPU of the main window while it replays a 500 Hz session.

Targets: at 1x the window keeps >= 30 frames per second and the whole process
(engine thread + GUI) stays under one core; at 10x the frame rate changes by < 20 %, because
the GUI thread never does filter work.

A "frame" is one display tick whose changes were painted (MainWindow.frames_painted, counted
from paint events, not timer ticks); the plots' view (its paint events) and each 3D view (its
frames_painted counter) are counted on their own as well, and the figure is the lowest of them.
CPU is the process time of all threads (engine, GUI, Mesa llvmpipe's rasteriser threads). The 500 Hz session comes
from the simulator (ekf.simulate) written in the phone's format (app.stream.protocol).

Run under a display; without one it re-runs itself under xvfb-run:
    cd /work/main && .venv/bin/python benchmarks/gui_fps.py [--seconds 10]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

RATES_HZ = {"gyr": 500.0, "acc": 500.0, "mag": 250.0, "ori": 500.0}


def write_session(path: Path, duration_s: float) -> Path:
    """A simulated 500 Hz session as a phone log (the standard script, seed 0)."""
    from ekf.simulate import simulate

    from app.stream.protocol import Sample, format_line
    session = simulate(duration_s=duration_s, rates_hz=RATES_HZ, seed=0)
    with open(path, "w", newline="\n") as file:
        for t_ms, tag, values in session.to_rows():
            file.write(format_line(Sample(int(t_ms), tag, tuple(float(v) for v in values))) + "\n")
    return path


class FrameCounter:
    """Counts paint events of the plots' view; the 3D views count their own frames."""

    def __init__(self, window) -> None:
        from PySide6 import QtCore

        self.plot_paints = 0
        self.views = [view.gl_view for view in (window.own_view, window.phone_view)
                      if view.gl_view is not None]
        counter = self

        class _Filter(QtCore.QObject):
            def eventFilter(self, watched, event):  # noqa: N802 (Qt name)
                if event.type() == QtCore.QEvent.Type.Paint:
                    counter.plot_paints += 1
                return False

        self._filter = _Filter()
        for group in window.plots.groups.values():      # only the shown tab paints
            group.graphics.viewport().installEventFilter(self._filter)

    @property
    def gl_paints(self) -> int:
        return sum(view.frames_painted for view in self.views)


def measure(app, window, counter: FrameCounter, seconds: float) -> dict[str, float]:
    """Run the event loop for `seconds`; frames/s and CPU cores of the whole process."""
    from PySide6 import QtCore

    ticks_before, frames_before = window.ticks, window.frames_painted
    poses_before = window.own_view.pose_changes + window.phone_view.pose_changes
    plot_before, gl_before = counter.plot_paints, counter.gl_paints
    samples_before = window.engine.samples_processed
    wall_start, cpu_start = time.perf_counter(), time.process_time()
    loop = QtCore.QEventLoop()
    QtCore.QTimer.singleShot(int(seconds * 1000), loop.quit)
    loop.exec()
    wall = time.perf_counter() - wall_start
    cpu = time.process_time() - cpu_start      # all threads of this process (llvmpipe's too)
    views = sum(view.gl_view is not None for view in (window.own_view, window.phone_view))
    return {"ticks_per_s": (window.ticks - ticks_before) / wall,
            "window_fps": (window.frames_painted - frames_before) / wall,
            "plot_fps": (counter.plot_paints - plot_before) / wall,
            "gl_fps": (counter.gl_paints - gl_before) / wall / max(views, 1),
            "poses_per_s": (window.own_view.pose_changes + window.phone_view.pose_changes
                            - poses_before) / wall / 2,
            "cpu_cores": cpu / wall,
            "samples_per_s": (window.engine.samples_processed - samples_before) / wall}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="measuring time per speed")
    parser.add_argument("--warmup", type=float, default=3.0,
                        help="seconds between the first filtered sample and measuring")
    parser.add_argument("--duration", type=float, default=300.0,
                        help="length of the simulated session, s (looped at 10x)")
    parser.add_argument("--no-gl", action="store_true",
                        help="3D views as placeholders (to see what the GL views cost)")
    parser.add_argument("--switch-interval", type=float, default=None, metavar="S",
                        help="override the GIL switch interval the application sets")
    parser.add_argument("--profile", metavar="FILE", help="cProfile the GUI thread at 1x")
    parser.add_argument("--tab", choices=("sensors", "orientation", "error"), default="sensors",
                        help="the tab of plots shown while measuring (orientation: PHONE's "
                             "dashed curves, the dearest to draw)")
    parser.add_argument("--quick", action="store_true",
                        help="a smoke run: 1 s per speed on a 20 s session")
    parser.add_argument("--render-every-frame", action="store_true",
                        help="render the 3D views for every snapshot, even when the pose did "
                             "not visibly change (the worst case: a phone that never rests)")
    args = parser.parse_args(argv)
    if args.quick:
        args.seconds, args.warmup, args.duration = 1.0, 0.5, 20.0

    if not os.environ.get("DISPLAY"):
        xvfb = shutil.which("xvfb-run")
        if xvfb is None:
            print("no display and no xvfb-run: cannot measure the GL window", file=sys.stderr)
            return 2
        return subprocess.call([xvfb, "-a", "-s", "-screen 0 1600x1000x24", sys.executable,
                                __file__, *(argv if argv is not None else sys.argv[1:])])

    from PySide6 import QtCore

    from app.ui.main import make_application
    app = make_application()            # as the application does
    if args.switch_interval:
        sys.setswitchinterval(args.switch_interval)

    from app.engine.live.worker import Engine
    from app.stream.sources import LogFileSource
    from app.engine.commands import ReplayControl
    from app.ui import phone_view
    from app.ui.main_window import MainWindow
    if args.render_every_frame:
        phone_view.REDRAW_QUAT_CHANGE = -1.0

    with tempfile.TemporaryDirectory(prefix="gui-fps-") as folder:
        log = write_session(Path(folder) / "session_500hz.txt", args.duration)
        engine = Engine(LogFileSource(log, speed=1.0, loop=True))
        engine.start()
        settings = QtCore.QSettings(str(Path(folder) / "settings.ini"),
                                    QtCore.QSettings.Format.IniFormat)
        window = MainWindow(engine, settings=settings, use_gl=False if args.no_gl else None)
        window.resize(1600, 1000)
        window.plots.set_current_group(args.tab)
        window.show()
        counter = FrameCounter(window)
        try:
            # Wait for the filter to run (the first call compiles numba code), then settle.
            deadline = time.monotonic() + 180.0
            while engine.samples_processed == 0 and time.monotonic() < deadline:
                measure(app, window, counter, 0.5)
            if engine.samples_processed == 0:
                print(f"the engine processed no samples in 180 s (error: {engine.error})",
                      file=sys.stderr)
                return 1
            measure(app, window, counter, args.warmup)
            if args.profile:
                import cProfile
                profiler = cProfile.Profile()
                profiler.enable()
            slow = measure(app, window, counter, args.seconds)
            if args.profile:
                profiler.disable()
                profiler.dump_stats(args.profile)
            engine.send(ReplayControl(speed=10.0))
            measure(app, window, counter, 1.0)
            fast = measure(app, window, counter, args.seconds)
        finally:
            window.close()
            engine.stop()

    from app.ui.phone_view import software_gl
    print(f"platform {app.platformName()}, 3D views: "
          f"{'OpenGL' if window.own_view.gl_view is not None else 'none (placeholder)'}"
          f"{' (software)' if software_gl() else ''}, frame timer {window.frame_interval_ms} ms, "
          f"LP_NUM_THREADS={os.environ.get('LP_NUM_THREADS', 'unset')}")
    for name, result in (("1x", slow), ("10x", fast)):
        print(f"{name:>4}: {result['window_fps']:5.1f} frames/s painted (plots "
              f"{result['plot_fps']:5.1f}/s; 3D {result['gl_fps']:5.1f}/s per view for "
              f"{result['poses_per_s']:5.1f} visible pose changes/s; {result['ticks_per_s']:5.1f} "
              f"timer ticks/s), CPU {result['cpu_cores']:.2f} cores, "
              f"{result['samples_per_s']:.0f} samples/s filtered")
    # The window's frames: display ticks whose changes were painted. The plots scroll on every
    # tick, so each frame repaints them; a 3D view repaints only when its pose visibly changed
    # (a phone at rest needs no new picture), so its count is shown, not used.
    frame_rate_1x = min(slow["window_fps"], slow["plot_fps"])
    frame_rate_10x = min(fast["window_fps"], fast["plot_fps"])
    change = abs(frame_rate_10x - frame_rate_1x) / max(frame_rate_1x, 1e-9)
    print(f"frame rate at 1x: {frame_rate_1x:.1f} fps (need >= 30): "
          f"{'ok' if frame_rate_1x >= 30 else 'TOO LOW'}")
    print(f"process CPU at 1x: {slow['cpu_cores']:.2f} cores (need < 1): "
          f"{'ok' if slow['cpu_cores'] < 1 else 'TOO HIGH'}")
    print(f"frame rate 10x vs 1x: {frame_rate_10x:.1f} vs {frame_rate_1x:.1f} fps, change "
          f"{100 * change:.0f} % (need < 20 %): {'ok' if change < 0.2 else 'TOO LARGE'}")
    print(f"(10x: CPU {fast['cpu_cores']:.2f} cores; load average now "
          f"{', '.join(f'{v:.2f}' for v in os.getloadavg())} on {os.cpu_count()} cores)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
