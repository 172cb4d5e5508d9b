"""Child processes for the benchmarks (server.child: waited for by their ready line, always stopped), started in
the repository. The benches import the package and this, never the test suite."""

from __future__ import annotations

from pathlib import Path

from server.child import Child as _Child
from server.child import free_port

ROOT = Path(__file__).resolve().parent.parent

__all__ = ["ROOT", "Child", "free_port"]


class Child(_Child):
    """``python *args`` in the repository; ``label`` names it in errors."""

    def __init__(self, label: str, *args: str, prefix: tuple[str, ...] = ()) -> None:
        super().__init__(*args, cwd=ROOT, prefix=prefix, label=label)
