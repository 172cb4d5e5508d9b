"""The page's last layout kept in a file, so a restarted studio shows the plots it showed.

Save layout / Load layout (web/monitor_panel.py) move a layout through the user's downloads; the arrangement also
survives a page reload (it lives in the studio). What did not survive was the studio process: after a restart the
live plots were empty. The studio keeps its current layout in ``<recordings dir>/studio-layout.json`` (the backend
names the path), written whenever it changes (to a temporary file, then renamed: a crash mid-write leaves the old
one), and read once at start. A missing, unreadable, huge or malformed file is no layout, never a failed start.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

log = logging.getLogger("asm_studio.layout")
MAX_BYTES = 1 << 20
"""A layout names a few dozen attributes: a larger file is not one (read no further)."""


class LayoutStore:
    """The last layout at ``path`` (None: kept nowhere)."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self._saved: Any = None

    def load(self) -> dict[str, Any] | None:
        """The layout the file holds, or None (no file, or not a layout's JSON object: logged)."""
        if self.path is None or not self.path.is_file():
            return None
        try:
            with self.path.open("rb") as file:
                raw = file.read(MAX_BYTES + 1)
            if len(raw) > MAX_BYTES:
                raise ValueError(f"larger than {MAX_BYTES} bytes")
            layout = json.loads(raw)
            if not isinstance(layout, dict):
                raise ValueError("not a JSON object")
        except (OSError, ValueError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
            log.warning("the last layout %s was not restored: %s", self.path, exc)
            return None
        self._saved = layout
        return layout

    def save(self, layout: dict[str, Any]) -> bool:
        """Write ``layout`` if it differs from what the file holds; whether it wrote. A failure is logged once per
        layout, never raised (the page goes on)."""
        if self.path is None or layout == self._saved:
            return False
        self._saved = layout
        temporary = self.path.with_name(self.path.name + ".tmp")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            temporary.write_text(json.dumps(layout, indent=2) + "\n", encoding="utf-8")
            os.replace(temporary, self.path)
        except OSError as exc:
            log.warning("the layout could not be kept in %s: %s", self.path, exc)
            return False
        return True
