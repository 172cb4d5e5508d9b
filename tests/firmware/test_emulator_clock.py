"""The emulator's clock and flash, as the firmware update made them fast (docs/benchmarks.md, 2026-11-27): the
per-block hook in C (asm_module/cortex_clock.c) counts every instruction and stops the core where SysTick's
interrupt or the watchdog's reset is due; the flash mapped read-only into the core still programs only through the
flash interface's rules; the port's SysTick interrupts every 20 ms and its clock (now_ms) is exact to the
millisecond between, a period on while the interrupt is pending."""

from __future__ import annotations

import shutil
import struct
import time
from collections.abc import Callable

import pytest
from unicorn import UC_ARCH_ARM, UC_MODE_MCLASS, UC_MODE_THUMB
from unicorn import arm_const as arm
from unicorn.unicorn import Uc

from asm_module.cortex_clock import REASON_BUDGET, REASON_SYSTICK, REASON_WATCHDOG, Clock

needs_arm_gcc = pytest.mark.skipif(
    shutil.which("arm-none-eabi-gcc") is None, reason="the board image needs arm-none-eabi-gcc (make test installs it)"
)
CODE = 0x20000000
# movs r0,#1; movw r1,#2 (32-bit); adds r0,r0,r1; b.n next  |  cmp r0,#3; it eq; addeq r0,#1; nop; b.n next  |  nop
BLOCKS = bytes.fromhex("0120 40f20201 4018 ffe7 0328 08bf 0130 00bf ffe7 00bf")
INSTRUCTIONS = 10
SECOND_BLOCK = CODE + 0x0A


def _core() -> tuple[Uc, Clock]:
    uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
    uc.mem_map(CODE, 0x1000)
    uc.mem_write(CODE, BLOCKS)
    return uc, Clock(uc, [(CODE, CODE + 0xFFF)])


def test_the_clock_counts_every_instruction_16_and_32_bit_across_blocks() -> None:
    uc, clock = _core()
    uc.emu_start(CODE | 1, CODE + len(BLOCKS))
    assert clock.state.cycles == INSTRUCTIONS and clock.state.reason == 0
    assert int(uc.reg_read(arm.UC_ARM_REG_R0)) == 4, "the code ran (1 + 2, then 3 + 1 in the IT block)"
    uc.emu_start(CODE | 1, CODE + len(BLOCKS))
    assert clock.state.cycles == 2 * INSTRUCTIONS, "counted again from the blocks kept"


def test_the_clock_stops_the_core_where_systick_and_the_watchdog_are_due() -> None:
    uc, clock = _core()
    state = clock.state
    state.csr, state.rvr, state.systick_next = 3, 999, 3  # enabled, interrupting, reaching zero in the first block
    uc.emu_start(CODE | 1, CODE + len(BLOCKS))
    assert state.reason == REASON_SYSTICK and int(uc.reg_read(arm.UC_ARM_REG_PC)) == CODE
    assert state.countflag == 1 and state.pending == 0 and state.systick_next == 3 + 1000
    assert state.cycles == 0, "stopped before the block during which it comes due: the block has not run"
    state.reason, state.depth = 0, 1  # inside a handler: a SysTick due again stays pending
    state.systick_next = 5
    uc.emu_start(CODE | 1, CODE + len(BLOCKS))
    assert state.reason == 0 and state.pending == 1 and state.cycles == INSTRUCTIONS
    assert int(uc.reg_read(arm.UC_ARM_REG_R0)) == 4
    uc, clock = _core()
    clock.state.watchdog_at = 6
    uc.emu_start(CODE | 1, CODE + len(BLOCKS))
    assert clock.state.reason == REASON_WATCHDOG and int(uc.reg_read(arm.UC_ARM_REG_PC)) == SECOND_BLOCK
    assert clock.state.cycles == 4, "reset as the block that runs out the watchdog begins"


@pytest.mark.realtime  # counts another thread's wakes on the wall clock: beside four workers it counted 4 (> 3)
def test_a_run_keeps_the_interpreter_lock_so_no_other_thread_cuts_in_between_its_callbacks() -> None:
    """cortex_clock.emu_start holds the GIL over a run (the binding's emu_start releases it): a thread ready to run
    cannot while a core runs a loop of twenty million instructions (the binding's call lets it)."""
    import threading

    from asm_module.cortex_clock import emu_start

    # movw r0,#0x9680; movt r0,#0x98 (10,000,000); l: subs r0,#1; bne l; nop
    loop = bytes.fromhex("49f28060 c0f29800 0138 fdd1 00bf")
    uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
    uc.mem_map(CODE, 0x1000)
    uc.mem_write(CODE, loop)
    uc.ctl_exits_enabled(True)
    uc.ctl_set_exits([CODE + len(loop) - 2])
    clock = Clock(uc, [(CODE, CODE + 0xFFF)])
    counted, stop = [0], threading.Event()

    def other() -> None:  # counts while it can run: every half millisecond
        while not stop.is_set():
            counted[0] += 1
            time.sleep(0.0005)

    def counted_over(start: Callable[[], None]) -> int:
        before = counted[0]
        start()
        return counted[0] - before

    thread = threading.Thread(target=other)
    thread.start()
    try:
        held = counted_over(lambda: emu_start(uc, CODE | 1))
        assert clock.state.cycles == 2 + 2 * 10_000_000, "the loop ran: movw, movt, ten million subs and bne"
        released = max(counted_over(lambda: uc.emu_start(CODE | 1, 0)) for _ in range(3))
    finally:
        stop.set()
        thread.join(10)
    assert held <= 3 and released >= 10, (held, released)  # a few at the Python steps around the call, at most


def test_a_run_gives_the_host_its_turn_at_its_budget_whatever_the_image_does() -> None:
    """A run keeps the interpreter lock (above), so the hook ends it at ``run_until`` even with no interrupt or
    watchdog due: an image spinning for good must not hold the host's whole process (every other board, the bus,
    the e-stop's path). The block it stops before is counted when it runs."""
    from asm_module.cortex_clock import emu_start

    spin = bytes.fromhex("fee7")  # b.n . (a branch to itself: a spin no interrupt ends)
    uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
    uc.mem_map(CODE, 0x1000)
    uc.mem_write(CODE, spin)
    clock = Clock(uc, [(CODE, CODE + 0xFFF)])
    clock.state.run_until = 100_000
    began = time.monotonic()
    emu_start(uc, CODE | 1)
    assert clock.state.reason == REASON_BUDGET and clock.state.cycles == 100_000 - 1, "stopped before the block"
    assert time.monotonic() - began < 30.0
    clock.state.reason, clock.state.run_until = 0, 150_000
    emu_start(uc, int(uc.reg_read(arm.UC_ARM_REG_PC)) | 1)  # resumed where it stopped, for a budget more
    assert clock.state.reason == REASON_BUDGET and clock.state.cycles == 150_000 - 1


@needs_arm_gcc
def test_a_call_into_the_image_that_never_returns_is_a_fault_not_a_hung_process(core) -> None:
    from asm_module.emulator import CALL_BUDGET_MS, FirmwareFault

    spin = FREE_RAM + 0x40
    core.uc.mem_write(spin, bytes.fromhex("fee7"))  # b.n .
    with pytest.raises(FirmwareFault, match=f"did not return within {CALL_BUDGET_MS} ms"):
        core.call(spin)
    core.uc.mem_write(FREE_RAM, STORE_AND_READ)  # the board goes on: a call after it works
    assert core.call(FREE_RAM, 7, FREE_RAM + 0x100) == 7


# -- on the board image -----------------------------------------------------------------------------------------

FREE_RAM = 0x2000F000
"""Above the image (about 21 KiB from 0x20000000), below its data and stack (the upper 64 KiB): a function of the
test's own, called as the host calls into the image."""
STORE_AND_READ = bytes.fromhex("0860 0868 7047")  # str r0,[r1]; ldr r0,[r1]; bx lr
SLOT_B, SLOT_A = 0x08040000, 0x08020000


@pytest.fixture
def core():
    from asm_module.bxcan import BxCan
    from asm_module.emulated import board_image
    from asm_module.emulator import Cortex, Joint

    board = Cortex(board_image(), BxCan(lambda *_: None), Joint(lambda _: None, lambda: None, lambda: (0.0, False)))
    yield board
    board.release()


@needs_arm_gcc
def test_a_store_to_the_flash_programs_only_as_the_controller_allows_and_reads_back_at_once(core) -> None:
    from asm_module.flash import CR, KEYR, KEYS, PG, PGSERR, WRPERR

    core.uc.mem_write(FREE_RAM, STORE_AND_READ)
    flash = core.flash_interface
    assert core.call(FREE_RAM, 0x12345678, SLOT_B) == 0xFFFFFFFF, "locked: the store changes nothing"
    assert flash.sr & PGSERR
    for key in KEYS:
        flash.write_register(KEYR, key)
    flash.write_register(CR, 2 << 8 | PG)  # PSIZE x32, PG
    assert core.call(FREE_RAM, 0x12345678, SLOT_B) == 0x12345678, "programmed, and read back in the same run"
    assert core.call(FREE_RAM, 0xFFFF0000, SLOT_B) == 0x12340000, "programming only clears bits"
    assert core.settings.memory[SLOT_B - 0x08000000 :][:4] == struct.pack("<I", 0x12340000)
    running = core.settings.memory[SLOT_A - 0x08000000 :][:4]
    assert core.call(FREE_RAM, 0, SLOT_A) == struct.unpack("<I", running)[0], "the running slot is protected"
    assert flash.sr & WRPERR


@needs_arm_gcc
def test_the_port_interrupts_every_20_ms_and_its_clock_is_exact_to_the_millisecond_between(core) -> None:
    probe = struct.unpack("<15I", core.uc.mem_read(core.app.symbol("asm_probe"), 60))
    clock, milliseconds = probe[14], probe[9]
    for ms in [*range(0, 25), 39, 40, 41, 59, 60, 61, 99, 100, 101, 250]:
        core.run(ms)
        assert core.idle and core.systicks == ms // 20, ms
        assert core.read_word(milliseconds) == 20 * (ms // 20), "the count at the last interrupt"
        assert core.call(clock) == ms, "the count now"
    assert core.ticks.ticks == 250 // 20 + 1, "a control tick at every interrupt (and one at the start)"
    state = core.clock.state
    state.cycles = state.systick_next  # the counter reloads; its interrupt is pending, not yet taken
    core.clock.count_down()
    assert state.pending == 1
    assert core.call(clock) == 260, "a period on while the interrupt is pending (the count not yet added)"
