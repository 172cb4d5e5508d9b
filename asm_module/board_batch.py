"""A batch of emulated boards' flash kept in a folder: what makes an emulated board a board you power-cycle.

A real board keeps its flash (its image, its node ID, its calibration: the settings sector) and its factory serial
(the STM32's 96-bit unique ID) when its power goes. The simulated robot of ``asm-robot --board-flash DIR`` keeps its
emulated boards' in ``DIR``, one pair of files per chain position (the board that sits on that joint, whatever node
ID it is given later):

- ``board-<position>.serial``: its serial, 24 hex digits; made at random the first time (a freshly made board);
- ``board-<position>.flash``: its flash (asm_module.flash.Settings' file); erased the first time, so the board is
  probe-flashed with the image and boots **unconfigured** (no node ID) until it is commissioned.

A robot restarted on the same folder has the same boards, with the IDs they were given; a deleted folder is a new,
unnumbered batch.
"""

from __future__ import annotations

import os
from pathlib import Path

from asm_py.canbus.commission import SERIAL_BYTES, parse_serial

from .flash import Settings


class BoardBatch:
    """The boards' flash in ``folder`` (made if missing); see the module docstring."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)

    def _path(self, position: int, suffix: str) -> Path:
        if not isinstance(position, int) or isinstance(position, bool) or not 1 <= position <= 253:
            raise ValueError(f"a chain position is 1..253, not {position!r}")
        return self.folder / f"board-{position}.{suffix}"

    def serial(self, position: int) -> bytes:
        """The serial of the board at ``position``: read, or made at random and kept when it has none yet.
        ValueError naming the file when what it holds is not a serial (never silently replaced: it is the board's
        identity)."""
        path = self._path(position, "serial")
        if not path.exists():
            serial = os.urandom(SERIAL_BYTES)
            path.write_text(serial.hex() + "\n")
            return serial
        text = path.read_text(errors="replace").strip()
        try:
            return parse_serial(text)
        except ValueError as exc:
            raise ValueError(f"{path}: a board's {str(exc).removeprefix('a ')}") from None

    def board(self, position: int) -> tuple[bytes, Settings]:
        """The serial and the flash of the board at ``position``."""
        return self.serial(position), self.settings(position)

    def settings(self, position: int) -> Settings:
        """The flash of the board at ``position`` (kept in its file; erased when new)."""
        return Settings(self._path(position, "flash"))
