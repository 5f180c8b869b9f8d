"""ekf's modules import one another without a cycle, counting imports inside functions too, and
stay within the house sizes (no file over 900 lines, no function over 80)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

EKF = Path(__file__).resolve().parents[2] / "ekf"


def _module_name(path: Path) -> str:
    parts = path.relative_to(EKF.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, modules: set[str]) -> set[str]:
    """The ekf modules that `path` imports anywhere (module level or inside a function)."""
    here = _module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            names = [base] + [f"{base}.{a.name}" for a in node.names]
        for name in names:
            # `from ekf import quaternion` imports ekf.quaternion; `import ekf.x.y` imports ekf.x
            while name and name not in modules:
                name = name.rpartition(".")[0]
            if name and name != here:
                found.add(name)
    return found


def _graph() -> dict[str, set[str]]:
    paths = sorted(EKF.rglob("*.py"))
    modules = {_module_name(p) for p in paths}
    graph = {_module_name(p): _imports(p, modules) for p in paths}
    return graph


def test_no_import_cycle_in_ekf():
    graph = _graph()
    assert "ekf.fast.filter" in graph and "ekf.estimator" in graph
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(name: str) -> None:
        state[name] = 1
        stack.append(name)
        for dep in sorted(graph[name]):
            if state.get(dep) == 1:
                cycle = stack[stack.index(dep):] + [dep]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if dep not in state:
                visit(dep)
        stack.pop()
        state[name] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name)


def test_house_sizes():
    for path in sorted(EKF.rglob("*.py")):
        text = path.read_text()
        assert len(text.splitlines()) <= 900, f"{path.name} has more than 900 lines"
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                assert length <= 80, f"{path.name}: {node.name} has {length} lines"
