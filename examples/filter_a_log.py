"""Filter a phone log through the API and print the error against the phone's own estimate.

    python examples/filter_a_log.py [LOG]      # without LOG: a simulated 60 s session

The log is read with the same parser and time ordering as the live stream, and the estimators run
through the same runner as the window, so these are the numbers
`orientation-lab evaluate LOG --estimator ekf,course,complementary,gyro,accmag` prints (the
whole log scored; `evaluate --skip S` and ``evaluate_log(..., skip_s=S)`` leave out the first S
seconds).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import ekf
from ekf.simulate import simulate
from app.engine.offline.filtering import evaluate_log, filter_log
from app.stream.demo import write_session
from app.stream.logfile import read_log


def main(argv: list[str]) -> int:
    with tempfile.TemporaryDirectory() as folder:
        if argv:
            path = Path(argv[0])
        else:   # a simulated phone whose ORI is the true orientation
            path = write_session(simulate(duration_s=60.0, seed=3), Path(folder) / "sim.txt")
        log = read_log(path)
        print(log.stats.summary())
        rows = filter_log(log, "ekf")
        print(f"{len(rows)} estimates; the last: t = {rows.t_ms[-1]} ms, "
              f"q = {rows.quat[-1].round(4).tolist()} (w x y z, sensor -> ENU)")
        print(f"{'estimator':<15}{'total °':>9}{'heading °':>11}{'inclination °':>15}")
        for name in ekf.ESTIMATORS:
            error = evaluate_log(log, name)
            print(f"{name:<15}{error.total_rmse_deg:>9.2f}{error.heading_rmse_deg:>11.2f}"
                  f"{error.inclination_rmse_deg:>15.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
