"""The emulated boards' backplane (asm_module/backplane.py): boards of one process on one channel share one bus and
its reader; a board's frame reaches the bus once and every other board at once, never itself; a frame from the bus
reaches each board once; the last board out shuts the bus down, a caller's bus is left open."""

from __future__ import annotations

import threading

import can
from can.interfaces.virtual import channels

from asm_module.backplane import Backplane

from ..helpers import wait_until
from ..transports import fresh_name


class Board:
    """A receiver that records what reached it."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, bool, bytes]] = []
        self.threads: set[str] = set()

    def __call__(self, can_id: int, extended: bool, data: bytes) -> None:
        self.frames.append((can_id, extended, data))
        self.threads.add(threading.current_thread().name)


def test_boards_on_one_channel_share_one_bus_and_each_frame_reaches_every_other_board_once() -> None:
    channel = fresh_name("backplane")
    a, b, c = Board(), Board(), Board()
    planes = [Backplane.join(board, interface="virtual", channel=channel) for board in (a, b, c)]
    outside = can.Bus(interface="virtual", channel=channel)
    try:
        assert planes[0] is planes[1] is planes[2] and len(channels[channel]) == 2, "one bus for the boards, one tool"
        planes[0].send(a, 0x1234, True, b"\x01")
        assert a.frames == [] and b.frames == c.frames == [(0x1234, True, b"\x01")], "at once, never to the sender"
        heard = outside.recv(timeout=5)
        assert heard is not None and heard.arbitration_id == 0x1234 and outside.recv(timeout=0.1) is None, "once"
        outside.send(can.Message(arbitration_id=0x42, data=b"\x02", is_extended_id=True))
        assert wait_until(lambda: len(a.frames) == 1 and len(b.frames) == len(c.frames) == 2, timeout=5)
        assert a.frames == [(0x42, True, b"\x02")] and a.threads == {f"asm-backplane:{planes[0].bus.channel_info}"}
        outside.send(can.Message(arbitration_id=0x43, data=b"", is_remote_frame=True, is_extended_id=True))
        outside.send(can.Message(arbitration_id=0x44, data=b"\x03", is_extended_id=True))
        assert wait_until(lambda: len(a.frames) == 2, timeout=5) and a.frames[-1][0] == 0x44, "no remote frames"
        for board in (a, b):
            planes[0].leave(board)
        assert len(channels[channel]) == 2, "open while a board is on it"
        planes[0].leave(c)
        assert len(channels[channel]) == 1, "the last board out shut the bus down"
        again = Backplane.join(a, interface="virtual", channel=channel)
        assert again is not planes[0] and len(channels[channel]) == 2, "a new one after"
        again.leave(a)
    finally:
        outside.shutdown()


def test_a_bus_given_is_a_backplane_of_its_own_and_stays_open() -> None:
    channel = fresh_name("backplane-given")
    given = can.Bus(interface="virtual", channel=channel)
    a, b = Board(), Board()
    try:
        mine, shared = Backplane.join(a, given), Backplane.join(b, interface="virtual", channel=channel)
        assert mine is not shared and mine.bus is given
        mine.send(a, 7, True, b"x")
        assert wait_until(lambda: b.frames == [(7, True, b"x")], timeout=5), "over the bus to the other backplane"
        mine.leave(a)
        shared.leave(b)
        given.send(can.Message(arbitration_id=8, data=b"y", is_extended_id=True))  # still open: no CanError
    finally:
        given.shutdown()
