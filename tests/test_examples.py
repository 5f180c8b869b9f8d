"""Smoke tests: every script in examples/ and every benchmark's --quick mode runs to the end,
each in a fresh interpreter (as pyqtgraph's examples/test_examples.py runs its examples).

A benchmark's --quick figures are not its figures: this only shows that the script still works
with today's API. Benchmarks whose peers (`make bench` installs them) or shared data are missing
report that and still exit 0.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((REPO / "examples").glob("*.py"))
QUICK_ARGS = {"headless_engine.py": ["--seconds", "1.5"],
              "stream_to_server.py": ["--seconds", "3"],
              "compare_estimators.py": ["--seconds", "20"],
              "embed_phone_view.py": ["--exit-after", "0.5"],
              "course_ekf.py": ["--seconds", "10"]}
BENCHMARKS = [("speed.py", []),
              ("accuracy.py", ["--only", "ours-default,ours-course,ours-smoothed"]),
              ("tune_defaults.py", []),
              ("tune_defaults.py", ["--held-out-only", "--objective", "means"]),
              ("tune_defaults.py", ["--held-out-only", "--augment", "1"]), ("robustness.py", []),
              ("live.py", ["--skip-no-loss"]), ("chaos.py", []), ("tuning.py", []),
              ("plugin.py", []), ("session.py", []), ("startup.py", [])]


def _run(script: Path, args: list[str], env: dict[str, str] | None = None,
         timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(script), *args], cwd=REPO, capture_output=True,
                          text=True, timeout=timeout, env=env)


def test_there_are_examples():
    assert len(EXAMPLES) >= 4


@pytest.mark.parametrize("script", EXAMPLES, ids=lambda p: p.name)
def test_example_runs(script, tmp_path):
    env = dict(os.environ, ORIENTATION_LAB_DATA=str(tmp_path))
    result = _run(script, QUICK_ARGS.get(script.name, []), env)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.strip(), "an example says what it did"
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("name, args", BENCHMARKS, ids=[" ".join([b[0], *b[1]])
                                                        for b in BENCHMARKS])
def test_benchmark_quick_mode_runs(name, args):
    result = _run(REPO / "benchmarks" / name, ["--quick", *args])
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    if name == "tune_defaults.py" and "held-out" in result.stdout:   # the shared data is here
        assert ("fit on all" in result.stdout) != ("--held-out-only" in args), result.stdout


@pytest.mark.gl
def test_gui_benchmark_quick_mode_runs():
    result = _run(REPO / "benchmarks" / "gui_fps.py", ["--quick"])
    assert result.returncode == 0, result.stdout + result.stderr
    assert "fps" in result.stdout


def test_filter_a_log_prints_the_figures_evaluate_prints(tmp_path):
    log = tmp_path / "sim.txt"
    assert _run(REPO / "app" / "__main__.py", ["simulate", "-o", str(log), "--duration",
                                                "20"]).returncode == 0
    example = _run(REPO / "examples" / "filter_a_log.py", [str(log)]).stdout
    command = _run(REPO / "app" / "__main__.py", ["evaluate", str(log), "--estimator",
                                                   "ekf,course"]).stdout

    def totals(text: str, column: int) -> list[str]:
        return [line.split()[column] for line in text.splitlines()
                if line.split()[:1] in (["ekf"], ["course"])]

    assert totals(example, 1) == totals(command, 2)
