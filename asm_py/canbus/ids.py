"""The 29-bit CAN identifier of ASM frames (docs/protocol.md, "CAN"), in the spirit of MDCN.

    bit 28..26  priority     0 = most urgent (a lower identifier wins arbitration)
    bit 25..24  destination  0 node, 1 group, 2 broadcast (every node), 3 system (heartbeat, e-stop)
    bit 23..16  destination  node ID 1-254, group ID 0-255, 0 for broadcast, a system code for system frames
    bit 15..8   source       node ID 1-254 of the sender
    bit  7..6   frame        0 single (a whole message), 1 first, 2 middle, 3 last fragment
    bit  5..0   counter      fragment counter mod 64 (0 in single frames, so their identifiers are stable)

All fragmentation bookkeeping is in the identifier, so every data byte of a middle or last frame is message payload;
only the first frame of a fragmented message spends 4 bytes on its total length and a CRC-16.
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple

MIN_NODE_ID = 1
MAX_NODE_ID = 254
MAX_PRIORITY = 7


class Dest(IntEnum):
    NODE = 0
    GROUP = 1
    BROADCAST = 2
    SYSTEM = 3


class FrameType(IntEnum):
    SINGLE = 0
    FIRST = 1
    MIDDLE = 2
    LAST = 3


class SystemCode(IntEnum):
    """Destination byte of system frames: what the frame is, not where it goes (system frames reach everyone)."""

    ESTOP = 0x00
    """Emergency stop: every node acts at once. Data: optional UTF-8 reason."""
    HEARTBEAT = 0x01
    """I am alive. Data: the node's name (UTF-8), so that names resolve to IDs on the bus."""
    LEAVE = 0x02
    """I am going offline (sent on an orderly close): others report the node lost at once."""


class Priority(IntEnum):
    """The priorities ASM uses; 8 levels exist and any may be configured."""

    ESTOP = 0
    REPLY = 2
    REQUEST = 3
    PUBLICATION = 4
    BULK = 5
    """Fragmented messages: a long transfer never delays a short control message."""
    HEARTBEAT = 6
    BULK_PUBLICATION = 7
    """Fragmented publications: apart from fragmented requests, so that a node that does not watch publications
    (a module) filters them out in hardware like single-frame ones, instead of receiving every node's."""


def frame_priority(priority: int, frames: int) -> int:
    """The priority a message's frames go out at: a fragmented message at BULK at best (a long transfer never
    delays a short control message), a fragmented publication at BULK_PUBLICATION, and an e-stop always at its
    own."""
    if frames > 1 and priority == Priority.PUBLICATION:
        return Priority.BULK_PUBLICATION
    if frames > 1 and priority != Priority.ESTOP:
        return max(priority, Priority.BULK)
    return priority


class CanId(NamedTuple):
    priority: int
    dest_kind: int
    dest: int
    source: int
    frame: int
    counter: int = 0

    def pack(self) -> int:
        """The 29-bit identifier; ValueError when a field is out of range."""
        if not (0 <= self.priority <= MAX_PRIORITY and 0 <= self.dest_kind <= 3 and 0 <= self.dest <= 0xFF
                and 0 <= self.source <= 0xFF and 0 <= self.frame <= 3 and 0 <= self.counter <= 0x3F):  # fmt: skip
            raise ValueError(f"CAN identifier field out of range: {self}")
        return (self.priority << 26 | self.dest_kind << 24 | self.dest << 16 | self.source << 8
                | self.frame << 6 | self.counter)  # fmt: skip

    @classmethod
    def unpack(cls, arbitration_id: int) -> CanId:
        return cls(
            (arbitration_id >> 26) & 0x7,
            (arbitration_id >> 24) & 0x3,
            (arbitration_id >> 16) & 0xFF,
            (arbitration_id >> 8) & 0xFF,
            (arbitration_id >> 6) & 0x3,
            arbitration_id & 0x3F,
        )


DEST_MASK = 0x3 << 24 | 0xFF << 16
"""Mask of the destination fields: acceptance filters select frames by it."""


def dest_filter(dest_kind: int, dest: int) -> dict[str, int | bool]:
    """A python-can ``can_filters`` entry accepting every frame to (dest_kind, dest)."""
    return {"can_id": dest_kind << 24 | dest << 16, "can_mask": DEST_MASK, "extended": True}


def priority_filter(priority: int, dest_kind: int, dest: int) -> dict[str, int | bool]:
    """A python-can ``can_filters`` entry accepting frames of one priority to (dest_kind, dest)."""
    return {"can_id": priority << 26 | dest_kind << 24 | dest << 16, "can_mask": 0x7 << 26 | DEST_MASK,
            "extended": True}  # fmt: skip


def source_filter(priority: int, dest_kind: int, dest: int, source: int) -> dict[str, int | bool]:
    """A python-can ``can_filters`` entry accepting frames of one priority to (dest_kind, dest) from one node (a
    neighbour's publications, for a module whose program waits on them)."""
    return {"can_id": priority << 26 | dest_kind << 24 | dest << 16 | source << 8,
            "can_mask": 0x7 << 26 | DEST_MASK | 0xFF << 8, "extended": True}  # fmt: skip


def check_node_id(node_id: int) -> int:
    if not isinstance(node_id, int) or not MIN_NODE_ID <= node_id <= MAX_NODE_ID:
        raise ValueError(f"CAN node IDs are {MIN_NODE_ID}..{MAX_NODE_ID}, not {node_id!r}")
    return node_id
