"""Every estimator and every sensor combination on a simulated phone with known truth (task 12).

    python examples/compare_estimators.py [--seconds 120] [--seed 0]

Uses only the numerics (`ekf`): a simulated session with scripted accelerations and magnetic
disturbances, `ekf.filter_batch` over its arrays, and the error against the true orientation
split into heading and inclination, which is what each sensor contributes.
"""

from __future__ import annotations

import argparse
import itertools
import sys

import numpy as np

import ekf
from ekf.simulate import simulate


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    session = simulate(duration_s=args.seconds, seed=args.seed)
    t_s, gyr, acc, mag = session.to_batch_arrays()
    truth = session.quat_at(t_s * 1000.0)
    after = t_s >= t_s[0] + 3.0    # leave the start-up out
    print(f"{args.seconds:g} s simulated (seed {args.seed}); RMSE after the first 3 s, degrees")
    print(f"{'estimator':<14}{'sensors':<14}{'total':>8}{'heading':>9}{'inclination':>13}")
    combinations = [c for size in (3, 2, 1) for c in itertools.combinations(ekf.SENSORS, size)]
    for name in ekf.ESTIMATORS:
        for sensors in (combinations if name == "ekf" else [ekf.SENSORS]):
            result = ekf.filter_batch(t_s, gyr, acc, mag, estimator=name, sensors=sensors)
            error = ekf.summarize(result.quat, truth, after)
            print(f"{name:<14}{'+'.join(sensors):<14}{error.total_rmse_deg:>8.2f}"
                  f"{error.heading_rmse_deg:>9.2f}{error.inclination_rmse_deg:>13.2f}")
    return 0 if np.isfinite(error.total_rmse_deg) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
