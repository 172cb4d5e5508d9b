"""Where the ``gaits`` command may write (``tune --out``, ``simulate --mjcf``): checked before any work is done, so
an hour of tuning never ends in a file that cannot be written, and never over a file the gait needs.

Refused: the gait file itself and the robot file it names (through any name: a symbolic or hard link too; every
gait of the robot would be invalid after), a path that is not a regular file (``/dev/full`` takes nothing, a FIFO
waits for ever), and a file that cannot be opened for writing (``/proc/self/x``, a read-only folder).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
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


def write_whole(out: Path, text: str) -> None:
    """Write ``text`` to ``out`` whole or not at all: into a new file beside it, then renamed over it. The result of
    an hour's search must not be left half written over the file it replaces — by a full disk, a kill, or ``gaits
    tune``'s exit deadline — and that file keeps its bytes until the new ones are all on disk. Through a symbolic
    link its target is replaced, keeping the target's permissions (a new file gets the umask's, as ``open`` gives).
    Where no file can be made beside it (a folder not writable, the file is), it is written in place, as before."""
    target = out.resolve()
    try:
        handle, temporary = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".partial", dir=target.parent)
    except OSError:
        target.write_text(text, encoding="utf-8")
        return
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as file:
            file.write(text)
            file.flush()
            os.fsync(file.fileno())
        try:
            mode = os.stat(target).st_mode & 0o7777
        except FileNotFoundError:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.chmod(temporary, mode)
        os.replace(temporary, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise
