"""A CAN node's timers and frames on python-can's virtual bus (issue 31): a node with nothing to watch wakes at its
heartbeats alone, the nodes of one process beat together on one grid, and the transport's frames copy as python-can's
messages do. (Split from test_can.py, which keeps the protocol's own tests.)"""

from __future__ import annotations

import time

import can

from asm_py.canbus.ids import CanId
from asm_py.node import Node
from asm_py.transport.can import CanTransport

from ..helpers import wait_until
from .virtual_can import Bus, not_heartbeat


class _CountingTransport(CanTransport):
    """Counts the wakes of its timer (issue 31: a node with nothing to watch wakes at its heartbeats alone)."""

    wakes = 0

    def _on_timer(self, due: float) -> float | None:
        self.wakes += 1
        return super()._on_timer(due)


def test_a_node_with_no_live_peer_wakes_its_timer_at_its_heartbeats_alone(bus: Bus) -> None:
    transport = _CountingTransport(1, interface="virtual", channel=bus.channel, heartbeat_period=0.1, watch_bus=False)
    node = Node("lonely", transport)
    try:
        began, beats = time.monotonic(), transport.frames_sent
        assert wait_until(lambda: transport.frames_sent - beats >= 8, timeout=30), "it still sends its heartbeats"
        elapsed, wakes = time.monotonic() - began, transport.wakes
        # a quarter-period timer would have woken ~4 times per beat; at the beats alone it wakes about once each
        assert wakes <= elapsed / 0.1 + 3, f"{wakes} wakes in {elapsed:.2f} s of 0.1 s heartbeats"
    finally:
        node.close()


def test_a_live_peer_is_watched_every_quarter_period_again(bus: Bus) -> None:
    a = bus.node("a", 1)
    transport = _CountingTransport(2, interface="virtual", channel=bus.channel, heartbeat_period=0.1)
    b = Node("b", transport)
    try:
        assert wait_until(lambda: "a" in b.discover(), timeout=10)
        began, wakes = time.monotonic(), transport.wakes
        assert wait_until(lambda: transport.wakes - wakes >= 12, timeout=30), "four wakes a period while 'a' lives"
        assert time.monotonic() - began < 10
        a.close()
        assert wait_until(lambda: "a" not in b.discover(), timeout=10), "its loss is still seen (LEAVE or silence)"
    finally:
        b.close()


def test_the_nodes_of_one_process_beat_together_on_one_grid(bus: Bus) -> None:
    """128 simulated modules in one process send their heartbeats in one batch (one wake for all; issue 31)."""
    period, transports = 0.4, []
    for k in range(3):
        transports.append(CanTransport(10 + k, interface="virtual", channel=bus.channel, heartbeat_period=period))
        Node(f"n{k}", transports[-1])
        time.sleep(0.15)  # opened at phases 0.15 s apart: without the grid their beats are too
    try:
        assert all(abs(t._next_beat / period - round(t._next_beat / period)) < 1e-6 for t in transports), "on the grid"
        beats: list[tuple[float, int]] = []
        firsts: set[int] = set()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and len(beats) < 15:
            frame = bus.sniffer.recv(timeout=0.1)
            if frame is None or not_heartbeat(frame):
                continue
            source = CanId.unpack(frame.arbitration_id).source
            if source in firsts:  # a node's first beat is at its opening, off the grid
                beats.append((frame.timestamp, source))
            firsts.add(source)
        beats.sort()
        batches: list[set[int]] = [set()]
        for (t, source), (before, _) in zip(beats, [beats[0], *beats[:-1]], strict=True):
            if t - before > period / 4:
                batches.append(set())
            batches[-1].add(source)
        assert len(batches) >= 4 and all(b == {10, 11, 12} for b in batches[1:-1]), batches  # ends may be partial
    finally:
        for transport in transports:
            transport.close()


def test_a_sent_frame_copies_as_deep_as_a_python_can_message() -> None:
    """python-can's virtual bus deep-copies each frame per receiver; the transport's frames copy directly (issue
    31), into an equal frame with its own data, which a receiver may change without touching the sender's."""
    import copy

    from asm_py.transport.can_send import Frame

    for channel in (None, "bus", ("a", 1), ["mutable"]):
        frame = Frame(arbitration_id=0x1234, is_extended_id=True, data=b"\x01\x02", is_fd=True, bitrate_switch=True,
                      channel=channel)  # fmt: skip
        twin = copy.deepcopy(frame)
        plain = copy.deepcopy(can.Message(arbitration_id=0x1234, is_extended_id=True, data=b"\x01\x02", is_fd=True,
                                          bitrate_switch=True, channel=channel))  # fmt: skip
        assert twin.equals(frame) and twin.equals(plain) and type(twin) is Frame
        twin.data[0] = 9
        assert frame.data == bytearray(b"\x01\x02")
        assert channel is None or isinstance(channel, str | tuple) or twin.channel is not channel
