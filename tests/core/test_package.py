"""The package as a whole: light imports, the exception tree, the demo and the README example."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import asm_py
from asm_py import AsmError, AsmTimeout, ServiceError, ServiceStopped, SimulationStalled

ROOT = Path(__file__).resolve().parents[2]


def test_asm_py_imports_neither_viser_nor_mujoco() -> None:
    code = "import sys, asm_py; print(sorted(m for m in ('viser', 'mujoco', 'numpy') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert out.stdout.strip() == "[]"


def test_the_robot_process_loads_unicorn_only_to_emulate_a_board() -> None:
    """asm-robot on real modules or simulated Python ones never emulates a board: Unicorn and its native library
    (~26 MB) stay unloaded until gaits.sim makes an emulated board (a review found server.robot importing it)."""
    code = "import sys, server.robot; print('unicorn' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60,
                         cwd=ROOT)  # fmt: skip
    assert out.stdout.strip() == "False"


def test_exception_tree() -> None:
    assert issubclass(AsmTimeout, TimeoutError) and issubclass(AsmTimeout, AsmError)
    assert issubclass(SimulationStalled, AsmTimeout)
    assert issubclass(ServiceError, AsmError)
    assert not issubclass(ServiceStopped, Exception), "must not be swallowed by `except Exception`"


def test_public_names_exist() -> None:
    for name in asm_py.__all__:
        assert hasattr(asm_py, name), name


def test_demo_runs_and_stops_cleanly() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "asm_module.demo", "--seconds", "1", "--modules", "3"],
        capture_output=True, text=True, timeout=60, cwd=ROOT,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert "direction set to -1" in out.stdout and "stopped cleanly" in out.stdout


def test_readme_example_runs() -> None:
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, re.S)
    assert blocks, "README.md has no python example"
    for block in blocks:
        out = subprocess.run([sys.executable, "-c", block], capture_output=True, text=True, timeout=60, cwd=ROOT)
        assert out.returncode == 0, f"README example failed:\n{block}\n{out.stderr}"
