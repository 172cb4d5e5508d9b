"""The STM32F4's flash interface (RM0090 §3) for the emulator: the whole 1 MiB of an STM32F405 — the bootloader, the
board's data, the boot log, the two image slots, the settings sector (docs/protocol.md §12, firmware/port/
stm32f4_layout.h) — with the controller's rules, so that what a board would do wrong with its flash fails here too.

- Flash is memory the core reads as it reads flash; a write programs, and only while FLASH_CR.PG is set, the
  controller unlocked (FLASH_KEYR: 0x45670123 then 0xCDEF89AB) and the size that of FLASH_CR.PSIZE: otherwise
  FLASH_SR.PGSERR (or PGPERR for a wrong size) and nothing changes. Programming clears bits and never sets one
  (flash cells go from 1 to 0; only an erase brings them back).
- FLASH_CR.STRT with SER erases the sector of SNB (RM0090's sizes: 0-3 16 KiB, 4 64 KiB, 5-11 128 KiB).
  Operations finish at once (FLASH_SR.BSY reads 0); FLASH_SR.EOP is not set (no interrupt).
- Write protection: the option bytes' nWRP bits (FLASH_OPTCR bits 16-27, set with FLASH_OPTKEYR's keys 0x08192A3B,
  0x4C5D6E7F and OPTSTRT): an erase or a program of a protected sector is FLASH_SR.WRPERR and changes nothing. The
  bootloader protects itself, the board's data and the running image's slot, so the image cannot overwrite itself.
- The contents outlive the core: a :class:`Settings` (the board's flash; the name is from when the settings sector
  was all it held) is given to every board booted on it (a power cycle is a new board on the same flash), and kept
  in a file if one is named (1 MiB and the option bytes; a file of the settings sector alone is read as that).
"""

from __future__ import annotations

import os
import struct
import weakref
from collections.abc import Callable
from pathlib import Path

BASE, SIZE = 0x08000000, 1 << 20
SECTORS = [(k << 14, 1 << 14) for k in range(4)] + [(1 << 16, 1 << 16)] + [(k << 17, 1 << 17) for k in range(1, 8)]
"""Each sector's (offset from 0x08000000, size), by number."""
SECTOR, SECTOR_ADDRESS, SECTOR_SIZE = 11, 0x080E0000, 0x20000
"""The settings sector (the node ID, calibration)."""
INTERFACE = 0x40023C00
KEYR, OPTKEYR, SR, CR, OPTCR = 0x04, 0x08, 0x0C, 0x10, 0x14
KEYS = (0x45670123, 0xCDEF89AB)
OPTKEYS = (0x08192A3B, 0x4C5D6E7F)
PG, SER, STRT, LOCK = 1, 2, 1 << 16, 1 << 31
OPTLOCK, OPTSTRT = 1, 2
PGSERR, PGPERR, WRPERR = 1 << 7, 1 << 6, 1 << 4
NWRP_ALL = 0xFFF
"""nWRP as delivered: no sector protected."""


def sector_of(offset: int) -> int:
    """The sector number holding flash offset ``offset``."""
    for number, (start, size) in enumerate(SECTORS):
        if start <= offset < start + size:
            return number
    raise ValueError(f"offset {offset:#x} is outside the flash")


class Settings:
    """A board's flash (erased: 0xFF) and its option bytes' write protection, kept in ``path`` if given (read from
    it when it exists). ``data`` is the settings sector."""

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path) if path is not None else None
        self.memory = bytearray(b"\xff" * SIZE)
        self.nwrp = NWRP_ALL
        if self.path is not None and self.path.exists():
            raw = self.path.read_bytes()
            if len(raw) == SIZE + 4:
                self.memory[:] = raw[:SIZE]
                (self.nwrp,) = struct.unpack_from("<I", raw, SIZE)
            else:  # the settings sector alone (the format before the update slots)
                self.memory[SECTOR_ADDRESS - BASE :] = raw.ljust(SECTOR_SIZE, b"\xff")[:SECTOR_SIZE]
        self.erases = 0
        self.programs = 0
        self.listeners: list[Callable[[int, int], None]] = []  # (offset, length) changed: a core's mapped copy
        self._fd: int | None = None  # the file, opened once: a programmed word is one write, not an open and a close
        if self.path is not None and not (self.path.exists() and self.path.stat().st_size == SIZE + 4):
            self.path.write_bytes(bytes(self.memory) + struct.pack("<I", self.nwrp))

    @property
    def data(self) -> memoryview:
        return memoryview(self.memory)[SECTOR_ADDRESS - BASE :]

    def sector(self, number: int) -> bytes:
        start, size = SECTORS[number]
        return bytes(self.memory[start : start + size])

    def protected(self, number: int) -> bool:
        return not self.nwrp >> number & 1

    def write(self, offset: int, data: bytes) -> None:
        """Write ``data`` at ``offset`` as a probe does (no controller, no protection): the board's first flash."""
        self.memory[offset : offset + len(data)] = data
        self.changed(offset, len(data))

    def changed(self, offset: int, length: int) -> None:
        for listener in self.listeners:
            listener(offset, length)
        if self.path is not None:
            if self._fd is None:
                self._fd = os.open(self.path, os.O_RDWR)
                weakref.finalize(self, os.close, self._fd)
            os.pwrite(self._fd, self.memory[offset : offset + length], offset)  # in the file at once (no buffer)
            os.pwrite(self._fd, struct.pack("<I", self.nwrp), SIZE)

    def save(self) -> None:
        if self.path is not None:
            self.path.write_bytes(bytes(self.memory) + struct.pack("<I", self.nwrp))


class FlashInterface:
    """The controller's registers and the flash as one core sees them (offsets from 0x08000000)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.cr = LOCK
        self.sr = 0
        self.optcr = settings.nwrp << 16 | 0xAAED  # RM0090's reset value: read protection off, no WRP
        self._key = 0  # how many of the two keys were written in order
        self._optkey = 0

    # -- the registers at 0x40023C00 -------------------------------------------------------------------------

    def read_register(self, offset: int) -> int:
        if offset == CR:
            return self.cr
        if offset == SR:
            return self.sr
        if offset == OPTCR:
            return self.optcr
        return 0

    def write_register(self, offset: int, value: int) -> None:
        if offset == KEYR:
            if self.cr & LOCK and value == KEYS[self._key]:
                self._key += 1
                if self._key == len(KEYS):
                    self.cr &= ~LOCK
                    self._key = 0
            else:
                self._key = 0  # a wrong key: the interface stays locked (a real one until reset)
        elif offset == OPTKEYR:
            if self.optcr & OPTLOCK and value == OPTKEYS[self._optkey]:
                self._optkey += 1
                if self._optkey == len(OPTKEYS):
                    self.optcr &= ~OPTLOCK
                    self._optkey = 0
            else:
                self._optkey = 0
        elif offset == SR:
            self.sr &= ~(value & 0xF3)  # the flags are cleared by writing 1
        elif offset == CR:
            if self.cr & LOCK:
                return  # locked: a write to FLASH_CR is ignored
            self.cr = value & (LOCK | STRT | 0x3FF)
            if value & STRT:
                self._erase()
            self.cr &= ~STRT
        elif offset == OPTCR:
            if self.optcr & OPTLOCK and not value & OPTLOCK:
                return  # locked: only setting OPTLOCK again does anything
            self.optcr = value & ~OPTSTRT
            if value & OPTSTRT and not self.optcr & OPTLOCK:
                self.settings.nwrp = value >> 16 & NWRP_ALL  # programmed into the option bytes: kept
                self.settings.changed(0, 0)

    def _erase(self) -> None:
        number = (self.cr >> 3) & 0xF
        if not self.cr & SER or number >= len(SECTORS):
            self.sr |= PGSERR
        elif self.settings.protected(number):
            self.sr |= WRPERR
        else:
            start, size = SECTORS[number]
            self.settings.memory[start : start + size] = b"\xff" * size
            self.settings.erases += 1
            self.settings.changed(start, size)

    # -- the flash at 0x08000000 -----------------------------------------------------------------------------

    def read(self, offset: int, size: int) -> int:
        return int.from_bytes(self.settings.memory[offset : offset + size], "little")

    def write(self, offset: int, size: int, value: int) -> None:
        if self.cr & LOCK or not self.cr & PG:
            self.sr |= PGSERR
            return
        if size != 1 << ((self.cr >> 8) & 3):
            self.sr |= PGPERR
            return
        if self.settings.protected(sector_of(offset)):
            self.sr |= WRPERR
            return
        memory = self.settings.memory
        old = int.from_bytes(memory[offset : offset + size], "little")
        memory[offset : offset + size] = (old & value).to_bytes(size, "little")
        self.settings.programs += 1
        self.settings.changed(offset, size)
