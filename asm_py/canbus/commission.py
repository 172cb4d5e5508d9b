"""Commissioning over CAN (docs/protocol.md §7, "Commissioning"): finding modules that have no node ID yet by their
unique serial, and numbering them.

A freshly flashed batch of identical modules cannot be told apart by anything but the serial each was made with (an
STM32's 96-bit unique ID). The tool finds them as CANopen's LSS fastscan does, by narrowing down on the serial, but a
byte per round trip rather than a bit: every module in the scan answers with its serial's byte at the scan position
*in the identifier* (source bits), so answers of modules with the same byte are the same frame (a real bus merges
them) and answers with different bytes are different identifiers (arbitration orders them): no collision either way.
The tool follows the first answer it gets; modules that answered another byte leave the scan and are found in a
later round. 12 round trips find a module, however many there are; a found module is muted, and the next round
finds the next one. A round that no module answers within ``window`` ends the search.

Every command is safe to repeat (a frame may be lost): a module answers a NARROW it already followed again, ASSIGN
and MUTE of the found module again.

- :class:`Commissionee` — a module's side, a pure state machine (asm_module.commissioning runs it for Python modules;
  firmware/src/commission.c is the same in C).
- :class:`Commissioner` — the tool's side on a python-can bus: :meth:`~Commissioner.discover`,
  :meth:`~Commissioner.assign`, :meth:`~Commissioner.number`, :func:`conflicts`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import can

from .._contract import SERIAL_BYTES, UNCONFIGURED, CommissionOp, CommissionReply, CommissionScope
from .ids import MAX_NODE_ID, MIN_NODE_ID, CanId, Dest, FrameType, Priority, SystemCode, dest_filter

__all__ = ["SERIAL_BYTES", "UNCONFIGURED", "Answer", "Commissionee", "Commissioner", "CommissionOp", "CommissionReply",
           "CommissionScope", "Found", "command_frame", "conflicts", "parse_reply", "reply_frame"]  # fmt: skip

TOOL_ID = 254
"""The node ID a commissioning tool sends from by default."""
POSITION_BITS = 4
POSITION_MASK = (1 << POSITION_BITS) - 1


def command_id(tool_id: int) -> int:
    """The identifier of a COMMISSION frame from ``tool_id``."""
    return CanId(Priority.REQUEST, Dest.SYSTEM, SystemCode.COMMISSION, tool_id, FrameType.SINGLE).pack()


def command_frame(op: int, *args: int, tool_id: int = TOOL_ID) -> can.Message:
    """A COMMISSION frame: opcode ``op`` then ``args`` (bytes)."""
    return can.Message(arbitration_id=command_id(tool_id), is_extended_id=True, data=bytes((op, *args)))


class Answer(NamedTuple):
    """A module's answer: its kind (CommissionReply), its value (a serial byte, a node ID) and, for a BYTE, the
    position of that byte in the serial (so that a late answer to an earlier command is never taken for this one)."""

    kind: int
    value: int
    position: int = 0


def reply_id(answer: Answer) -> int:
    """The identifier of a COMMISSIONED frame: the value in the source bits, the kind in counter bits 5-4 and the
    position in counter bits 3-0."""
    counter = answer.kind << POSITION_BITS | answer.position
    return CanId(Priority.REPLY, Dest.SYSTEM, SystemCode.COMMISSIONED, answer.value, FrameType.SINGLE, counter).pack()


def reply_frame(answer: Answer) -> can.Message:
    return can.Message(arbitration_id=reply_id(answer), is_extended_id=True, data=b"")


def parse_reply(frame: can.Message) -> Answer | None:
    """The answer a COMMISSIONED frame carries; None for any other frame."""
    if not frame.is_extended_id or frame.is_error_frame or frame.is_remote_frame:
        return None
    cid = CanId.unpack(frame.arbitration_id)
    if cid.dest_kind != Dest.SYSTEM or cid.dest != SystemCode.COMMISSIONED or cid.frame != FrameType.SINGLE:
        return None
    return Answer(cid.counter >> POSITION_BITS, cid.source, cid.counter & POSITION_MASK)


def is_command(frame: can.Message) -> bool:
    if not frame.is_extended_id or frame.is_error_frame or frame.is_remote_frame:
        return False
    cid = CanId.unpack(frame.arbitration_id)
    return cid.dest_kind == Dest.SYSTEM and cid.dest == SystemCode.COMMISSION and cid.frame == FrameType.SINGLE


COMMAND_FILTER = dest_filter(Dest.SYSTEM, SystemCode.COMMISSION)
"""A python-can filter passing the commands (what a module listens to)."""
REPLY_FILTER = dest_filter(Dest.SYSTEM, SystemCode.COMMISSIONED)
"""A python-can filter passing the answers (what a tool listens to)."""


def check_serial(serial: bytes) -> bytes:
    if len(serial) != SERIAL_BYTES:
        raise ValueError(f"a module's serial has {SERIAL_BYTES} bytes, not {len(serial)}")
    return bytes(serial)


def parse_serial(text: str) -> bytes:
    """A serial as people and files write it: 24 hex digits. ValueError naming what was given (its first 40
    characters: a hostile text can be as long as its file)."""
    try:
        serial = bytes.fromhex(text)
    except ValueError:
        serial = b""
    if len(serial) != SERIAL_BYTES:
        raise ValueError(f"a serial is {2 * SERIAL_BYTES} hex digits, not {text[:40]!r}")
    return serial


class Commissionee:
    """A module's side of commissioning: :meth:`command` takes a COMMISSION frame's data and says what to answer.

    ``store(node_id)`` is called on an ASSIGN before it is answered (the module writes its non-volatile memory; an
    exception there means no answer, so the tool tries again)."""

    def __init__(self, serial: bytes, node_id: int = UNCONFIGURED, store: Callable[[int], None] | None = None) -> None:
        self.serial = check_serial(serial)
        self.node_id = node_id
        self.store = store
        self.position: int | None = None
        """Where in the serial the scan has come (SERIAL_BYTES: this module is the one found); None: not in a scan."""
        self.muted = False

    def _in_scope(self, scope: int, node_id: int) -> bool:
        if scope == CommissionScope.UNCONFIGURED:
            return self.node_id == UNCONFIGURED
        if scope == CommissionScope.NODE_ID:
            return self.node_id == node_id
        return scope == CommissionScope.EVERY

    def _answer(self) -> Answer:
        position = self.position if self.position is not None else 0
        if position >= SERIAL_BYTES:
            return Answer(CommissionReply.FOUND, self.node_id)
        return Answer(CommissionReply.BYTE, self.serial[position], position)

    def command(self, data: bytes) -> Answer | None:
        """What to answer command ``data`` with, or None to stay silent."""
        if not data:
            return None
        op, args = data[0], data[1:]
        found = self.position == SERIAL_BYTES
        if op == CommissionOp.SCAN and args:
            in_scope = not self.muted and self._in_scope(args[0], args[1] if len(args) > 1 else -1)
            self.position = 0 if in_scope else None
            return self._answer() if in_scope else None
        if op == CommissionOp.NARROW and len(args) >= 2 and self.position is not None:
            at, byte = args[0], args[1]
            if at < SERIAL_BYTES and self.serial[at] == byte and self.position in (at, at + 1):
                self.position = at + 1  # moved on now, or already (a repeated command): the same answer
                return self._answer()
            self.position = None
            return None
        if op == CommissionOp.ASSIGN and args and found:
            node_id = args[0]
            if node_id != UNCONFIGURED and not MIN_NODE_ID <= node_id <= MAX_NODE_ID:
                return None
            if self.store is not None:
                self.store(node_id)
            self.node_id = node_id
            return Answer(CommissionReply.ASSIGNED, node_id)
        if op == CommissionOp.MUTE and found:
            self.muted = True
            return Answer(CommissionReply.MUTED, self.node_id)
        if op == CommissionOp.UNMUTE:
            self.muted = False
            self.position = None
        return None


@dataclass(frozen=True)
class Found:
    """A module found on the bus: its serial and the node ID it has (0: none)."""

    serial: bytes
    node_id: int

    @property
    def serial_hex(self) -> str:
        return self.serial.hex()


def conflicts(roster: Iterable[Found]) -> dict[int, list[bytes]]:
    """The node IDs that more than one module of ``roster`` has, with their serials."""
    holders: dict[int, list[bytes]] = {}
    for found in roster:
        if found.node_id != UNCONFIGURED:
            holders.setdefault(found.node_id, []).append(found.serial)
    return {node_id: serials for node_id, serials in sorted(holders.items()) if len(serials) > 1}


class Commissioner:
    """The tool's side on ``bus`` (its filters are set to pass the answers only; the caller owns the bus).

    ``window``: how long a command waits for its first answer at least (a round that gets none concludes nobody is
    there); ``retries``: how often a command that got no answer is sent again. The wait follows the round trips
    measured (4 × their smoothed time, when that is longer than the window) and doubles at each repetition of a
    command (up to 2 s), as TCP's retransmission timer does (RFC 6298): a bus of slow modules (emulated boards on a
    busy machine) is waited for, a fast one is not."""

    def __init__(self, bus: can.BusABC, *, tool_id: int = TOOL_ID, window: float = 0.05, retries: int = 3) -> None:
        self.bus = bus
        self.tool_id = tool_id
        self.window = window
        self.retries = retries
        self.commands_sent = 0
        self.rtt: float | None = None
        """The smoothed round trip of a command and its first answer, seconds (None until one is measured)."""
        bus.set_filters([REPLY_FILTER])

    # -- one command and its answer ------------------------------------------------------------------------------

    def _drain(self) -> None:
        while self.bus.recv(timeout=0) is not None:
            pass

    def send(self, op: int, *args: int) -> None:
        self.bus.send(command_frame(op, *args, tool_id=self.tool_id), timeout=0.1)
        self.commands_sent += 1

    def _wait(self, kind: int, attempt: int, *, value: int | None = None, position: int = 0) -> Answer | None:
        """The first answer of ``kind`` (with ``value`` if given) at ``position`` within the wait of repetition
        ``attempt`` (0: the first sending) after now; any other answer is a late one to an earlier command."""
        began = time.monotonic()
        wait = max(self.window, 4 * self.rtt) if self.rtt is not None else self.window
        deadline = began + min(max(2.0, self.window), wait * 2**attempt)
        while (left := deadline - time.monotonic()) > 0:
            frame = self.bus.recv(timeout=left)
            reply = None if frame is None else parse_reply(frame)
            if (reply is not None and reply.kind == kind and reply.position == position
                    and (value is None or reply.value == value)):  # fmt: skip
                sample = time.monotonic() - began
                self.rtt = sample if self.rtt is None else 0.875 * self.rtt + 0.125 * sample
                return reply
        return None

    def ask(self, op: int, *args: int, kind: int, value: int | None = None, position: int = 0) -> Answer | None:
        """Send a command (again, up to ``retries`` times) until its answer comes; None if none did."""
        for attempt in range(1 + self.retries):
            self._drain()
            self.send(op, *args)
            reply = self._wait(kind, attempt, value=value, position=position)
            if reply is not None:
                return reply
        return None

    # -- what a tool does ----------------------------------------------------------------------------------------

    def _narrow(self, first: int) -> Found | None:
        """Follow the scan from serial byte ``first`` to one module (muted once found); None if the scan broke off
        (a module answered late or went away: the next round starts again)."""
        serial = [first]
        reply: Answer | None = None
        for position in range(SERIAL_BYTES):
            last = position == SERIAL_BYTES - 1
            kind = CommissionReply.FOUND if last else CommissionReply.BYTE
            reply = self.ask(CommissionOp.NARROW, position, serial[position], kind=kind,
                             position=0 if last else position + 1)  # fmt: skip
            if reply is None:
                return None
            if not last:
                serial.append(reply.value)
        found = Found(bytes(serial), reply.value if reply is not None else UNCONFIGURED)
        muted = self.ask(CommissionOp.MUTE, kind=CommissionReply.MUTED)
        return found if muted is not None else None

    def discover(self, scope: int = CommissionScope.EVERY, node_id: int = 0, *, limit: int = 1024) -> list[Found]:
        """Every module of ``scope`` on the bus, found one per round (at most ``limit`` rounds), in the order found;
        every module is unmuted again at the end."""
        found: dict[bytes, Found] = {}
        self.send(CommissionOp.UNMUTE)
        try:
            for _ in range(limit):
                first = self.ask(CommissionOp.SCAN, scope, node_id, kind=CommissionReply.BYTE)
                if first is None:
                    break
                module = self._narrow(first.value)
                if module is not None:
                    found[module.serial] = module
        finally:
            self.send(CommissionOp.UNMUTE)
        return list(found.values())

    def select(self, serial: bytes) -> int | None:
        """Make the module with ``serial`` the found one (every other leaves the scan): its node ID, or None if no
        module answered."""
        check_serial(serial)
        for attempt in range(1 + self.retries):
            self._drain()
            self.send(CommissionOp.UNMUTE)
            self.send(CommissionOp.SCAN, CommissionScope.EVERY, 0)
            for position, byte in enumerate(serial):  # answers on the way are not waited for
                self.send(CommissionOp.NARROW, position, byte)
            reply = self._wait(CommissionReply.FOUND, attempt)
            if reply is not None:
                return reply.value
        return None

    def assign(self, serial: bytes, node_id: int) -> None:
        """Give the module with ``serial`` node ID ``node_id`` (0: erase its ID); LookupError if it does not answer."""
        if node_id != UNCONFIGURED and not MIN_NODE_ID <= node_id <= MAX_NODE_ID:
            raise ValueError(f"node IDs are {MIN_NODE_ID}..{MAX_NODE_ID} (or {UNCONFIGURED} to erase), not {node_id}")
        for _ in range(1 + self.retries):
            if self.select(serial) is None:
                continue
            if self.ask(CommissionOp.ASSIGN, node_id, kind=CommissionReply.ASSIGNED, value=node_id) is not None:
                self.send(CommissionOp.UNMUTE)
                return
        raise LookupError(f"module {serial.hex()} did not answer")

    def number(self, *, first: int = MIN_NODE_ID, order: Sequence[bytes] | None = None) -> list[Found]:
        """Give every module without a node ID the next free one from ``first``, in ``order`` (serials; the modules
        it does not name follow in serial order) — the IDs other modules have are skipped. What was assigned.

        ValueError before anything is assigned if modules on the bus share an ID (:func:`conflicts`)."""
        roster = self.discover(CommissionScope.EVERY)
        clash = conflicts(roster)
        if clash:
            raise ValueError(describe_conflicts(clash))
        used = {module.node_id for module in roster}
        new = {module.serial for module in roster if module.node_id == UNCONFIGURED}
        ranked = [s for s in (order or ()) if s in new] + sorted(new - set(order or ()))
        assigned = []
        node_id = first
        for serial in ranked:
            while node_id in used:
                node_id += 1
            if node_id > MAX_NODE_ID:
                raise ValueError(f"no node ID is left for module {serial.hex()}")
            self.assign(serial, node_id)
            used.add(node_id)
            assigned.append(Found(serial, node_id))
        return assigned


def describe_conflicts(clash: dict[int, list[bytes]]) -> str:
    """One line per shared node ID, naming the serials that share it."""
    return "; ".join(f"node ID {node_id} is held by {len(serials)} modules: {', '.join(s.hex() for s in serials)}"
                     for node_id, serials in clash.items())  # fmt: skip
