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


class _WakeTransport(CanTransport):
    """Notes the timer wake (its due time) at which each heartbeat went out: one wake for all is a fact of the
    sender, which a receiver's timestamps show only as long as no thread is starved between two sends."""

    def __init__(self, *args: object, beats: list[tuple[float, int]], **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._beats, self._due = beats, -1.0

    def _on_timer(self, due: float) -> float | None:
        self._due = due
        return super()._on_timer(due)

    def _send_heartbeat(self) -> None:
        super()._send_heartbeat()
        if self._due >= 0:  # a node's first beat is at its opening, off the grid
            self._beats.append((self._due, self.node_id))


def test_the_nodes_of_one_process_beat_together_on_one_grid(bus: Bus) -> None:
    """128 simulated modules in one process send their heartbeats in one batch (one wake for all; issue 31) — also
    while they hear each other, when each wakes every quarter period (a CI run under load split a batch: the
    quarter-period wakes were off the grid, at each node's own phase)."""
    period, transports, beats = 0.4, [], []
    for k in range(3):
        transports.append(_WakeTransport(10 + k, interface="virtual", channel=bus.channel, heartbeat_period=period,
                                         beats=beats))  # fmt: skip
        Node(f"n{k}", transports[-1])
        time.sleep(0.15)  # opened at phases 0.15 s apart: without the grid their beats are too
    try:
        assert all(abs(t._next_beat / period - round(t._next_beat / period)) < 1e-6 for t in transports), "on the grid"
        assert wait_until(lambda: all(len(t._alive) == 2 for t in transports), timeout=10), "they hear each other"
        assert wait_until(lambda: len(beats) >= 15, timeout=30), beats
        batches: dict[float, set[int]] = {}
        for due, source in list(beats):
            batches.setdefault(due, set()).add(source)
        dues = sorted(batches)
        assert len(dues) >= 4 and all(batches[d] == {10, 11, 12} for d in dues[1:-1]), batches  # ends may be partial
        assert all(abs(d / period - round(d / period)) < 1e-6 for d in dues[1:]), f"wakes off the grid: {dues}"
        seen: set[int] = set()
        while len(seen) < 3:  # and the beats are on the bus
            frame = bus.sniffer.recv(timeout=10)
            assert frame is not None, "no heartbeat on the bus"
            if not not_heartbeat(frame):
                seen.add(CanId.unpack(frame.arbitration_id).source)
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
