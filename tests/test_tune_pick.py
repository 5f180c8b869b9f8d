"""benchmarks/tune_defaults.py: what a search returns (--top K) is the centre of its K best
trials, geometric on a log-scale range, and the single best trial for K = 1; it, `tune` and the
window's auto-tune search the ranges the settings declare."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from tune_defaults import centre_of_best  # noqa: E402

SPACE = {"a_log": (0.1, 10.0, True, 0.1), "b_lin": (0.0, 4.0, False, 1.0)}
DONE = [(0.9, {"a_log": 1.0, "b_lin": 1.0}),
        (0.5, {"a_log": 4.0, "b_lin": 3.0}),      # best
        (0.6, {"a_log": 1.0, "b_lin": 1.0}),      # second
        (2.0, {"a_log": 9.0, "b_lin": 4.0})]


def test_one_is_the_best_trial():
    assert centre_of_best(DONE, 1, SPACE) == {"a_log": 4.0, "b_lin": 3.0}


def test_the_centre_of_the_best_is_geometric_on_a_log_scale():
    picked = centre_of_best(DONE, 2, SPACE)
    assert picked["a_log"] == pytest.approx(2.0)      # sqrt(4 * 1), not the mean 2.5
    assert picked["b_lin"] == pytest.approx(2.0)      # (3 + 1) / 2


def test_k_takes_the_k_lowest_objectives_or_all_there_are():
    assert centre_of_best(DONE, 10, SPACE)["b_lin"] == pytest.approx(9.0 / 4.0)
    assert centre_of_best(DONE, 3, SPACE)["b_lin"] == pytest.approx(5.0 / 3.0)


# ---- the search ranges come from the settings' declarations ------------------------------------
def test_every_search_reads_the_declared_search_ranges():
    import tune_defaults

    from app.engine.tuning import autotune
    from ekf.settings import search_ranges
    declared = search_ranges()
    assert autotune.RANGES == {n: (r.low, r.high) for n, r in declared.items()}
    assert tune_defaults.SPACE == {n: (declared[n].low, declared[n].high, True,
                                       declared[n].round_to) for n in tune_defaults.SEARCHED}
    base = tune_defaults.ekf.PRESETS["default"]
    assert {p.name: (p.low, p.high) for p in autotune.parse_parameters("mag_gate,acc_noise_cov",
                                                                     base)} == {
        "mag_gate": (declared["mag_gate"].low, declared["mag_gate"].high),
        "acc_noise_cov": (declared["acc_noise_cov"].low, declared["acc_noise_cov"].high)}


def test_declared_search_ranges_are_values_the_settings_allow():
    import ekf
    from ekf.settings import search_ranges
    for name, r in search_ranges().items():
        assert 0 < r.low < r.high, name                    # a log scale
        for v in (r.low, r.high):                          # checked against the declaration
            value = [[v if i == j else 0.0 for j in range(3)] for i in range(3)] if name.endswith(
                "_cov") else v
            ekf.EKFSettings().with_changes(**{name: value})
