"""The package builds as a wheel and an sdist with its resources inside, and the wheel, installed
into a fresh virtual environment outside the source tree, runs: --version, simulate, filter and
evaluate, and the built-in demo session is there (marked slow: it builds, installs and compiles
the kernels afresh, about a minute)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEMO = "app/resources/demo_session.txt.gz"

pytestmark = pytest.mark.slow


def _run(args, cwd: Path, env: dict[str, str], timeout: float = 300) -> str:
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)
    assert done.returncode == 0, f"{args} exited {done.returncode}:\n{done.stderr[-2000:]}"
    return done.stdout


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("dist")
    tree = tmp_path_factory.mktemp("tree") / "orientation-lab"
    # a copy of the tree, so that no earlier build/ folder slips into the wheel and none is left
    shutil.copytree(ROOT, tree, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", ".pytest_cache"))
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    _run([sys.executable, "-m", "build", "--no-isolation", "--wheel", "--sdist",
          "--outdir", str(out), str(tree)], cwd=out, env=env, timeout=600)
    wheels, sdists = sorted(out.glob("*.whl")), sorted(out.glob("*.tar.gz"))
    assert len(wheels) == 1 and len(sdists) == 1, sorted(p.name for p in out.iterdir())
    return {"wheel": wheels[0], "sdist": sdists[0], "dir": out}


def test_the_wheel_and_the_sdist_hold_the_code_and_the_resources(built):
    names = set(zipfile.ZipFile(built["wheel"]).namelist())
    assert DEMO in names
    for module in ("app/cli/__init__.py", "app/engine/userfilter/template.py",
                   "ekf/fast/filter.py", "app/ui/main_window.py",
                   "app/engine/userfilter/octave_host/ol_host.m",
                   "app/engine/userfilter/matlab_template/tu_qw.m",
                   "app/engine/userfilter/matlab_template/README.md"):
        assert module in names, module
    assert not any(name.startswith(("tests/", "benchmarks/")) for name in names)
    with tarfile.open(built["sdist"]) as sdist:
        members = {name.split("/", 1)[1] for name in sdist.getnames() if "/" in name}
    assert DEMO in members and "pyproject.toml" in members


def test_the_wheel_installed_outside_the_source_tree_runs(built, tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = Path(_run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     cwd=tmp_path, env={"PATH": os.environ["PATH"]}).strip())
    # The dependencies (numpy, numba, Qt, pip) come from the test's environment, whose own
    # site-packages is one path line: its .pth files (the editable install of this tree) are
    # not read, so only the wheel provides `app` and `ekf`.
    (site / "zz_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    env = {"PATH": f"{venv / 'bin'}{os.pathsep}{os.environ['PATH']}", "HOME": str(tmp_path),
           "NUMBA_CACHE_DIR": str(tmp_path / "numba"), "QT_QPA_PLATFORM": "offscreen",
           "ORIENTATION_LAB_DATA": str(tmp_path / "data")}
    _run([str(python), "-m", "pip", "install", "-q", "--no-deps", "--no-index",
          str(built["wheel"])], cwd=tmp_path, env=env)
    where = _run([str(python), "-c", "import app, ekf; print(app.__file__); print(ekf.__file__)"],
                 cwd=tmp_path, env=env).split()
    assert all(Path(path).is_relative_to(venv) for path in where), where
    tool = str(venv / "bin" / "orientation-lab")
    assert "orientation-lab" in _run([tool, "--version"], cwd=tmp_path, env=env)
    _run([tool, "simulate", "-o", "walk.txt", "--duration", "8", "--seed", "3"],
         cwd=tmp_path, env=env)
    _run([tool, "filter", "walk.txt", "-o", "walk.csv"], cwd=tmp_path, env=env)
    rows = (tmp_path / "walk.csv").read_text().splitlines()
    assert len(rows) > 700 and rows[0].startswith("t")
    report = _run([tool, "evaluate", "walk.txt"], cwd=tmp_path, env=env)
    ekf_row = next(line.split() for line in report.splitlines() if line.startswith("ekf "))
    assert int(ekf_row[1]) == 800 and 0.0 <= float(ekf_row[2]) < 10.0, report
    demo = _run([str(python), "-c", "from app.stream.sources import DEMO_SESSION, demo_source; "
                 "demo_source(); print(DEMO_SESSION)"], cwd=tmp_path, env=env).strip()
    assert Path(demo).is_relative_to(venv) and Path(demo).is_file()
