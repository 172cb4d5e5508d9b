"""The memory-mapped registers the board port touches, as the emulated core (asm_module/emulator.py) answers its
loads and stores: bxCAN (asm_module/bxcan.py), SysTick and the SCB, the cycle counter, the independent watchdog, the
flash interface, the encoder's and the servo PWM's timers, the foot switch's pin. A mixin of :class:`Cortex`, whose
state these read and write; apart so that each file stays one idea (the core's running, its peripherals).

An empty poll of CAN_RF0R with nothing else touched since the last one is the main loop idling: the run stops there
(REASON_IDLE) and the clock jumps to the next interrupt (see the emulator's docstring).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from unicorn.unicorn import Uc

from .board_flash import known_image
from .board_types import Joint
from .bxcan import RF0R, BxCan
from .cortex_clock import NEVER, REASON_IDLE, CoreClock
from .elf import Image
from .firmware_image import LOAD_ADDRESS
from .flash import INTERFACE, FlashInterface
from .watchdog import BASE as IWDG
from .watchdog import IndependentWatchdog

SCB_VTOR, SCB_AIRCR = 0xE000ED08, 0xE000ED0C
DEMCR, DWT_CTRL, DWT_CYCCNT = 0xE000EDFC, 0xE0001000, 0xE0001004
SCB_ICSR, PENDSTSET = 0xE000ED04, 1 << 26
ENCODER_COUNTS = 4096


class Peripherals:
    """The registers' side of :class:`~asm_module.emulator.Cortex` (what it holds, declared for the type checker)."""

    uc: Uc
    can: BxCan
    joint: Joint
    flash_interface: FlashInterface
    watchdog: IndependentWatchdog
    registers: dict[int, int]
    encoder: dict[int, int]
    pwm: dict[int, int]
    cpacr: int
    vectors: tuple[int, ...]
    app: Image | None
    _c: CoreClock
    _activity: int
    _activity_at_empty: int
    _reading: Any
    _cyccnt_base: int
    _stop: Callable[[int], None]
    _reset: Callable[[str], None]

    # -- the peripherals ---------------------------------------------------------------------------------------

    def _read(self, uc: Uc, offset: int, size: int, page: int) -> int:
        address = page + offset
        word = self._register(address & ~3)
        return (word >> 8 * (address & 3)) & ((1 << 8 * size) - 1)

    def _register(self, address: int) -> int:
        if 0x40006400 <= address < 0x40006800:
            value = self.can.read(address - 0x40006400)
            if address - 0x40006400 == RF0R and not value & 3 and not self.can.wire:
                c = self._c
                if self._activity == self._activity_at_empty and not c.calling and not c.reason:
                    self._stop(REASON_IDLE)
                self._activity_at_empty = self._activity
                return value
        else:
            if address == 0x40000024 and self.encoder.get(0x08, 0) & 7 == 3 and self.encoder.get(0, 0) & 1:
                self._reading = self.joint.read()
                return round(self._reading[0] * ENCODER_COUNTS / 360) & 0xFFFFFFFF
            if address == 0x40020010:  # GPIOA_IDR: the foot switch on PA2
                return int(self._reading[1]) << 2
            if INTERFACE <= address < INTERFACE + 0x20:
                return self.flash_interface.read_register(address - INTERFACE)
            if address == SCB_VTOR:
                return self.registers.get(SCB_VTOR, 0)
            if IWDG <= address < IWDG + 0x10:
                return self.watchdog.read(address - IWDG)
            value = self._systick(address)
        self._activity += 1
        return value

    def _systick(self, address: int) -> int:
        c = self._c
        if address == 0xE000E010:
            flag, c.countflag = c.countflag, 0
            return c.csr | flag << 16
        if address == 0xE000E014:
            return c.rvr
        if address == 0xE000E018:
            return max(0, c.systick_next - c.cycles - 1) if c.csr & 1 else 0
        if address == 0xE000ED88:
            return self.cpacr
        if address == SCB_ICSR:
            return PENDSTSET if c.pending else 0
        if address == DWT_CYCCNT:
            return self._cyccnt()
        return self.registers.get(address, 0)

    def _cyccnt(self) -> int:
        on = self.registers.get(DEMCR, 0) >> 24 & 1 and self.registers.get(DWT_CTRL, 0) & 1
        return (self._c.cycles - self._cyccnt_base) & 0xFFFFFFFF if on else 0

    def _write(self, uc: Uc, offset: int, size: int, value: int, page: int) -> None:
        address = page + offset
        if IWDG <= address < IWDG + 0x10:
            self.watchdog.write(address - IWDG, value, self._c.cycles)  # feeding it is no activity: the loop may idle
            expires = self.watchdog.expires_at
            self._c.watchdog_at = NEVER if expires is None else expires
            return
        self._activity += 1
        if 0x40006400 <= address < 0x40006800:
            self.can.write(address - 0x40006400, value)
        elif address == 0xE000E010:
            c = self._c
            if value & 1 and not c.csr & 1:
                c.systick_next = c.cycles + c.rvr + 1
            c.csr = value & 7
        elif address == 0xE000E014:
            self._c.rvr = value & 0xFFFFFF
        elif address == 0xE000E018:
            c = self._c
            c.systick_next = c.cycles + c.rvr + 1  # any write clears the counter: it reloads
        elif address == 0xE000ED88:
            self.cpacr = value
        elif address == DWT_CYCCNT:
            self._cyccnt_base = self._c.cycles - value  # counting on from the value written
        elif 0x40000000 <= address < 0x40000400:
            self.encoder[address & 0x3FF] = value
        elif 0x40000400 <= address < 0x40000800:
            self._pwm(address & 0x3FF, value)
        elif INTERFACE <= address < INTERFACE + 0x20:
            self.flash_interface.write_register(address - INTERFACE, value)
        elif address == SCB_VTOR:
            self._vector_table(value)
        elif address == SCB_AIRCR and value >> 16 == 0x05FA and value & 4:
            self._reset("the image asked for a reset (SYSRESETREQ)")
        else:
            self.registers[address] = value

    def _vector_table(self, address: int) -> None:
        """VTOR moved (the bootloader starting an image): exceptions vector there, and the image (in RAM, its header
        just below the table) is looked up among the known ones for its symbols."""
        self.registers[SCB_VTOR] = address
        self.vectors = struct.unpack("<16I", self.uc.mem_read(address, 64))
        if address == LOAD_ADDRESS + 0x80:
            self.app = known_image(lambda at, n: bytes(self.uc.mem_read(LOAD_ADDRESS + at, n)))

    def _pwm(self, offset: int, value: int) -> None:
        """TIM3: a new compare value or output enable commands the servo (the preload's wait for the next 20 ms
        period is not modelled); the output disabled relaxes it."""
        before = self.pwm.get(0x20, 0) & 1
        self.pwm[offset] = value
        running = self.pwm.get(0, 0) & 1 and self.pwm.get(0x18, 0) >> 4 & 7 in (6, 7)
        enabled = self.pwm.get(0x20, 0) & 1
        if running and enabled and offset in (0x34, 0x20):
            self.joint.command((self.pwm.get(0x34, 0) - 1500) * 90 / 1000)
        elif before and not enabled:
            self.joint.relax()
