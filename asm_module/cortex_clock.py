"""The emulated core's clock as the emulator shares it with its C block hook (asm_module/cortex_clock.c): the cycle
count, SysTick's state, the watchdog's deadline and why the core last stopped, in one ctypes struct that the hook
updates for every block the image executes and the emulator reads and writes between (and inside) its runs.

Why C: the hook runs for every translated block — dozens per millisecond of an idle board, hundreds for each CAN
frame it receives — and as a Python callback it cost two to three microseconds and a GIL hand-over each, most of
what eight boards in one process spent (docs/benchmarks.md, "Real modules: firmware update over the bus"). For the
callbacks left (peripheral registers, flash stores) :func:`emu_start` keeps the interpreter lock over a run.
"""

from __future__ import annotations

import ctypes
import threading

from unicorn import UC_HOOK_BLOCK
from unicorn import arm_const as arm
from unicorn.unicorn import Uc, UcError
from unicorn.unicorn_py3.unicorn import uclib

from .firmware_build import build_cortex_clock

NEVER = (1 << 64) - 1
"""``watchdog_at`` of a watchdog not started."""
REASON_NONE, REASON_SYSTICK, REASON_WATCHDOG, REASON_BUDGET = 0, 1, 2, 3
"""Why the hook stopped the core (REASON_BUDGET: the run reached ``run_until``)."""
REASON_IDLE, REASON_RESET, REASON_FAULT, REASON_STOPPED, REASON_RETURN = 4, 5, 6, 7, 8
"""Why a run stopped, beyond the hook's own (asm_module/emulator.py): the main loop idles, the image asked for a
reset, it reached Default_Handler, Unicorn stopped for a reason of its own, a handler returned (EXC_RETURN)."""
CACHE_SLOTS = 4096


class _Block(ctypes.Structure):
    _fields_ = [("address", ctypes.c_uint64), ("size", ctypes.c_uint32), ("count", ctypes.c_uint32)]


class CoreClock(ctypes.Structure):
    """struct core_clock of cortex_clock.c, field for field."""

    _fields_ = [
        ("cycles", ctypes.c_uint64),
        ("systick_next", ctypes.c_uint64),
        ("watchdog_at", ctypes.c_uint64),
        ("run_until", ctypes.c_uint64),
        ("csr", ctypes.c_uint32),
        ("rvr", ctypes.c_uint32),
        ("countflag", ctypes.c_uint32),
        ("pending", ctypes.c_uint32),
        ("depth", ctypes.c_uint32),
        ("calling", ctypes.c_uint32),
        ("reason", ctypes.c_uint32),
        ("xpsr", ctypes.c_int32),
        ("reg_read", ctypes.c_void_p),
        ("emu_stop", ctypes.c_void_p),
        ("mem_read", ctypes.c_void_p),
        ("cache", _Block * CACHE_SLOTS),
    ]

    cycles: int
    systick_next: int
    watchdog_at: int
    run_until: int
    csr: int
    rvr: int
    countflag: int
    pending: int
    depth: int
    calling: int
    reason: int


_lock = threading.Lock()
_library: ctypes.CDLL | None = None
_held: ctypes.PyDLL | None = None


def _hooks() -> ctypes.CDLL:
    global _library
    with _lock:
        if _library is None:
            library = ctypes.CDLL(str(build_cortex_clock()))
            library.asm_cortex_count_down.argtypes = [ctypes.POINTER(CoreClock)]
            library.asm_cortex_count_down.restype = None
            _library = library
        return _library


def emu_start(uc: Uc, begin: int) -> None:
    """``uc.emu_start(begin, 0)`` with the interpreter lock kept while the core runs (Unicorn through a PyDLL, as
    asm_module/c_module.py calls the host library): the binding's CDLL releases it for the call, and every Python
    callback of a run (a peripheral register, the flash) then waited to take it back — behind every other thread
    of the process, up to a switch interval (5 ms) each on a loaded machine. A long run still lets other threads in
    at its callbacks' switch points."""
    global _held
    with _lock:
        if _held is None:
            held = ctypes.PyDLL(uclib._name)
            held.uc_emu_start.argtypes = [ctypes.c_void_p, ctypes.c_uint64, ctypes.c_uint64, ctypes.c_uint64,
                                          ctypes.c_size_t]  # fmt: skip
            held.uc_emu_start.restype = ctypes.c_int
            _held = held
    uc._hook_exception = None  # what the binding's emu_start does: a hook's exception is raised after the run
    status = _held.uc_emu_start(uc._uch, begin, 0, 0, 0)
    if status:
        raise UcError(status)
    if uc._hook_exception is not None:
        raise uc._hook_exception


def _address(function: object) -> int:
    address = ctypes.cast(function, ctypes.c_void_p).value  # pyright: ignore[reportArgumentType]
    assert address is not None
    return address


class Clock:
    """One core's clock, its block hook added to ``uc`` for each (begin, end) range of code."""

    def __init__(self, uc: Uc, ranges: list[tuple[int, int]]) -> None:
        library = _hooks()
        self.state = state = CoreClock()
        state.watchdog_at = NEVER
        state.run_until = NEVER
        state.xpsr = arm.UC_ARM_REG_XPSR
        state.reg_read, state.emu_stop = _address(uclib.uc_reg_read), _address(uclib.uc_emu_stop)
        state.mem_read = _address(uclib.uc_mem_read)
        self._pointer = ctypes.pointer(state)
        self._count_down = library.asm_cortex_count_down
        hook = _address(library.asm_cortex_block)
        for begin, end in ranges:
            handle = ctypes.c_size_t()
            status = uclib.uc_hook_add(uc._uch, ctypes.byref(handle), UC_HOOK_BLOCK, hook, ctypes.addressof(state),
                                       begin, end)  # fmt: skip
            if status:
                raise UcError(status)

    def count_down(self) -> None:
        """SysTick reached zero by now (cycles): COUNTFLAG, and the interrupt pending if TICKINT."""
        self._count_down(self._pointer)
