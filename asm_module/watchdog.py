"""The STM32F4's independent watchdog (IWDG, RM0090 §19) for the emulator: what resets a board whose new image never
confirms itself (firmware update rollback), apart from the core so that its rules are read in one place.

KR 0x5555 opens PR and RLR for writing, 0xCCCC starts it, 0xAAAA reloads it (only once started); it counts the LSI's
32 kHz divided by 4 << PR down from RLR, and then resets the board. Time is the core's cycle count at 168 MHz.
"""

from __future__ import annotations

BASE = 0x40003000
LSI_HZ = 32_000
CLOCK_HZ = 168_000_000
KR, PR, RLR = 0x0, 0x4, 0x8


class IndependentWatchdog:
    """The IWDG's registers and, once started, the cycle at which it resets the board (``expires_at``)."""

    def __init__(self) -> None:
        self.registers: dict[int, int] = {PR: 0, RLR: 0xFFF}
        self._unlocked = False
        self.expires_at: int | None = None

    def read(self, offset: int) -> int:
        return self.registers.get(offset, 0)

    def write(self, offset: int, value: int, cycles: int) -> None:
        """A register write at core cycle ``cycles``."""
        if offset == KR:
            key = value & 0xFFFF
            self._unlocked = key == 0x5555
            if key == 0xCCCC or (key == 0xAAAA and self.expires_at is not None):
                period = (self.registers[RLR] + 1) * (4 << self.registers[PR])
                self.expires_at = cycles + period * CLOCK_HZ // LSI_HZ
        elif offset in (PR, RLR) and self._unlocked:
            self.registers[offset] = value & (7 if offset == PR else 0xFFF)

    def expired(self, cycles: int) -> bool:
        """Whether the watchdog has run out by core cycle ``cycles`` (never before it is started)."""
        return self.expires_at is not None and cycles >= self.expires_at
