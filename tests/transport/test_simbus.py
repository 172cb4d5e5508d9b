"""The simulated robot's CAN bus (asm_py/canbus/simbus.py): a frame reaches exactly the buses whose acceptance
filters pass it: the channel's index of filters by mask (which makes a frame's cost independent of the number of
buses that do not receive it: bench/robot.py) agrees with testing every filter of every bus."""

from __future__ import annotations

import random

import can
import pytest

from asm_py.canbus.simbus import SimBus

from ..transports import fresh_name

pytestmark = pytest.mark.timeout(120)


def _drain(bus: can.BusABC) -> list[int]:
    got = []
    while (frame := bus.recv(timeout=0)) is not None:
        got.append(frame.arbitration_id)
    return got


def test_every_frame_reaches_exactly_the_buses_whose_filters_pass_it() -> None:
    rng = random.Random(5)
    channel = fresh_name("simbus")
    masks = [0x03FF0000, 0x1FFF0000, 0x1F000000, 0x1FFFFF00, 0x7FF, 0]
    buses = [SimBus(channel=channel) for _ in range(12)]
    try:
        for round_ in range(4):  # filters change between rounds: the index follows
            for k, bus in enumerate(buses):
                if k % 5 == 4:
                    bus.set_filters(None)  # everything
                    continue
                count = rng.randrange(1, 4)
                filters = [{"can_id": rng.getrandbits(29), "can_mask": rng.choice(masks),
                            "extended": rng.choice([True, False, None])} for _ in range(count)]  # fmt: skip
                bus.set_filters(filters)
            sent = []
            for _ in range(400):
                extended = rng.random() < 0.8
                target = rng.choice(buses)._accept
                if target and rng.random() < 0.6:  # often an ID one of the filters passes
                    can_id, mask, _ = rng.choice(target)
                    arbitration_id = (can_id & mask) | (rng.getrandbits(29) & ~mask)
                else:
                    arbitration_id = rng.getrandbits(29)
                if not extended:
                    arbitration_id &= 0x7FF
                frame = can.Message(arbitration_id=arbitration_id, is_extended_id=extended, data=b"x")
                sender = buses[round_]
                sender.send(frame)
                sent.append((frame, sender))
            for bus in buses:
                expected = [f.arbitration_id for f, sender in sent if sender is not bus and bus._accepts(f)]
                assert sorted(_drain(bus)) == sorted(expected)  # e-stop-priority frames come first: sorted
    finally:
        for bus in buses:
            bus.shutdown()
