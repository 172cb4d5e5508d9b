"""The house's shape: packages import only downwards, no module imports itself in a circle, every module stays small.

Read from the sources (ast), so a circle shows even when the import order happens to make it work. An import under
``if TYPE_CHECKING:`` or inside a function is not an edge: it runs after both modules exist.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("asm_py", "asm_module", "gaits", "server", "web")
LAYERS: dict[str, set[str]] = {
    "asm_py": set(),
    "asm_module": {"asm_py"},
    "gaits": {"asm_py", "asm_module"},
    "server": {"asm_py", "asm_module", "gaits"},
    "web": {"asm_py", "asm_module", "gaits", "server"},
    "bench": {"asm_py", "asm_module", "gaits", "server", "web"},
}
"""What each package may import (besides itself): the page sits on the servers, never the other way round."""
MAX_LINES = 500
GENERATED = {"asm_py/_contract.py", "asm_module/_profile.py"}


def _modules() -> dict[str, Path]:
    found: dict[str, Path] = {}
    for package in (*PACKAGES, "bench"):
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            found[name] = path
    return found


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _top_level_imports(module: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The project modules ``module`` imports when it is imported (not under TYPE_CHECKING, not in a function)."""
    tree = ast.parse(path.read_text(), str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    targets: set[str] = set()

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.If):
                if not _is_type_checking(node):
                    visit(node.body)
                    visit(node.orelse)
            elif isinstance(node, ast.Try):
                visit(node.body)
                for handler in node.handlers:
                    visit(handler.body)
                visit(node.orelse)
                visit(node.finalbody)
            elif isinstance(node, ast.Import):
                targets.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")
                    anchor = anchor[: len(anchor) - node.level + 1]
                    base = ".".join([*anchor, base] if base else anchor)
                targets.add(base)
                targets.update(f"{base}.{alias.name}" for alias in node.names)

    visit(tree.body)
    return {t for t in targets if t in known and t != module}


def _graph() -> dict[str, set[str]]:
    known = _modules()
    return {name: _top_level_imports(name, path, known) for name, path in known.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return found


def test_no_import_circles_between_or_inside_packages() -> None:
    graph = _graph()
    # a package's __init__ re-exports its modules: that edge is not a circle of ideas, so leave it out
    trimmed = {
        m: {t for t in ts if not (m == t.rpartition(".")[0] or t == m.rpartition(".")[0])} for m, ts in graph.items()
    }
    assert _cycles(trimmed) == []


@pytest.mark.parametrize("package", sorted(LAYERS))
def test_packages_import_only_the_layers_below(package: str) -> None:
    graph = _graph()
    wrong = {
        (module, target)
        for module, targets in graph.items()
        if module.split(".")[0] == package
        for target in targets
        if target.split(".")[0] != package and target.split(".")[0] not in LAYERS[package]
    }
    assert not wrong, sorted(wrong)


def test_every_module_is_under_500_lines() -> None:
    long = {
        str(path.relative_to(ROOT)): n
        for path in _modules().values()
        if str(path.relative_to(ROOT)) not in GENERATED and (n := len(path.read_text().splitlines())) >= MAX_LINES
    }
    assert not long, long


def test_the_checker_sees_a_circle_and_ignores_type_checking() -> None:
    assert _cycles({"a": {"b"}, "b": {"a"}, "c": set()}) == [["a", "b"]]
    tree = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import X\n"
    path = ROOT / "tests" / "artifacts" / "layout_probe.py"
    path.parent.mkdir(exist_ok=True)
    path.write_text(tree)
    try:
        assert _top_level_imports("asm_py.a", path, {"asm_py.b": path}) == set()
        path.write_text("from .b import X\n")
        assert _top_level_imports("asm_py.a", path, {"asm_py.b": path}) == {"asm_py.b"}
    finally:
        path.unlink()
