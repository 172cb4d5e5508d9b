"""The checker's stub of MuJoCo (typings/mujoco) names the same enum values the bindings have.

A stub that drifted from the installed mujoco would let the checker pass code that looks up the wrong object kind.
"""

import ast

import mujoco
import pytest

from tests.helpers import ROOT

STUB = ROOT / "typings" / "mujoco" / "__init__.pyi"


def _stub_enums() -> dict[str, dict[str, int]]:
    tree = ast.parse(STUB.read_text())
    enums: dict[str, dict[str, int]] = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef) and any(getattr(b, "id", "") == "IntEnum" for b in node.bases):
            enums[node.name] = {
                stmt.targets[0].id: ast.literal_eval(stmt.value)
                for stmt in node.body
                if isinstance(stmt, ast.Assign) and isinstance(stmt.targets[0], ast.Name)
            }
    return enums


@pytest.mark.parametrize(("enum", "members"), sorted(_stub_enums().items()))
def test_stub_enum_values_match_the_bindings(enum: str, members: dict[str, int]) -> None:
    real = getattr(mujoco, enum)
    assert {name: int(getattr(real, name)) for name in members} == members


def test_stub_functions_exist_in_the_bindings() -> None:
    tree = ast.parse(STUB.read_text())
    names = [n.name for n in tree.body if isinstance(n, ast.FunctionDef | ast.ClassDef) and n.name != "__getattr__"]
    assert len(names) >= 8
    assert [n for n in names if not hasattr(mujoco, n)] == []
