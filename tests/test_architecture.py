"""The rooms of the house and the arrows between them.

* The import contracts in pyproject.toml (import-linter): layers cli > ui > engine > stream > ekf,
  Qt only in the window, no sockets in the numerics.
* No import cycle anywhere in app/ or ekf/, function-level imports included (an import hidden in
  a function is still an arrow).
* Headless modules and commands run with Qt made unimportable, in a fresh interpreter.
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("app", "ekf")
QT = {"PySide6", "PyQt5", "PyQt6", "shiboken6", "pyqtgraph", "OpenGL"}


# ---- import-linter ---------------------------------------------------------------------------

def test_import_contracts_hold():
    lint = Path(sys.executable).with_name("lint-imports")
    command = [str(lint)] if lint.exists() else [shutil.which("lint-imports") or "lint-imports"]
    result = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


# ---- no cycles -------------------------------------------------------------------------------

def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(path): path for package in PACKAGES
            for path in (REPO / package).rglob("*.py")}


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Every project module `name` imports, at any depth of its code."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[:len(anchor) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            # `from pkg import sub` imports the module pkg.sub when there is one
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base
                       for alias in node.names]
        else:
            continue
        for target in targets:
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph[node]):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for node in sorted(graph):
        if node not in index:
            visit(node)
    return out


def test_no_import_cycles_function_level_imports_included():
    modules = _modules()
    graph = {name: _imports(name, path, modules) for name, path in modules.items()}
    assert graph["app.cli"] >= {"app.ui.main"}, "the walk must see function-level imports"
    assert _cycles(graph) == []


def test_the_cycle_finder_finds_a_hidden_cycle(tmp_path):
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]


# ---- headless with Qt blocked ------------------------------------------------------------------

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


def test_numerics_stream_engine_and_commands_import_without_qt():
    r = run_blocked(QT, """
        import pkgutil, importlib, ekf, app.stream, app.engine
        for package in (ekf, app.stream, app.engine):
            for m in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
                importlib.import_module(m.name)
        import app.cli, app.paths
        parser = app.cli.build_parser()
        for cmd in ("filter", "evaluate", "calibrate", "calibrate-mag", "tune", "simulate",
                    "send", "serve"):
            parser.parse_args([cmd, "x"] if cmd not in ("simulate", "serve") else
                              ([cmd, "-o", "x"] if cmd == "simulate" else [cmd]))
        print("ok")
    """)
    assert r.returncode == 0, r.stderr
    assert "ok" in r.stdout


def test_ekf_imports_nothing_of_app():
    r = run_blocked(QT | {"app"}, """
        import pkgutil, importlib, ekf
        for m in pkgutil.walk_packages(ekf.__path__, "ekf."):
            importlib.import_module(m.name)
        print("ok")
    """)
    assert r.returncode == 0, r.stderr


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
        for forbidden in ("make_estimator", "OrientationEKF", "FastEKF", "filter_batch",
                          "import socket", "app.cli"):
            assert forbidden not in text, f"{path.name} uses {forbidden}"



# ---- one owner: no private attribute read from outside ---------------------------------------

def _private_reads_from_outside(source: str) -> list[str]:
    """`obj._x` where `_x` is none of this module's own names (an attribute it sets on `self`
    or `cls`, a function, class or class attribute it defines): a private attribute of another
    module's object, by line."""
    tree = ast.parse(source)
    own: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            own.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) \
                and isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
            own.add(node.attr)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            own.add(node.id)
    return sorted({f"{node.lineno}: {ast.unparse(node)}" for node in ast.walk(tree)
                   if isinstance(node, ast.Attribute) and node.attr.startswith("_")
                   and not node.attr.startswith("__") and node.attr not in own
                   and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))})


# Names with an underscore that are a library's public interface: os._exit, a namedtuple's
# _replace, and numba's dispatcher cache (the kernels' cache guard and the parser's "is it
# cached" look at it).
_LIBRARY_NAMES = (": os._exit", "._replace", "._cache", "._cache_file", "._index_path")


@pytest.mark.parametrize("package", ["app/ui", "app/engine", "app/stream", "app/cli", "ekf"])
def test_no_module_reads_another_modules_private_attributes(package):
    offences = [f"{path.relative_to(REPO)}:{found}"
                for path in sorted((REPO / package).rglob("*.py"))
                for found in _private_reads_from_outside(path.read_text())
                if not found.endswith(_LIBRARY_NAMES)]
    assert offences == []


def test_the_private_read_check_finds_what_it_looks_for():
    assert _private_reads_from_outside("window._action(menu)") == ["1: window._action"]
    assert _private_reads_from_outside("self.scene._buffer = None") == ["1: self.scene._buffer"]
    assert _private_reads_from_outside("self._buffer = 1\nx = other._buffer") == []
    assert _private_reads_from_outside("class A:\n    _n = 1\nA()._n") == []
    assert _private_reads_from_outside("self._x = 1; self.__class__") == []
