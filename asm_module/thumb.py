"""Thumb-2 code as the emulator (asm_module/emulator.py) needs to judge it, and Unicorn's batched register access."""

from __future__ import annotations

import ctypes

from unicorn.unicorn import Uc, UcError


def local_16bit(halfword: int, address: int, start: int, end: int) -> bool:
    """A 16-bit Thumb instruction at ``address`` that stays inside [start, end): not the first half of a 32-bit
    one, not BLX/BX to a register other than LR, and a branch only to inside."""
    if halfword >> 11 in (0b11101, 0b11110, 0b11111):
        return False  # a 32-bit instruction (every FP one is): not proven local
    if halfword & 0xFF00 == 0x4700:  # BX/BLX Rm
        return halfword == 0x4770  # BX LR: the return
    if halfword & 0xFF87 == 0x4687:  # MOV PC, Rm: a jump anywhere
        return False
    if halfword & 0xF500 == 0xB100:  # CBZ/CBNZ, forward
        target = address + 4 + ((halfword >> 9 & 1) << 6 | (halfword >> 3 & 0x1F) << 1)
        return start <= target < end
    if halfword & 0xF800 == 0xE000:  # B, 11-bit offset
        offset = (halfword & 0x7FF) << 1
        target = address + 4 + (offset - 0x1000 if offset & 0x800 else offset)
        return start <= target < end
    if halfword & 0xF000 == 0xD000 and halfword & 0x0F00 not in (0x0E00, 0x0F00):  # B<cond>, 8-bit offset
        offset = (halfword & 0xFF) << 1
        target = address + 4 + (offset - 0x200 if offset & 0x100 else offset)
        return start <= target < end
    return True


class Batch:
    """32-bit registers read or written together (uc_reg_read_batch), their buffers made once: the binding's
    reg_read_batch looks up each register's type on every call, most of what an interrupt cost here."""

    def __init__(self, uc: Uc, registers: list[int]) -> None:
        self.uc, n = uc, len(registers)
        self.ids = (ctypes.c_int * n)(*registers)
        self.values = (ctypes.c_uint32 * n)()
        base = ctypes.addressof(self.values)
        self.pointers = (ctypes.c_void_p * n)(*(base + 4 * k for k in range(n)))
        self.count = ctypes.c_int(n)

    def read(self) -> list[int]:
        status = self.uc._do_reg_read_batch(self.ids, self.pointers, self.count)
        if status:
            raise UcError(status)
        return list(self.values)

    def write(self, values: list[int]) -> None:
        self.values[:] = [v & 0xFFFFFFFF for v in values]
        status = self.uc._do_reg_write_batch(self.ids, self.pointers, self.count)
        if status:
            raise UcError(status)
