"""The board image in an instruction-level emulator: a Cortex-M4 (Unicorn, Thumb, M-class) running the STM32F4
port's ELF unchanged, with models of what the port touches — bxCAN (asm_module/bxcan.py), SysTick and its
interrupt, the FPU's enable bit, the servo's PWM timer, the encoder's timer and the foot switch's pin.

Why each piece is as it is:

- **Time** is the instruction count (one instruction taken as one cycle: a Cortex-M4 retires most in one, loads,
  branches and divisions take more, so real cycles are somewhat higher), in milliseconds of 168,000 from the end
  of the boot. SysTick fires every RVR + 1 of them, as the image configured it (3,360,000: the port's 20 ms control
  period), and SCB_ICSR.PENDSTSET says when its interrupt is pending. Instructions are counted per translated
  block, from the block's bytes (Thumb-2: a halfword starting 0b11101, 0b11110 or 0b11111 begins a 32-bit
  instruction), by a hook in C (asm_module/cortex_clock.c).
- **Idle**: the port polls CAN_RF0R in its main loop. Two empty polls with nothing else touched between them and
  no interrupt taken mean the loop can do nothing until an interrupt or a frame: the emulator stops there and
  jumps the clock to the next SysTick interrupt or the watchdog's expiry, as far as the outside clock allows, so an
  idle module costs a few blocks per interrupt, and the host may call into the image at that point (the main loop,
  outside the runtime).
- **Interrupts**: Unicorn has no NVIC. A SysTick exception is entered as the core would: the basic or (when the
  FPU is in use, CONTROL.FPCA) extended frame pushed on the main stack, 8-byte aligned, LR = EXC_RETURN, PC = the
  vector; the handler's branch to EXC_RETURN stops Unicorn (its core raises an exception return it cannot
  finish) and the emulator pops the frame. The core stays in thread mode while the handler runs (Unicorn's own
  exception return needs the NVIC it lacks). The extended frame's FP part is stacked lazily, as the M4 does by
  default: the FP registers are kept aside only for a handler not proven FP-free from its code.
- **Boot**: a fresh board's flash is written as a probe writes it (asm_module/board_flash.py); the core starts in
  the bootloader (sector 0), which copies the chosen image to RAM and points VTOR at it; the image is known by its
  header's CRC (its ELF's symbols). The watchdog and SYSRESETREQ end a core with :class:`BoardReset`.
- **Faults**: any access outside the mapped memory and peripherals, or reaching Default_Handler, raises
  :class:`FirmwareFault` naming the address — the emulated board has stopped. FPU instructions before the image
  sets CPACR would fault on the board (Unicorn runs them anyway); the emulator checks CONTROL.FPCA at every stop.
- **The cycle counter** (DWT_CYCCNT, which the port reads around its control tick for module.info) is the same
  instruction count, running once DEMCR.TRCENA and DWT_CTRL.CYCCNTENA are set; a write sets it.
"""

from __future__ import annotations

import math
import struct

from unicorn import (
    UC_ARCH_ARM,
    UC_HOOK_CODE,
    UC_HOOK_MEM_WRITE_PROT,
    UC_MODE_MCLASS,
    UC_MODE_THUMB,
    UC_PROT_EXEC,
    UC_PROT_READ,
)
from unicorn import arm_const as arm
from unicorn.unicorn import Uc, UcContext, UcError

from .board_flash import bootloader, known_images, probe_flash, register_image
from .board_types import BoardReset, FirmwareFault, Joint, TickStats
from .bxcan import BxCan
from .cortex_clock import (
    NEVER,
    REASON_BUDGET,
    REASON_FAULT,
    REASON_IDLE,
    REASON_NONE,
    REASON_RESET,
    REASON_RETURN,
    REASON_STOPPED,
    REASON_SYSTICK,
    REASON_WATCHDOG,
    Clock,
    CoreClock,
    emu_start,
)
from .cortex_peripherals import Peripherals
from .elf import Image
from .firmware_image import LOAD_ADDRESS, MAX_SIZE
from .flash import SECTORS, FlashInterface, Settings
from .thumb import Batch, local_16bit
from .watchdog import CLOCK_HZ, IndependentWatchdog

FLASH, FLASH_SIZE = 0x08000000, 1 << 20
BOOT_SIZE = SECTORS[0][1]
"""The bootloader's sector: the only flash the core executes from (images run from RAM). The whole flash is mapped
read-only into the core, a copy of the board's :class:`Settings` kept in step with it (read as fast as RAM, as the
board's flash accelerator reads it); every store to it goes to the flash interface (asm_module/flash.py), which
programs it."""
RAM, RAM_SIZE = 0x20000000, 128 << 10
UID = 0x1FFF7A10
"""The 96-bit unique ID (RM0090 §39.1): the board's serial."""
PAINT = 0xC5C5C5C5
"""What the stack is filled with at boot; the high-water mark is where it was overwritten."""
EXC_RETURN_BASIC, EXC_RETURN_FP = 0xFFFFFFF9, 0xFFFFFFE9
CALL_RETURN = 0x1FFFFF00
"""Where a function the host calls returns to (an exit address: never reached by the image itself)."""
SYSTICK_VECTOR = 15
AHEAD = 50
"""Milliseconds a busy image may run ahead of the outside clock in one call of Cortex.run."""
CALL_BUDGET_MS = 100
"""Milliseconds of the board's time a call of the host into the image may take before it is a fault: the run holds
the interpreter lock, and a handler spinning for good would hold the host's whole process with it."""
CYCLES_PER_MS = CLOCK_HZ // 1000
"""The emulated clock's millisecond: the STM32F405/407's core clock (168 MHz), which the port's SysTick reload
assumes, at one instruction a cycle."""
_FRAME_REGS = [arm.UC_ARM_REG_R0, arm.UC_ARM_REG_R1, arm.UC_ARM_REG_R2, arm.UC_ARM_REG_R3, arm.UC_ARM_REG_R12,
               arm.UC_ARM_REG_LR, arm.UC_ARM_REG_PC, arm.UC_ARM_REG_XPSR]  # fmt: skip
_FP_REGS = [getattr(arm, f"UC_ARM_REG_S{k}") for k in range(16)]
_ENTRY_REGS = [*_FRAME_REGS, arm.UC_ARM_REG_CONTROL, arm.UC_ARM_REG_SP]


class Cortex(Peripherals):
    """One board booted to its image's main loop's first idle point: its bootloader chose the image, copied it to
    RAM and started it. ``settings`` is its flash (asm_module/flash.py): a fresh one (erased) is first written as a
    probe would (:func:`probe_flash`: the bootloader and ``image``); on a used one the board boots what the flash
    holds. ``board_config``, if given, is written over the image's symbol of that name in the board's sector (as a
    flasher writes a module's own settings); ``serial`` is its unique ID."""

    def __init__(self, image: Image, can: BxCan, joint: Joint, board_config: bytes | None = None, *,
                 settings: Settings | None = None, serial: bytes = bytes(12)) -> None:  # fmt: skip
        self.image, self.can, self.joint = image, can, joint
        self.uc = uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        self.settings = settings = settings if settings is not None else Settings()
        register_image(image)
        if settings.memory[:4] == b"\xff" * 4:
            probe_flash(settings, image)
        if board_config is not None:
            address, size = image.symbols["board_config"]
            settings.write(address - FLASH, board_config[:size].ljust(size, b"\0"))
        self.flash_interface = FlashInterface(settings)
        uc.mem_map(FLASH, BOOT_SIZE, UC_PROT_READ | UC_PROT_EXEC)
        uc.mem_map(FLASH + BOOT_SIZE, FLASH_SIZE - BOOT_SIZE, UC_PROT_READ)
        uc.mem_write(FLASH, bytes(settings.memory))
        uc.hook_add(UC_HOOK_MEM_WRITE_PROT, self._flash_write, begin=FLASH, end=FLASH + FLASH_SIZE - 1)
        settings.listeners.append(self._mirror)
        uc.mem_map(UID & ~0xFFF, 0x1000, UC_PROT_READ)
        uc.mem_write(UID, serial)
        uc.mem_map(RAM, RAM_SIZE)
        self.app: Image | None = None  # the image running, once the bootloader started one the emulator knows
        self.stack_bottom = (image.symbol("_ebss") + 7) & ~7
        self.stack_top = image.symbol("_stack_top")
        uc.mem_write(self.stack_bottom, struct.pack("<I", PAINT) * ((self.stack_top - self.stack_bottom) // 4))
        self.registers: dict[int, int] = {}  # every peripheral register written and not modelled further
        self.watchdog = IndependentWatchdog()
        for page in (0x40000000, 0x40003000, 0x40006000, 0x40020000, 0x40023000, 0xE0001000, 0xE000E000):
            uc.mmio_map(page, 0x1000, self._read, page, self._write, page)
        self.systicks = 0  # SysTick interrupts taken
        self.idle = False  # the last run ended in the main loop's idle poll: the host may call into the image
        self.idle_cycles = 0  # of those, skipped while the main loop idled
        self.worst_period = 0  # the most cycles executed in one control period (from a control tick to the next)
        self._period_start: int | None = None
        self.epoch = 0  # the cycle count at the end of the boot: the emulated clock's millisecond 0
        self.cpacr = 0
        self._cyccnt_base = 0  # CYCCNT = cycles - this (it counts while DEMCR.TRCENA and DWT_CTRL.CYCCNTENA are set)
        self.pwm: dict[int, int] = {}  # TIM3's registers by offset
        self.encoder: dict[int, int] = {}  # TIM2's
        self._reading = (0.0, False)
        self._activity = self._activity_at_empty = 0
        self._reset_cause = ""
        self._fp_context: UcContext | None = None  # the FP registers at exception entry (lazy stacking)
        self._fault = ""  # what stopped the image, in words (Default_Handler)
        self.ticks = TickStats()
        self._tick_start: int | None = None
        self._returns: set[int] = set()
        self.clock = Clock(uc, [(FLASH, FLASH + BOOT_SIZE - 1), (LOAD_ADDRESS, LOAD_ADDRESS + MAX_SIZE - 1)])
        self._c: CoreClock = self.clock.state  # the cycle count, SysTick, the watchdog's deadline, the stop reason
        self._hooked: set[int] = set()
        for known in {id(i): i for i in [*known_images(), image]}.values():  # each image's, while it runs
            self._hook(known)
        boot_fault = bootloader().symbol("Default_Handler")
        uc.hook_add(UC_HOOK_CODE, self._faulted, None, begin=boot_fault, end=boot_fault)
        uc.ctl_exits_enabled(True)
        uc.ctl_set_exits([EXC_RETURN_BASIC & ~1, EXC_RETURN_FP & ~1, CALL_RETURN])
        stack, reset = struct.unpack_from("<II", settings.memory, 0)
        uc.reg_write(arm.UC_ARM_REG_SP, stack)
        uc.reg_write(arm.UC_ARM_REG_CONTROL, 0)
        self._resume_at = reset & ~1  # where the next run continues (the PC, kept here between runs)
        self._entry_read = Batch(uc, _ENTRY_REGS)
        self._entry_write = Batch(uc, [arm.UC_ARM_REG_SP, arm.UC_ARM_REG_LR, arm.UC_ARM_REG_CONTROL])
        self._return_read = Batch(uc, [arm.UC_ARM_REG_SP, arm.UC_ARM_REG_CONTROL])
        self._return_write = Batch(uc, [*_FRAME_REGS[:6], arm.UC_ARM_REG_XPSR, arm.UC_ARM_REG_CONTROL,
                                         arm.UC_ARM_REG_SP])  # fmt: skip
        self._fp_free_vectors: dict[int, bool] = {}
        self.vectors = struct.unpack_from("<16I", settings.memory, 0)
        self.run(0)
        if self.app is not None and id(self.app) not in self._hooked:  # first seen by this boot (no ELF of it)
            self._hook(self.app)
            uc.ctl_flush_tb()  # its code translated so far, translated again with the hooks
        self.epoch = self.cycles

    def _hook(self, image: Image) -> None:
        """Hook ``image``'s control tick (when its symbols say where) and its fault handler: each acts only while
        that image runs (self.app)."""
        self._hooked.add(id(image))
        if "asm_module_tick" in image.symbols:
            tick = image.symbol("asm_module_tick")
            self.uc.hook_add(UC_HOOK_CODE, self._tick_entered, image, begin=tick, end=tick)
        fault = image.symbol("Default_Handler")
        self.uc.hook_add(UC_HOOK_CODE, self._faulted, image, begin=fault, end=fault)

    def release(self) -> None:
        """Stop mirroring the flash into this core (it was reset or powered off; the flash lives on)."""
        if self._mirror in self.settings.listeners:
            self.settings.listeners.remove(self._mirror)

    def _flash_write(self, uc: Uc, access: int, address: int, size: int, value: int, _: object) -> bool:
        """A store to the flash: the flash interface decides what it programs (asm_module/flash.py), mirrored into
        the core at once (the next load reads it); the store itself does not happen (the flash is mapped read-only:
        every store comes here, and a handled one is dropped), so no bit changes that the controller would not."""
        self.flash_interface.write(address - FLASH, size, value)
        return True

    def _mirror(self, offset: int, length: int) -> None:
        """The flash changed (programmed, erased, or written by a probe): the core's copy follows (Unicorn
        translates again any code of the bootloader's sector that changed)."""
        if length:
            self.uc.mem_write(FLASH + offset, bytes(self.settings.memory[offset : offset + length]))

    # -- running -----------------------------------------------------------------------------------------------

    def _interrupt(self) -> int:
        """The cycle of the next SysTick interrupt (NEVER while SysTick does not interrupt)."""
        c = self._c
        return c.systick_next if c.csr & 3 == 3 and c.rvr else NEVER

    @property
    def wake_ms(self) -> float:
        """When an idle image next has something to do without a frame — its next SysTick interrupt or the
        watchdog's expiry — in milliseconds of the emulated clock (inf: never)."""
        at = min(self._interrupt(), self._c.watchdog_at)
        return math.inf if at == NEVER else (at - self.epoch) / CYCLES_PER_MS

    @property
    def now_ms(self) -> int:
        """The emulated clock in milliseconds since the boot ended (the first idle point): what run() runs to."""
        return (self._c.cycles - self.epoch) // CYCLES_PER_MS

    def run(self, until_ms: int) -> None:
        """Run the image until it idles at millisecond ``until_ms`` of the emulated clock (:attr:`now_ms`): idle, the
        clock jumps to what comes first of the next SysTick interrupt, the watchdog's expiry and ``until_ms`` — no
        instruction could run before it — and no further. A busy image runs on past it, by AHEAD milliseconds at
        most in one call (then ``idle`` is False: the host must not call into it yet)."""
        self.idle = False
        c = self._c
        until = self.epoch + until_ms * CYCLES_PER_MS
        c.run_until = until + AHEAD * CYCLES_PER_MS  # a run keeps the interpreter lock: never longer than this
        try:
            self._run_to(until)
        finally:
            c.run_until = NEVER

    def _run_to(self, until: int) -> None:
        c = self._c
        while True:
            reason = self._resume()
            if reason == REASON_BUDGET:  # busy (spinning with no interrupt due, say): the host's turn, then on
                return
            if reason == REASON_SYSTICK:
                if c.cycles >= until + AHEAD * CYCLES_PER_MS:
                    c.pending = 1  # taken at the next run
                    return
                self._enter(self.vectors[SYSTICK_VECTOR])
            elif reason == REASON_RETURN:
                self._exception_return()
            elif reason == REASON_RESET:
                raise BoardReset(self._reset_cause)
            elif reason == REASON_WATCHDOG:
                raise BoardReset("the independent watchdog expired")
            elif reason == REASON_IDLE:
                interrupt = self._interrupt()
                wake = min(interrupt, c.watchdog_at, until)
                self.idle_cycles += max(0, wake - c.cycles)
                c.cycles = max(c.cycles, wake)
                if self.watchdog.expired(c.cycles):
                    raise BoardReset("the independent watchdog expired")
                if c.cycles < interrupt:  # the outside clock's now: the host's turn
                    self.idle = True
                    return
                self.clock.count_down()
                c.pending = 0
                self._enter(self.vectors[SYSTICK_VECTOR])
            else:
                raise FirmwareFault(f"the image stopped at {self.pc:#010x} ({self._fault or 'stopped'})")

    @property
    def pc(self) -> int:
        return int(self.uc.reg_read(arm.UC_ARM_REG_PC))

    @property
    def cycles(self) -> int:
        """Instructions executed since reset: the emulated clock (asm_module/cortex_clock.c counts them)."""
        return self._c.cycles

    def _resume(self) -> int:
        c = self._c
        c.reason = REASON_NONE
        try:
            emu_start(self.uc, self._resume_at | 1)
        except UcError as exc:  # a branch to EXC_RETURN is one: Unicorn's core raises its exception return
            if self.pc not in (EXC_RETURN_BASIC & ~1, EXC_RETURN_FP & ~1):
                raise FirmwareFault(f"{exc} at {self.pc:#010x}") from None
        self._resume_at = pc = self.pc
        if pc in (EXC_RETURN_BASIC & ~1, EXC_RETURN_FP & ~1):
            return REASON_RETURN
        if self.cpacr & 0xF << 20 != 0xF << 20 and int(self.uc.reg_read(arm.UC_ARM_REG_CONTROL)) & 4:
            raise FirmwareFault("an FPU instruction ran before CPACR enabled the FPU (a UsageFault on the board)")
        return c.reason or REASON_STOPPED

    def _stop(self, reason: int) -> None:
        self._c.reason = reason
        self.uc.emu_stop()

    def _reset(self, cause: str) -> None:
        self._reset_cause = cause
        self._stop(REASON_RESET)

    def _faulted(self, uc: Uc, address: int, size: int, image: Image | None) -> None:
        if image is not self.app:
            return  # another image's Default_Handler address: code of the one running
        self._fault = "Default_Handler: an exception the image does not handle"
        self._stop(REASON_FAULT)

    def _tick_entered(self, uc: Uc, address: int, size: int, image: Image) -> None:
        if image is not self.app:
            return
        self._tick_start = self.cycles
        busy = self._tick_start - self.idle_cycles
        if self._period_start is not None:  # the first period is the boot's
            self.worst_period = max(self.worst_period, busy - self._period_start)
        self._period_start = busy
        back = int(uc.reg_read(arm.UC_ARM_REG_LR)) & ~1
        if back not in self._returns:
            self._returns.add(back)
            uc.hook_add(UC_HOOK_CODE, self._tick_returned, begin=back, end=back)

    def _tick_returned(self, uc: Uc, address: int, size: int, _: object) -> None:
        if self._tick_start is not None:
            spent = self.cycles - self._tick_start
            self.ticks.ticks += 1
            self.ticks.total += spent
            self.ticks.worst = max(self.ticks.worst, spent)
            self._tick_start = None

    # -- exceptions --------------------------------------------------------------------------------------------

    def _enter(self, vector: int) -> None:
        """Take an exception: push the frame as the core does and branch to ``vector``. With the FPU in use
        (CONTROL.FPCA) the frame is the extended one, its FP part reserved and — lazy stacking, the M4's default —
        filled only if the handler uses the FPU (then from the registers as they were at entry)."""
        uc = self.uc
        self._activity += 1
        self.systicks += 1
        values = self._entry_read.read()
        sp, control = values.pop(), values.pop()
        values[6] = self._resume_at  # the return address: the instruction not yet executed
        values[7] = (values[7] & ~0x1FF) | 1 << 24  # the stacked xPSR: thread mode, Thumb
        extended = bool(control & 4)
        size = 0x68 if extended else 0x20
        frame = (sp - size) & ~7
        if frame != sp - size:
            values[7] |= 1 << 9  # the frame was realigned: one padding word above it
        uc.mem_write(frame, struct.pack("<8I", *values))
        self._fp_context = uc.context_save() if extended and not self._fp_free(vector) else None
        self._entry_write.write([frame, EXC_RETURN_FP if extended else EXC_RETURN_BASIC, control & ~4])
        self._resume_at = vector & ~1
        self._c.depth += 1

    def _fp_free(self, vector: int) -> bool:
        """The handler at ``vector`` cannot touch the FPU: its code (its symbol's extent) is 16-bit instructions
        only — no FP instruction is — that call nothing and branch nowhere outside it, so lazy stacking will never
        have to save the FP registers for it. Decided once per handler from the image."""
        known = self._fp_free_vectors.get(vector)
        if known is None:
            start = vector & ~1
            symbols = self.app.symbols.values() if self.app is not None else ()
            size = next((size for address, size in symbols if address & ~1 == start and size), 0)
            code = bytes(self.uc.mem_read(start, size))
            halfwords = struct.unpack(f"<{len(code) // 2}H", code[: len(code) // 2 * 2])
            known = bool(halfwords) and all(local_16bit(h, start + 2 * k, start, start + size)
                                            for k, h in enumerate(halfwords))  # fmt: skip
            self._fp_free_vectors[vector] = known
        return known

    def _exception_return(self) -> None:
        uc = self.uc
        extended = self._resume_at == EXC_RETURN_FP & ~1
        sp, control = self._return_read.read()
        size = 0x68 if extended else 0x20
        words = struct.unpack("<8I", uc.mem_read(sp, 32))
        self._resume_at = words[6] & ~1
        if extended and control & 4 and self._fp_context is not None:  # the handler used the FPU: lazy state back
            context = self._fp_context
            fp = [(r, context.reg_read(r)) for r in (*_FP_REGS, arm.UC_ARM_REG_FPSCR)]
            uc.mem_write(sp + 32, struct.pack("<17II", *(v for _, v in fp), 0))
            uc.reg_write_batch(fp)
        self._return_write.write([*words[:6], words[7], control | 4 if extended else control & ~4,
                                  sp + size + (4 if words[7] & 1 << 9 else 0)])  # fmt: skip
        self._c.depth -= 1

    # -- the host's calls --------------------------------------------------------------------------------------

    def call(self, function: int, *args: int | bytes) -> int:
        """Call ``function`` in the image (at an idle point: the main loop, outside the runtime) with up to four
        arguments (bytes are copied onto the image's stack and passed by address); its r0. The registers are put
        back afterwards, as if the main loop had not been interrupted."""
        if not self.idle:
            raise RuntimeError("the image is busy (not at its idle point): it cannot be called into now")
        uc = self.uc
        saved = uc.context_save()
        sp = int(uc.reg_read(arm.UC_ARM_REG_SP))
        values = []
        for arg in args:
            if isinstance(arg, bytes):
                sp = (sp - len(arg)) & ~7
                uc.mem_write(sp, arg)
                values.append(sp)
            else:
                values.append(arg)
        uc.reg_write(arm.UC_ARM_REG_SP, sp & ~7)
        for r, v in zip([arm.UC_ARM_REG_R0, arm.UC_ARM_REG_R1, arm.UC_ARM_REG_R2, arm.UC_ARM_REG_R3], values,
                        strict=False):  # fmt: skip
            uc.reg_write(r, v)
        uc.reg_write(arm.UC_ARM_REG_LR, CALL_RETURN | 1)
        c = self._c
        c.calling, c.reason, self._fault = 1, REASON_NONE, ""
        c.run_until = c.cycles + CALL_BUDGET_MS * CYCLES_PER_MS
        try:
            emu_start(uc, function | 1)
            if c.reason == REASON_BUDGET:
                raise FirmwareFault(f"a call to {function:#010x} did not return within {CALL_BUDGET_MS} ms of the "
                                    f"board's time (at {self.pc:#010x})")  # fmt: skip
            if self.pc != CALL_RETURN or c.reason:
                raise FirmwareFault(f"a call to {function:#010x} stopped at {self.pc:#010x} "
                                    f"({self._fault or self._reset_cause or c.reason})")  # fmt: skip
            return int(uc.reg_read(arm.UC_ARM_REG_R0))
        except UcError as exc:
            raise FirmwareFault(f"{exc} at {self.pc:#010x} in a call to {function:#010x}") from None
        finally:
            c.calling, c.run_until = 0, NEVER
            uc.context_restore(saved)

    def read_word(self, address: int) -> int:
        return struct.unpack("<I", self.uc.mem_read(address, 4))[0]

    def stack_used(self) -> int:
        """The stack's high-water mark in bytes: how far below its top the boot-time paint was overwritten."""
        paint = struct.pack("<I", PAINT)
        memory = bytes(self.uc.mem_read(self.stack_bottom, self.stack_top - self.stack_bottom))
        for at in range(0, len(memory), 4):
            if memory[at : at + 4] != paint:
                return len(memory) - at
        return 0
