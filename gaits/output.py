"""Where the ``gaits`` command may write (``tune --out``, ``simulate --mjcf``): checked before any work is done, so
an hour of tuning never ends in a file that cannot be written, and never over a file the gait needs.

Refused: the gait file itself and the robot file it names (through any name: a symbolic or hard link too; every
gait of the robot would be invalid after), a path that is not a regular file (``/dev/full`` takes nothing, a FIFO
waits for ever), and a file that cannot be opened for writing (``/proc/self/x``, a read-only folder).
"""

from __future__ import annotations

import os
from pathlib import Path

from .model import Gait


def _same(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except (OSError, RuntimeError):  # a link loop: no file of the gait's
        return False


def refused(out: Path, source: str | Path, gait: Gait) -> str | None:
    """Why ``out`` may not be written for the gait read from ``source``; None when it may. Creates nothing that was
    not there (a file made to test it is removed)."""
    source = Path(source)
    if _same(out, source):
        return "is the gait file itself: it would be overwritten"
    if gait.robot.file is not None and _same(out, source.parent / gait.robot.file):
        return f"is the gait's robot file ({gait.robot.file}): every gait of the robot needs it"
    try:
        existed = out.exists()
        if existed and not out.is_file():
            return "is not a regular file"
        with open(out, "a", encoding="utf-8"):  # appends nothing: an existing file keeps its bytes until written
            pass
        if not existed:
            out.unlink()
    except (OSError, RuntimeError, ValueError) as exc:
        return f"cannot be written: {getattr(exc, 'strerror', None) or exc}"
    return None
