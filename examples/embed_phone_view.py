"""Embed the 3D phone widget in a window of your own and turn it.

    python examples/embed_phone_view.py [--exit-after S]

`PhoneView` draws one orientation (w x y z, sensor -> East-North-Up) with its uncertainty; here
it follows a simulated session's true orientation at 30 frames per second. Without OpenGL the
view is a text label with the same interface, so this runs anywhere Qt does.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from PySide6 import QtCore, QtWidgets

from ekf.simulate import simulate
from app.ui.main import make_application
from app.ui.phone_view import PhoneView


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--exit-after", type=float, default=None, metavar="S",
                        help="close after S seconds")
    args = parser.parse_args(argv)
    app = make_application()
    session = simulate(duration_s=60.0, seed=0)
    window = QtWidgets.QMainWindow()
    window.setWindowTitle("A PhoneView of your own")
    view = PhoneView("SIMULATED")
    window.setCentralWidget(view)
    window.resize(640, 480)
    clock = QtCore.QElapsedTimer()
    clock.start()
    frames = {"count": 0}

    def turn() -> None:
        t_ms = 1000.0 + (clock.elapsed() % 59_000)
        view.set_orientation(session.quat_at(np.array([t_ms]))[0], np.eye(4) * 1e-3)
        frames["count"] += 1

    timer = QtCore.QTimer()
    timer.timeout.connect(turn)
    timer.start(33)
    window.show()
    if args.exit_after is not None:
        QtCore.QTimer.singleShot(int(args.exit_after * 1000), window.close)
    app.exec()
    timer.stop()
    print(f"{frames['count']} orientations drawn ({'3D' if view.gl_view else 'text'} view)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
