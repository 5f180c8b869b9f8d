"""The rooms of the house: numerics never import Qt or sockets; I/O and headless commands never
import Qt. Checked in a fresh interpreter where importing Qt fails loudly."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

BLOCKER = textwrap.dedent("""
    import sys, importlib.abc
    BLOCKED = {blocked!r}
    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"forbidden import: {{name}}")
            return None
    sys.meta_path.insert(0, Block())
""")


def run_blocked(blocked: set[str], body: str) -> subprocess.CompletedProcess:
    code = BLOCKER.format(blocked=sorted(blocked)) + textwrap.dedent(body)
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True,
                          timeout=120)


QT = {"PySide6", "PyQt5", "PyQt6", "shiboken6", "pyqtgraph", "OpenGL"}


def test_ekf_imports_no_qt_or_app():
    r = run_blocked(QT | {"app"}, """
        import pkgutil, importlib, ekf
        for m in pkgutil.walk_packages(ekf.__path__, "ekf."):
            importlib.import_module(m.name)
        print("ok")
    """)
    assert r.returncode == 0, r.stderr
    assert "ok" in r.stdout


def test_ekf_source_never_imports_sockets_files_or_the_app():
    # (numba itself pulls in socket through the standard library, so check ekf's own imports.)
    import ast
    for path in (REPO / "ekf").glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            for name in names:
                assert name.split(".")[0] not in {"socket", "selectors", "app", "PySide6", "pyqtgraph"}, \
                    f"{path.name} imports {name}"


def test_io_engine_and_headless_commands_import_no_qt():
    r = run_blocked(QT, """
        import pkgutil, importlib, app.stream
        for m in pkgutil.walk_packages(app.stream.__path__, "app.stream."):
            importlib.import_module(m.name)
        import app.engine, app.engine.runner, app.engine.snapshot, app.cli
        parser = app.cli.build_parser()
        for cmd in ("filter", "evaluate", "calibrate", "simulate", "send", "serve"):
            parser.parse_args([cmd, "x"] if cmd not in ("simulate", "serve") else
                              ([cmd, "-o", "x"] if cmd == "simulate" else [cmd]))
        print("ok")
    """)
    assert r.returncode == 0, r.stderr
    assert "ok" in r.stdout


def test_headless_command_runs_with_qt_blocked(tmp_path):
    out = tmp_path / "sim.txt"
    r = run_blocked(QT, f"""
        import app.cli
        assert app.cli.main(["simulate", "-o", {str(out)!r}, "--duration", "5"]) == 0
        assert app.cli.main(["filter", {str(out)!r}, "-o", {str(tmp_path / 'est.csv')!r}]) == 0
        print("ok")
    """)
    assert r.returncode == 0, r.stderr
    lines = (tmp_path / "est.csv").read_text().splitlines()
    assert lines[0] == "t_ms,qw,qx,qy,qz,acc_rejected,mag_rejected,at_rest"
    assert len(lines) > 400


def test_widgets_do_not_reach_into_the_filter():
    # app/ui draws snapshots and sends commands: it must not construct or call estimators.
    for path in (REPO / "app" / "ui").glob("*.py"):
        text = path.read_text()
        for forbidden in ("make_estimator", "OrientationEKF", "FastEKF", "filter_batch", "import socket"):
            assert forbidden not in text, f"{path.name} uses {forbidden}"
