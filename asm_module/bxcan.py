"""A model of the STM32F4's bxCAN controller (CAN1, RM0090 chapter 32) as the board image sees it through its
registers: three transmit mailboxes, receive FIFO 0 and the 28 acceptance filter banks in every mode (mask or
list, one 32-bit or two 16-bit filters per bank).

The emulator (asm_module/emulator.py) maps these registers into the image's address space; frames the firmware
queues in a mailbox go out at once through ``transmit`` (a real controller takes about 130 us per frame at 1 Mbit/s;
nothing here waits on arbitration), and frames from the bus that pass the acceptance filters wait on ``wire`` until
the FIFO has room (asked again as they enter it) — so the filters the port configured decide what reaches the
firmware, as on the board. Not modelled: FIFO 1 (frames its filters send there are counted and dropped), overruns
(a frame waits on the wire instead), error counters, time stamps, bit timing (BTR is kept, not interpreted), CAN2.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable

BANKS = 28
FIFO_DEPTH = 3
MATCHES_KEPT = 4096
"""Identifiers whose filter answer a controller remembers (a bus of random identifiers must not grow it)."""
MCR, MSR, TSR, RF0R, RF1R, IER, ESR, BTR = range(0, 0x20, 4)
MAILBOXES = 0x180  # TIxR, TDTxR, TDLxR, TDHxR, 0x10 apart
FIFO0 = 0x1B0  # RI0R, RDT0R, RDL0R, RDH0R
FMR, FM1R, FS1R, FFA1R, FA1R = 0x200, 0x204, 0x20C, 0x214, 0x21C
BANK_REGISTERS = 0x240  # FiR1, FiR2, 8 bytes a bank

Frame = tuple[int, bool, bytes]
"""(identifier, extended, data): a classic frame as it crosses the model's edges."""


def register_image(can_id: int, extended: bool, remote: bool = False) -> int:
    """The frame as a 32-bit filter register holds it (STID, EXID, IDE, RTR)."""
    return (can_id << 3 | 4 if extended else can_id << 21) | int(remote) << 1


def register_image16(can_id: int, extended: bool, remote: bool = False) -> int:
    """The frame as a 16-bit filter holds it (STID, RTR, IDE, EXID[17:15])."""
    if extended:
        return (can_id >> 18) << 5 | int(remote) << 4 | 1 << 3 | (can_id >> 15) & 7
    return can_id << 5 | int(remote) << 4


class BxCan:
    """CAN1's registers, ``transmit`` called with each frame the firmware sends."""

    def __init__(self, transmit: Callable[[int, bool, bytes], None]) -> None:
        self.transmit = transmit
        self.mcr, self.msr, self.btr, self.ier = 0x00010002, 0x00000C02, 0x01230000, 0
        self.tsr_done = 0  # RQCP/TXOK bits of completed requests
        self.mailboxes = [[0, 0, 0, 0] for _ in range(3)]
        self.fifo: deque[tuple[Frame, int]] = deque()  # (frame, filter match index)
        self.wire: deque[Frame] = deque()  # frames from the bus, not yet offered to the filters
        self.lock = threading.Lock()  # the wire is filled by the bus's thread
        self.fmr, self.fm1r, self.fs1r, self.ffa1r, self.fa1r = 0x2A1C0E01, 0, 0, 0, 0
        self.banks = [[0, 0] for _ in range(BANKS)]
        self._matches: dict[tuple[int, bool], tuple[int, int] | None] = {}
        """match()'s answers since the filters last changed: on a busy bus every frame is asked about by every
        board (a firmware update: ~4,700 frames a module, all seen by all), and the 28 banks cost ~20 µs a frame."""
        self.sent = self.filtered = self.to_fifo1 = self.unsent = 0

    # -- the bus side -----------------------------------------------------------------------------------------

    def deliver(self, can_id: int, extended: bool, data: bytes) -> bool:
        """A frame seen on the bus (any thread), kept if the acceptance filters pass it (or are being set up: they
        are asked again as it enters the FIFO), so a frame for other nodes never wakes the emulated core — as the
        controller's filters keep it from the CPU. A CAN FD frame is not one the controller can receive. Whether
        it was kept."""
        if len(data) > 8:
            return False
        with self.lock:
            if self.fmr & 1 or self.match(can_id, extended) is not None:
                self.wire.append((can_id, extended, data))
                return True
            self.filtered += 1
            return False

    def pending(self) -> bool:
        """Frames wait on the wire or in the FIFO."""
        return bool(self.wire or self.fifo)

    def _refill(self) -> None:
        """Move frames from the wire into FIFO 0 while it has room, through the acceptance filters (none pass while
        the controller sleeps or it or its filters are being initialised)."""
        if self.msr & 3 or self.fmr & 1:
            return
        with self.lock:
            while self.wire and len(self.fifo) < FIFO_DEPTH:
                frame = self.wire.popleft()
                match = self.match(frame[0], frame[1])
                if match is None:
                    self.filtered += 1
                elif match[0] == 1:
                    self.to_fifo1 += 1
                else:
                    self.fifo.append((frame, match[1]))

    # -- the filters ------------------------------------------------------------------------------------------

    def match(self, can_id: int, extended: bool) -> tuple[int, int] | None:
        """(FIFO, filter match index) of the filter that passes the frame, by RM0090's priority (32-bit before
        16-bit, an identifier list before a mask, then the lower filter number); None if no active filter does.
        Remembered per identifier until a filter register is written (at most MATCHES_KEPT identifiers)."""
        key = (can_id, extended)
        try:
            return self._matches[key]
        except KeyError:
            pass
        answer = self._match(can_id, extended)
        if len(self._matches) >= MATCHES_KEPT:
            self._matches.clear()
        self._matches[key] = answer
        return answer

    def _match(self, can_id: int, extended: bool) -> tuple[int, int] | None:
        image32, image16 = register_image(can_id, extended), register_image16(can_id, extended)
        numbers = [0, 0]
        best: tuple[tuple[int, int, int], int, int] | None = None
        for bank in range(BANKS):
            fifo, listed, wide = self.ffa1r >> bank & 1, self.fm1r >> bank & 1, self.fs1r >> bank & 1
            first = numbers[fifo]
            numbers[fifo] += (2 if listed else 1) if wide else (4 if listed else 2)
            if not self.fa1r >> bank & 1:
                continue
            r1, r2 = self.banks[bank]
            hit: int | None = None
            if wide and listed:
                hit = 0 if image32 == r1 else 1 if image32 == r2 else None
            elif wide:
                hit = 0 if (image32 ^ r1) & r2 == 0 else None
            elif listed:
                ids = [r1 & 0xFFFF, r1 >> 16, r2 & 0xFFFF, r2 >> 16]
                hit = ids.index(image16) if image16 in ids else None
            else:
                pairs = [(r1 & 0xFFFF, r1 >> 16), (r2 & 0xFFFF, r2 >> 16)]
                hit = next((k for k, (i, m) in enumerate(pairs) if (image16 ^ i) & m == 0), None)
            if hit is not None:
                key = (1 - wide, 1 - listed, first + hit)
                if best is None or key < best[0]:
                    best = (key, fifo, first + hit)
        return None if best is None else (best[1], best[2])

    # -- the registers ----------------------------------------------------------------------------------------

    def read(self, offset: int) -> int:
        """The register at ``offset`` from CAN1's base, as the firmware reads it."""
        if offset == MCR:
            return self.mcr
        if offset == MSR:
            return self.msr
        if offset == TSR:
            return 0x1C000000 | self.tsr_done  # every mailbox empty (sent at once), the next is mailbox 0
        if offset == RF0R:
            self._refill()
            return len(self.fifo) | (len(self.fifo) == FIFO_DEPTH) << 3
        if offset in (IER, BTR):
            return self.ier if offset == IER else self.btr
        if MAILBOXES <= offset < FIFO0:
            box, word = divmod(offset - MAILBOXES, 0x10)
            return self.mailboxes[box][word // 4] & ~1  # TXRQ reads 0: the request was served
        if FIFO0 <= offset < FIFO0 + 0x10:
            if not self.fifo:
                return 0
            (can_id, extended, data), index = self.fifo[0]
            padded = data.ljust(8, b"\0")
            return [register_image(can_id, extended), len(data) | index << 8, int.from_bytes(padded[:4], "little"),
                    int.from_bytes(padded[4:], "little")][(offset - FIFO0) // 4]  # fmt: skip
        return self._read_filters(offset)

    def _read_filters(self, offset: int) -> int:
        registers = {FMR: self.fmr, FM1R: self.fm1r, FS1R: self.fs1r, FFA1R: self.ffa1r, FA1R: self.fa1r}
        if offset in registers:
            return registers[offset]
        if BANK_REGISTERS <= offset < BANK_REGISTERS + 8 * BANKS:
            bank, word = divmod(offset - BANK_REGISTERS, 8)
            return self.banks[bank][word // 4]
        return 0

    def write(self, offset: int, value: int) -> None:
        """The firmware writes ``value`` to the register at ``offset``."""
        if offset == MCR:
            self.mcr = value
            inrq, sleep = value & 1, value >> 1 & 1
            self.msr = (self.msr & ~3) | inrq | (sleep and not inrq) << 1
        elif offset == TSR:
            self.tsr_done &= ~value  # RQCPx and the bits with it: write 1 to clear
        elif offset == RF0R:
            if value & 1 << 5 and self.fifo:  # RFOM0: release the output mailbox
                self.fifo.popleft()
                self._refill()
        elif offset in (IER, BTR):
            if offset == IER:
                self.ier = value
            elif self.msr & 1:  # BTR is writable in initialisation mode only
                self.btr = value
        elif MAILBOXES <= offset < FIFO0:
            box, word = divmod(offset - MAILBOXES, 0x10)
            self.mailboxes[box][word // 4] = value
            if word == 0 and value & 1:
                self._send(box)
        else:
            self._write_filters(offset, value)

    def _write_filters(self, offset: int, value: int) -> None:
        with self.lock:  # the bus's thread asks match() meanwhile: no answer of the old filters is kept
            self._matches.clear()
            self._set_filter(offset, value)

    def _set_filter(self, offset: int, value: int) -> None:
        if offset == FMR:
            self.fmr = value
            return
        if BANK_REGISTERS <= offset < BANK_REGISTERS + 8 * BANKS:
            bank, word = divmod(offset - BANK_REGISTERS, 8)
            if self.fmr & 1 or not self.fa1r >> bank & 1:  # an active bank's registers are locked outside FINIT
                self.banks[bank][word // 4] = value
        elif offset == FA1R:
            self.fa1r = value & (1 << BANKS) - 1
        elif not self.fmr & 1:
            return  # modes, scales and FIFO assignments change in filter initialisation mode only
        elif offset == FM1R:
            self.fm1r = value & (1 << BANKS) - 1
        elif offset == FS1R:
            self.fs1r = value & (1 << BANKS) - 1
        elif offset == FFA1R:
            self.ffa1r = value & (1 << BANKS) - 1

    def _send(self, box: int) -> None:
        tir, tdtr, tdlr, tdhr = self.mailboxes[box]
        if self.msr & 3:  # initialisation or sleep mode: nothing leaves the controller
            self.unsent += 1
            return
        extended = bool(tir & 4)
        can_id = tir >> 3 if extended else tir >> 21
        dlc = min(tdtr & 0xF, 8)
        data = (tdlr | tdhr << 32).to_bytes(8, "little")[:dlc]
        self.sent += 1
        self.tsr_done |= 3 << (8 * box)  # RQCP, TXOK
        self.transmit(can_id, extended, data)
