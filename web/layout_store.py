"""The page's last layout kept in a file, so a restarted studio shows the plots it showed.

Save layout / Load layout (web/monitor_panel.py) move a layout through the user's downloads; the arrangement also
survives a page reload (it lives in the studio). What did not survive was the studio process: after a restart the
live plots were empty. The studio keeps its current layout in ``<recordings dir>/studio-layout.json`` (the backend
names the path), written whenever it changes (to a temporary file, then renamed: a crash mid-write leaves the old
one), and read once at start. A missing file is no layout yet, never a failed start.

A file that is there but is not a layout (not JSON, not an object, a version this studio does not read, plots it
does not have, a directory, unreadable) is the user's: it is never written over. The studio says which file and
why, in its log and on the page, and keeps no layout there until it is moved away (a review found a mistyped
``--layout`` file replaced by an empty layout at the page's first save).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

log = logging.getLogger("asm_studio.layout")
MAX_BYTES = 1 << 20
"""A layout names a few dozen attributes: a larger file is not one (read no further)."""
VERSION = 1
"""The layout version this studio writes and reads; a file of another version is refused, never guessed at."""

Check = Callable[[dict[str, Any]], None]
"""What the page checks of a layout beyond its version (its plots, its window): ValueError saying what is wrong."""


def check_version(layout: dict[str, Any]) -> None:
    """ValueError for a layout of a version this studio does not read (it would be read as something it is not).
    A missing version is version 1: a layout typed by hand."""
    version = layout.get("version", VERSION)
    if version != VERSION or isinstance(version, bool):
        raise ValueError(f"version {json.dumps(version)[:40]}, and this studio reads layouts of version {VERSION} only")


def read_layout(raw: bytes, source: str, check: Check | None = None) -> dict[str, Any]:
    """The layout ``raw`` holds (a file's bytes; ``source`` names the file in every message), or ValueError: ``<source>
    is not a layout: <why>``."""
    try:
        if len(raw) > MAX_BYTES:
            raise ValueError(f"larger than {MAX_BYTES} bytes")
        try:
            layout = json.loads(raw)
        except UnicodeDecodeError:
            raise ValueError("not UTF-8 text") from None
        except json.JSONDecodeError as exc:
            raise ValueError(f"not JSON ({exc})") from None
        if not isinstance(layout, dict):
            raise ValueError("not a JSON object")
        check_version(layout)
        if check is not None:
            check(layout)
    except ValueError as exc:
        raise ValueError(f"{source} is not a layout: {exc}") from None
    return layout


class LayoutStore:
    """The last layout at ``path`` (None: kept nowhere); ``check`` is what the page checks of a layout."""

    def __init__(self, path: Path | None, check: Check | None = None) -> None:
        self.path = path
        self.check = check
        self._saved: Any = None
        self.refused: str | None = None
        """Why the layout is not kept in the file: it is there and is not a layout, or it could not be written (the
        studio's log and the page say it). None: it is kept."""
        self._theirs = False
        """The file was there and is not a layout: it is the user's, never written over."""

    def load(self) -> dict[str, Any] | None:
        """The layout the file holds, or None: no file yet, or a file that is not a layout (``refused`` says why, the
        log too, and the file is never written over)."""
        path = self.path
        if path is None or not (path.exists() or path.is_symlink()):
            return None
        try:
            if not path.is_file():
                raise ValueError(f"{path} is not a layout: not a regular file")
            with path.open("rb") as file:
                raw = file.read(MAX_BYTES + 1)
            layout = read_layout(raw, str(path), self.check)
        except (OSError, ValueError) as exc:
            why = str(exc) if isinstance(exc, ValueError) else f"{path} cannot be read: {exc.strerror or exc}"
            self._theirs = True
            self._refuse(f"{why} — the last layout was not restored, and the file is left as it is: no layout is "
                         "kept in it (move it away, or give --layout another file)")  # fmt: skip
            return None
        self._saved = layout
        return layout

    def _refuse(self, why: str) -> None:
        if why != self.refused:
            log.warning("%s", why)
        self.refused = why

    def spare(self, layout: dict[str, Any]) -> None:
        """Write nothing for ``layout`` (what the page shows after the file's layout could not be restored: its
        modules never answered): the file keeps the user's layout until the plots are changed."""
        self._saved = layout

    def save(self, layout: dict[str, Any]) -> bool:
        """Write ``layout`` if it differs from what the file holds; whether it wrote. Nothing is written over a file
        that was not a layout; a failure is ``refused`` and logged (once while it is the same), never raised (the
        page goes on)."""
        path = self.path
        if path is None or self._theirs or layout == self._saved:
            return False
        self._saved = layout
        if path.is_dir():  # renamed over, it would fail, and the temporary file would stay beside it
            self._refuse(f"the layout could not be kept in {path}: it is a directory")
            return False
        temporary = path.with_name(path.name + ".tmp")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            temporary.write_text(json.dumps(layout, indent=2) + "\n", encoding="utf-8")
            os.replace(temporary, path)
        except OSError as exc:
            with contextlib.suppress(OSError):
                temporary.unlink(missing_ok=True)  # nothing half-written left beside it
            self._refuse(f"the layout could not be kept in {path}: {exc.strerror or exc}")
            return False
        self.refused = None
        return True
