"""The suite's own machinery: what `make test` relies on from pytest-xdist.

`make test` runs with ``--dist loadgroup`` so that the tests of one ``xdist_group`` run on one worker, one after
another (the browser tests, the tuner's, the firmware build's). pytest 9.2 moved a test's ID to ``Node._id`` while
pytest-xdist 3.8 still renamed ``Node._nodeid``: every group was ignored, silently, and the grouped tests spread
over the workers like any others. This test runs a small suite the way `make test` does and fails when that happens.
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

GROUPED = """
import pytest

pytestmark = pytest.mark.xdist_group("together")

{tests}
"""


def test_tests_of_one_xdist_group_run_on_one_worker(tmp_path: Path) -> None:
    (tmp_path / "pytest.ini").write_text("[pytest]\n", encoding="utf-8")  # the rootdir: none of our conftests
    tests = "\n".join(f"def test_grouped_{k}(): pass\n" for k in range(6))
    (tmp_path / "test_grouped.py").write_text(GROUPED.format(tests=tests), encoding="utf-8")
    (tmp_path / "test_alone.py").write_text("\n".join(f"def test_alone_{k}(): pass\n" for k in range(6)))
    run = subprocess.run(
        [sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadgroup", "-v", "-p", "no:cacheprovider"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    ran = re.findall(r"\[(gw\d)\].*PASSED (\S+)", run.stdout)
    grouped = {worker for worker, test in ran if "test_grouped_" in test}
    named = [test for _, test in ran if "test_grouped_" in test]
    assert len(named) == 6 and all(test.endswith("@together") for test in named), (
        "the grouped tests do not carry their group: pytest-xdist's loadgroup is not applied\n" + run.stdout
    )
    assert len(grouped) == 1, f"one group's tests ran on {sorted(grouped)}\n{run.stdout}"
    assert len(ran) == 12


def test_hypothesis_judges_no_example_by_the_wall_clock() -> None:
    """An example slower than Hypothesis's default 200 ms deadline passes: under the suite's load a 7-byte codec round
    trip once took 329 ms and failed the suite (tests/conftest.py's profile)."""
    import time

    from hypothesis import given, settings
    from hypothesis import strategies as st

    @settings(max_examples=2, database=None)
    @given(st.integers())
    def slow(_: int) -> None:
        time.sleep(0.25)

    slow()


COMPILES = """
import importlib._bootstrap_external as external

compiled = []
source_to_code = external.SourceLoader.source_to_code


def noted(self, data, path, *, _optimize=-1):
    compiled.append(path)
    return source_to_code(self, data, path, _optimize=_optimize)


external.SourceLoader.source_to_code = noted
import {modules}  # noqa: E401, F401
print(sorted(compiled))
"""


def _compiled_from_source(root: Path, modules: str, folders: list[Path]) -> list[str]:
    """What importing ``modules`` in a fresh process (from ``root``, ``PYTHONDONTWRITEBYTECODE`` set) compiles from
    source among ``folders``."""
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    run = subprocess.run([sys.executable, "-c", COMPILES.format(modules=modules)], cwd=root, env=env,
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert run.returncode == 0, run.stderr
    inside = tuple(f"{folder}{os.sep}" for folder in folders)
    return [path for path in ast.literal_eval(run.stdout.strip()) if path.startswith(inside)]


def test_a_studio_or_robot_the_suite_starts_compiles_none_of_our_modules_from_source() -> None:
    """With ``PYTHONDONTWRITEBYTECODE`` set, as in this machine's environment, every process compiled ~150 of our
    modules from source (0.2-0.3 CPU-s each, a few hundred processes a run) until tests/conftest.py wrote their
    bytecode before the tests (``pytest_configure``). On a checkout whose bytecode is current anyway this passes
    without that hook; the next test is of the hook's own work."""
    from .conftest import CHECKOUT, source_folders

    compiled = _compiled_from_source(CHECKOUT, "server.robot, server.studio, web.app", source_folders())
    assert compiled == [], f"compiled from source: {compiled}"


def test_compile_checkout_writes_what_a_process_then_reads(tmp_path: Path) -> None:
    from .conftest import compile_checkout, source_folders

    for folder in ("pkg", "docs", ".hidden"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "__init__.py").write_text("VALUE = 1\n", encoding="utf-8")
    (tmp_path / "pkg" / "mod.py").write_text("from . import VALUE\n", encoding="utf-8")
    assert [p.name for p in source_folders(tmp_path)] == ["pkg"]
    assert _compiled_from_source(tmp_path, "pkg.mod", [tmp_path / "pkg"]) != [], "compiled before: nothing written"
    assert compile_checkout(tmp_path).returncode == 0
    assert _compiled_from_source(tmp_path, "pkg.mod", [tmp_path / "pkg"]) == []
    assert not list((tmp_path / "docs").glob("__pycache__")), "a folder of no module is left alone"
