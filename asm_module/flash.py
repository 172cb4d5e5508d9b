"""The STM32F4's flash interface (RM0090 §3) for the emulator: the settings sector a board keeps its node ID in
(firmware/port/stm32f4_bxcan.c), with the controller's rules, so that what a board would do wrong with its flash
fails here too.

- The sector (11: 128 KiB at 0x080E0000) is memory the core reads as it reads flash; a write to it programs, and
  only while FLASH_CR.PG is set, the controller unlocked (FLASH_KEYR: 0x45670123 then 0xCDEF89AB) and the size
  that of FLASH_CR.PSIZE: otherwise FLASH_SR.PGSERR (or PGPERR for a wrong size) and nothing changes. Programming
  clears bits and never sets one (flash cells go from 1 to 0; only an erase brings them back).
- FLASH_CR.STRT with SER erases the sector of SNB (sector 11 here; another sector is the image, which the model
  leaves alone: WRPERR). Operations finish at once (FLASH_SR.BSY reads 0); FLASH_SR.EOP is not set (no interrupt).
- The contents outlive the core: a :class:`Settings` is given to every board booted on it (a power cycle is a new
  board on the same settings), and kept in a file if one is named.
"""

from __future__ import annotations

from pathlib import Path

SECTOR, SECTOR_ADDRESS, SECTOR_SIZE = 11, 0x080E0000, 0x20000
INTERFACE = 0x40023C00
KEYR, SR, CR = 0x04, 0x0C, 0x10
KEYS = (0x45670123, 0xCDEF89AB)
PG, SER, STRT, LOCK = 1, 2, 1 << 16, 1 << 31
PGSERR, PGPERR, WRPERR = 1 << 7, 1 << 6, 1 << 4


class Settings:
    """The settings sector's bytes (erased: 0xFF), kept in ``path`` if given (read from it when it exists)."""

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path) if path is not None else None
        if self.path is not None and self.path.exists():
            self.data = bytearray(self.path.read_bytes().ljust(SECTOR_SIZE, b"\xff")[:SECTOR_SIZE])
        else:
            self.data = bytearray(b"\xff" * SECTOR_SIZE)
        self.erases = 0
        self.programs = 0

    def save(self) -> None:
        if self.path is not None:
            self.path.write_bytes(bytes(self.data))


class FlashInterface:
    """The controller's registers and the settings sector as one core sees them."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.cr = LOCK
        self.sr = 0
        self._key = 0  # how many of the two keys were written in order

    # -- the registers at 0x40023C00 -------------------------------------------------------------------------

    def read_register(self, offset: int) -> int:
        if offset == CR:
            return self.cr
        if offset == SR:
            return self.sr
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
        elif offset == SR:
            self.sr &= ~(value & 0xF3)  # the flags are cleared by writing 1
        elif offset == CR:
            if self.cr & LOCK:
                return  # locked: a write to FLASH_CR is ignored
            self.cr = value & (LOCK | STRT | 0x3FF)
            if value & STRT:
                self._erase()
            self.cr &= ~STRT

    def _erase(self) -> None:
        if not self.cr & SER:
            self.sr |= PGSERR
        elif (self.cr >> 3) & 0xF != SECTOR:
            self.sr |= WRPERR  # the image's sectors: not the settings' to erase
        else:
            self.settings.data[:] = b"\xff" * SECTOR_SIZE
            self.settings.erases += 1
            self.settings.save()

    # -- the sector at 0x080E0000 ----------------------------------------------------------------------------

    def read(self, offset: int, size: int) -> int:
        return int.from_bytes(self.settings.data[offset : offset + size], "little")

    def write(self, offset: int, size: int, value: int) -> None:
        if self.cr & LOCK or not self.cr & PG:
            self.sr |= PGSERR
            return
        if size != 1 << ((self.cr >> 8) & 3):
            self.sr |= PGPERR
            return
        old = int.from_bytes(self.settings.data[offset : offset + size], "little")
        self.settings.data[offset : offset + size] = (old & value).to_bytes(size, "little")
        self.settings.programs += 1
        self.settings.save()
