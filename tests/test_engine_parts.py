"""The engine's parts: each owns its state and is handed what it needs; nothing outside the
engine's own module (app/engine/live/worker.py) reads the engine's private attributes."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

APP = Path(__file__).resolve().parents[1] / "app"
OWN_MODULE = APP / "engine" / "live" / "worker.py"


def _engine_private_reads(tree: ast.AST) -> list[tuple[int, str]]:
    """`engine._x` and `something.engine._x` (the engine's private attributes), by line."""
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute) or not node.attr.startswith("_") \
                or node.attr.startswith("__"):
            continue
        owner = node.value
        if (isinstance(owner, ast.Name) and owner.id == "engine") or \
                (isinstance(owner, ast.Attribute) and owner.attr == "engine"):
            found.append((node.lineno, ast.unparse(node)))
    return found


def test_no_module_outside_the_engine_reads_its_private_attributes():
    offences = []
    for path in sorted(APP.rglob("*.py")):
        if path == OWN_MODULE:
            continue
        tree = ast.parse(path.read_text(), str(path))
        offences += [f"{path.relative_to(APP.parent)}:{line}: {text}"
                     for line, text in _engine_private_reads(tree)]
    assert offences == []


@pytest.mark.parametrize("source, expected", [
    ("engine._runner.reset()", ["engine._runner"]),
    ("self.engine._health.warn('x')", ["self.engine._health"]),
    ("engine.runner.reset(); engine.__class__", []),
    ("other._private", []),
])
def test_the_check_finds_what_it_looks_for(source, expected):
    assert [text for _, text in _engine_private_reads(ast.parse(source))] == expected


def test_every_handler_takes_the_typed_parts():
    """The command table's handlers work on EngineParts, never on an untyped engine."""
    tree = ast.parse((APP / "engine" / "live" / "worker.py").read_text())
    handlers = [node for node in tree.body if isinstance(node, ast.FunctionDef)
                and node.args.args and node.args.args[0].arg in ("parts", "engine")]
    assert len(handlers) >= 6
    for function in handlers:
        first = function.args.args[0]
        assert (first.arg, ast.unparse(first.annotation)) == ("parts", "EngineParts"), \
            function.name
