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

from typing import TYPE_CHECKING, NamedTuple

from .._contract import (
    CAN_COUNTER_MASK,
    CAN_COUNTER_SHIFT,
    CAN_DEST_KIND_MASK,
    CAN_DEST_KIND_SHIFT,
    CAN_DEST_MASK,
    CAN_DEST_SHIFT,
    CAN_FRAME_MASK,
    CAN_FRAME_SHIFT,
    CAN_PRIORITY_MASK,
    CAN_PRIORITY_SHIFT,
    CAN_SOURCE_MASK,
    CAN_SOURCE_SHIFT,
    MAX_NODE_ID,
    MIN_NODE_ID,
    Dest,
    FrameType,
    Priority,
    SystemCode,
)

if TYPE_CHECKING:
    from can.typechecking import CanFilter

__all__ = ["DEST_MASK", "FIELDS", "MAX_NODE_ID", "MAX_PRIORITY", "MIN_NODE_ID", "CanId", "Dest", "FrameType",
           "Priority", "SystemCode", "check_node_id", "dest_filter", "frame_priority", "kind_filter", "priority_filter",
           "source_filter"]  # fmt: skip

MAX_PRIORITY = CAN_PRIORITY_MASK
_new_tuple = tuple.__new__


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
        if not (0 <= self.priority <= CAN_PRIORITY_MASK and 0 <= self.dest_kind <= CAN_DEST_KIND_MASK
                and 0 <= self.dest <= CAN_DEST_MASK and 0 <= self.source <= CAN_SOURCE_MASK
                and 0 <= self.frame <= CAN_FRAME_MASK and 0 <= self.counter <= CAN_COUNTER_MASK):  # fmt: skip
            raise ValueError(f"CAN identifier field out of range: {self}")
        return (self.priority << CAN_PRIORITY_SHIFT | self.dest_kind << CAN_DEST_KIND_SHIFT
                | self.dest << CAN_DEST_SHIFT | self.source << CAN_SOURCE_SHIFT | self.frame << CAN_FRAME_SHIFT
                | self.counter)  # fmt: skip

    @classmethod
    def unpack(cls, arbitration_id: int) -> CanId:
        a = arbitration_id  # every received frame comes through here: the fields spelled out, no generator, and
        # the tuple made directly (a NamedTuple's own __new__ is a Python function: twice the time)
        return _new_tuple(cls, ((a >> CAN_PRIORITY_SHIFT) & CAN_PRIORITY_MASK,
                                (a >> CAN_DEST_KIND_SHIFT) & CAN_DEST_KIND_MASK, (a >> CAN_DEST_SHIFT) & CAN_DEST_MASK,
                                (a >> CAN_SOURCE_SHIFT) & CAN_SOURCE_MASK, (a >> CAN_FRAME_SHIFT) & CAN_FRAME_MASK,
                                (a >> CAN_COUNTER_SHIFT) & CAN_COUNTER_MASK))  # fmt: skip


_FIELDS = ((CAN_PRIORITY_SHIFT, CAN_PRIORITY_MASK), (CAN_DEST_KIND_SHIFT, CAN_DEST_KIND_MASK),
           (CAN_DEST_SHIFT, CAN_DEST_MASK), (CAN_SOURCE_SHIFT, CAN_SOURCE_MASK), (CAN_FRAME_SHIFT, CAN_FRAME_MASK),
           (CAN_COUNTER_SHIFT, CAN_COUNTER_MASK))  # fmt: skip
"""(shift, mask) of each field of the identifier, in CanId's order."""
FIELDS = _FIELDS
_PRIORITY_BITS = CAN_PRIORITY_MASK << CAN_PRIORITY_SHIFT
DEST_MASK = CAN_DEST_KIND_MASK << CAN_DEST_KIND_SHIFT | CAN_DEST_MASK << CAN_DEST_SHIFT
"""Mask of the destination fields: acceptance filters select frames by it."""


def dest_filter(dest_kind: int, dest: int) -> CanFilter:
    """A python-can ``can_filters`` entry accepting every frame to (dest_kind, dest)."""
    can_id = dest_kind << CAN_DEST_KIND_SHIFT | dest << CAN_DEST_SHIFT
    return {"can_id": can_id, "can_mask": DEST_MASK, "extended": True}


def kind_filter(dest_kind: int) -> CanFilter:
    """A python-can ``can_filters`` entry accepting every frame of one destination kind (every system frame)."""
    return {"can_id": dest_kind << CAN_DEST_KIND_SHIFT, "can_mask": CAN_DEST_KIND_MASK << CAN_DEST_KIND_SHIFT,
            "extended": True}  # fmt: skip


def priority_filter(priority: int, dest_kind: int, dest: int) -> CanFilter:
    """A python-can ``can_filters`` entry accepting frames of one priority to (dest_kind, dest)."""
    return {"can_id": priority << CAN_PRIORITY_SHIFT | dest_kind << CAN_DEST_KIND_SHIFT | dest << CAN_DEST_SHIFT,
            "can_mask": _PRIORITY_BITS | DEST_MASK, "extended": True}  # fmt: skip


def source_filter(priority: int, dest_kind: int, dest: int, source: int) -> CanFilter:
    """A python-can ``can_filters`` entry accepting frames of one priority to (dest_kind, dest) from one node (a
    neighbour's publications, for a module whose program waits on them)."""
    return {"can_id": priority << CAN_PRIORITY_SHIFT | dest_kind << CAN_DEST_KIND_SHIFT | dest << CAN_DEST_SHIFT
            | source << CAN_SOURCE_SHIFT, "can_mask": _PRIORITY_BITS | DEST_MASK | CAN_SOURCE_MASK << CAN_SOURCE_SHIFT,
            "extended": True}  # fmt: skip


def check_node_id(node_id: int) -> int:
    if not isinstance(node_id, int) or not MIN_NODE_ID <= node_id <= MAX_NODE_ID:
        raise ValueError(f"CAN node IDs are {MIN_NODE_ID}..{MAX_NODE_ID}, not {node_id!r}")
    return node_id
