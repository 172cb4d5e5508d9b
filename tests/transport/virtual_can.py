"""A virtual CAN channel for the CAN transport's tests (test_can.py, test_can_timers.py; the ``bus`` fixture in
conftest.py): a sniffer that sees every frame, and the nodes on it."""

from __future__ import annotations

import time

import can

from asm_py.canbus.ids import CanId, Dest, SystemCode
from asm_py.node import Node
from asm_py.transport.can import CanTransport

from ..transports import FAST_BEATS, fresh_name


class Bus:
    """A virtual CAN channel with a sniffer that sees every frame, and nodes on it (closed at the end)."""

    def __init__(self, **options) -> None:
        self.channel = fresh_name("asm-can")
        self.options = {**FAST_BEATS, **options}
        self.sniffer = can.Bus(interface="virtual", channel=self.channel)
        self.nodes: list[Node] = []

    def node(self, name: str, node_id: int, **options) -> Node:
        transport = CanTransport(node_id, interface="virtual", channel=self.channel, **{**self.options, **options})
        node = Node(name, transport)
        self.nodes.append(node)
        return node

    def raw(self) -> can.BusABC:
        return can.Bus(interface="virtual", channel=self.channel)

    def drain(self, quiet: float = 0.2) -> list[can.Message]:
        """The frames seen until ``quiet`` seconds pass without any but heartbeats."""
        frames = []
        last = time.monotonic()
        while time.monotonic() - last < quiet:
            frame = self.sniffer.recv(timeout=0.02)
            if frame is not None:
                frames.append(frame)
                if not_heartbeat(frame):
                    last = time.monotonic()
        return frames

    def close(self) -> None:
        for node in self.nodes:
            node.close()
        self.sniffer.shutdown()


def not_heartbeat(frame: can.Message) -> bool:
    cid = CanId.unpack(frame.arbitration_id)
    return not (cid.dest_kind == Dest.SYSTEM and cid.dest in (SystemCode.HEARTBEAT, SystemCode.LEAVE))
