"""Starting real OS processes for tests: wait for a ready line (never a sleep), always clean up.

The child itself is server.child's, which the benches use too."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from server.child import Child

ROOT = Path(__file__).resolve().parent.parent


class Process(Child):
    """A child started in the repository (``python -m server.…`` finds the packages from there)."""

    def __init__(self, *args: str, cwd: Path = ROOT, prefix: tuple[str, ...] = ()) -> None:
        super().__init__(*args, cwd=cwd, prefix=prefix)


def run(*args: str, timeout: float = 60.0, prefix: tuple[str, ...] = ()) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*prefix, sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)
