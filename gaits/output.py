"""Where the ``gaits`` command may write (``tune --out``, ``simulate --mjcf``): checked before any work is done, so
an hour of tuning never ends in a file that cannot be written, and never over a file the gait needs.

Refused: the gait file itself and the robot file it names (through any name: a symbolic or hard link too; every
gait of the robot would be invalid after), a path that is not a regular file (``/dev/full`` takes nothing, a FIFO
waits for ever), and a file that cannot be opened for writing (``/proc/self/x``, a read-only folder).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import stat
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
        if not existed:  # made here: through a dangling link, the link's target (the link is kept)
            Path(os.path.realpath(out)).unlink()
    except (OSError, RuntimeError, ValueError) as exc:
        return f"cannot be written: {getattr(exc, 'strerror', None) or exc}"
    return None


def write_whole(out: Path, text: str) -> None:
    """Write ``text`` to ``out`` whole or not at all: into a new file beside it, then renamed over it. The result of
    an hour's search must not be left half written over the file it replaces — by a full disk, a kill, or ``gaits
    tune``'s exit deadline — and that file keeps its bytes until the new ones are all on disk. Through a symbolic
    link, its target is replaced. The new file has the permissions of the one it replaces (or the umask's).

    Where a rename would change more than the bytes, the file is written in place as before: another user's file
    (its owner, group and ACLs would become ours), a file with other hard links (they would keep the old bytes), one
    this user may not write, and wherever the folder takes no new file or the rename is refused (a sticky folder).
    A kill during the write can leave a ``.gaits-*.partial`` file beside it."""
    target = Path(os.path.realpath(out))  # a link loop is no error here: the write below says it
    if not _replaceable(target):
        target.write_text(text, encoding="utf-8")
        return
    try:
        temporary = _new_beside(target)
    except OSError:
        target.write_text(text, encoding="utf-8")
        return
    try:
        with open(temporary, "w", encoding="utf-8") as file:
            file.write(text)
            file.flush()
            os.fsync(file.fileno())
        with contextlib.suppress(FileNotFoundError):
            os.chmod(temporary, os.stat(target).st_mode & 0o777)
        try:
            os.replace(temporary, target)
        except PermissionError:  # a sticky folder: renamed over only by the folder's or the file's owner
            os.unlink(temporary)
            target.write_text(text, encoding="utf-8")
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise


def _replaceable(target: Path) -> bool:
    """Whether renaming a new file over ``target`` changes nothing but its bytes (see ``write_whole``)."""
    try:
        info = os.stat(target)
    except FileNotFoundError:
        return True
    except OSError:
        return False
    return (stat.S_ISREG(info.st_mode) and info.st_uid == os.geteuid() and info.st_nlink == 1
            and os.access(target, os.W_OK))  # fmt: skip


def _new_beside(target: Path) -> Path:
    """A new, empty file in ``target``'s folder, with a short name (a long ``target`` name must not make it too
    long) and the umask's permissions (``open`` applies it; ``mkstemp`` would give 0600)."""
    for _ in range(100):
        path = target.parent / f".gaits-{secrets.token_hex(4)}.partial"
        try:
            os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        except FileExistsError:
            continue
        return path
    raise FileExistsError(f"no new file name in {target.parent}")
