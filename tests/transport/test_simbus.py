"""The simulated robot's CAN bus (asm_py/canbus/simbus.py): a frame reaches exactly the buses whose acceptance
filters pass it: the channel's index of filters by mask (which makes a frame's cost independent of the number of
buses that do not receive it: bench/robot.py) agrees with testing every filter of every bus."""

from __future__ import annotations

import random
import threading
import time

import can
import pytest

from asm_py.canbus.simbus import SimBus

from ..helpers import wait_until
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


def _dispatchers() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith("asm-can-dispatch:")]


def test_pushed_buses_get_their_frames_in_order_from_one_thread_and_the_thread_ends_with_the_last() -> None:
    """Issue 31: a process hosting many nodes reads none of their buses with a thread of its own."""
    channel = fresh_name("simbus-push")
    sender = SimBus(channel=channel)
    got: dict[int, list[int]] = {0: [], 1: [], 2: []}
    threads: set[int] = set()
    buses = [SimBus(channel=channel) for _ in range(3)]
    before = len(_dispatchers())
    try:
        for k, bus in enumerate(buses):
            bus.set_filters([{"can_id": k << 8, "can_mask": 0xF00, "extended": True}])
            bus.push_to(lambda frame, k=k: (got[k].append(frame.arbitration_id), threads.add(threading.get_ident())))
        assert len(_dispatchers()) == before + 1
        # priority bits set (normal frames), the bus in bits 8-11, the frame's number above them: every frame is one
        # bus's (the number once reached into bits 8-11: 1 frame in 10 matched no filter and the wait ran 10 s out)
        frames = [0x1000000 | k << 12 | (k % 3) << 8 for k in range(300)]
        for arbitration_id in frames:
            sender.send(can.Message(arbitration_id=arbitration_id, is_extended_id=True, data=b"x"))
        deadline = time.monotonic() + 10
        while sum(map(len, got.values())) < 300 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert sum(map(len, got.values())) == 300
        for k in range(3):
            assert got[k] == [f for f in frames if (f >> 8) & 0xF == k]  # exactly its frames, in the order sent
        assert len(threads) == 1 and threading.get_ident() not in threads
        assert buses[0].recv(timeout=0) is None  # a pushed bus's recv gets nothing: its frames went to the callback
    finally:
        for bus in buses:
            bus.shutdown()
        sender.shutdown()
    deadline = time.monotonic() + 5
    while len(_dispatchers()) > before and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(_dispatchers()) == before


def test_an_urgent_frame_overtakes_the_frames_queued_for_the_dispatch_thread() -> None:
    channel = fresh_name("simbus-urgent")
    sender = SimBus(channel=channel)
    receiver = SimBus(channel=channel)
    order: list[int] = []
    gate, inside = threading.Event(), threading.Event()

    def handle(frame: can.Message) -> None:
        inside.set()
        gate.wait(5)  # the first frame holds the thread while the others queue up
        order.append(frame.arbitration_id)

    receiver.push_to(handle)
    try:
        for k in range(1, 6):
            sender.send(can.Message(arbitration_id=0x1C000000 | k, is_extended_id=True, data=b""))
            assert k > 1 or inside.wait(5)
        sender.send(can.Message(arbitration_id=0x00000042, is_extended_id=True, data=b"stop"))  # priority 0
        gate.set()
        deadline = time.monotonic() + 10
        while len(order) < 6 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert order[0] == 0x1C000001  # already being handled when the stop came
        assert order[1] == 0x42 and order[2:] == [0x1C000000 | k for k in range(2, 6)]
    finally:
        receiver.shutdown()
        sender.shutdown()


def test_frames_held_by_a_thread_go_out_together_at_the_end_and_nothing_is_reordered() -> None:
    """Issue 31: a control tick's frames reach the bridge in one hand-off (``SimBus.holding``). Another thread's
    frame, or an urgent one, sends what waits before it; the frames of every sender reach each receiver in the order
    they were sent; a second holder is refused."""
    channel = fresh_name("simbus-hold")
    a, b, receiver = SimBus(channel=channel), SimBus(channel=channel), SimBus(channel=channel)

    def frame(k: int) -> can.Message:
        return can.Message(arbitration_id=0x1C000000 | k, is_extended_id=True, data=bytes([k]))

    try:
        with SimBus.holding(channel):
            a.send(frame(1))
            b.send(frame(2))
            assert _drain(receiver) == []  # held: nothing delivered yet
            with pytest.raises(RuntimeError, match="already held"), SimBus.holding(channel):
                pass
            other = threading.Thread(target=lambda: b.send(frame(3)))
            other.start()
            other.join(5)
            assert _drain(receiver) == [0x1C000001, 0x1C000002, 0x1C000003]  # the other thread's frame came after
            a.send(frame(4))
            a.send(can.Message(arbitration_id=0x00000042, is_extended_id=True, data=b"stop"))  # urgent: at once
            assert _drain(receiver) == [0x42, 0x1C000004]  # (the urgent FIFO is read first, as a controller's)
            a.send(frame(5))
            b.send(frame(6))
        assert _drain(receiver) == [0x1C000005, 0x1C000006]
        a.send(frame(7))  # released: at once again
        assert _drain(receiver) == [0x1C000007]
    finally:
        for bus in (a, b, receiver):
            bus.shutdown()


def test_the_receivers_remembered_for_an_identifier_follow_filter_changes() -> None:
    channel = fresh_name("simbus")
    sender, receiver = SimBus(channel=channel), SimBus(channel=channel)
    frame_id = 0x0102_0304
    try:
        receiver.set_filters([{"can_id": frame_id, "can_mask": 0x1FFF_FFFF, "extended": True}])
        for _ in range(3):  # the second and third use the remembered receivers
            sender.send(can.Message(arbitration_id=frame_id, data=b"a"))
        assert _drain(receiver) == [frame_id] * 3
        receiver.set_filters([{"can_id": frame_id + 1, "can_mask": 0x1FFF_FFFF, "extended": True}])
        sender.send(can.Message(arbitration_id=frame_id, data=b"b"))
        assert _drain(receiver) == [], "a filter change forgets what was remembered"
        receiver.set_filters(None)
        for k in range(5000):  # more identifiers than are remembered: the memory is bounded, delivery unchanged
            sender.send(can.Message(arbitration_id=k, data=b"c"))
        assert _drain(receiver) == list(range(5000))
        assert len(SimBus._receivers[channel]._known) <= 4096
    finally:
        sender.shutdown()
        receiver.shutdown()


def test_a_transport_frame_is_delivered_itself_and_what_its_sender_records_is_a_copy(tmp_path) -> None:
    """asm_sim hands a transport's own frame to its receivers instead of a copy (issue 31): the sender lets it go,
    so recording what it sent must not turn the frame a receiver holds into a transmitted one. A plain python-can
    message is still copied."""
    from asm_py.transport.can import CanTransport

    channel = fresh_name("simbus")
    listener = SimBus(channel=channel)
    transport = CanTransport(5, interface="asm_sim", channel=channel, heartbeat_period=60.0,
                             record=tmp_path / "sent.asc")  # fmt: skip
    try:
        transport.attach("m5", lambda source, data, respond: None)
        while listener.recv(timeout=0) is not None:  # the first heartbeat
            pass
        transport.publish("x", b"\x20\x00\x01\x02\x03")
        frame = listener.recv(timeout=5)
        assert frame is not None and frame.is_rx and frame.channel == channel and frame.timestamp > 0
        assert bytes(frame.data) == b"\x20\x00\x01\x02\x03"
        plain = can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x07")
        transport.bus.send(plain)
        copied = listener.recv(timeout=5)
        assert copied is not None and copied is not plain and plain.channel is None
        assert bytes(copied.data) == b"\x07" and copied.channel == channel and copied.is_rx
    finally:
        transport.close()
        listener.shutdown()
    sent = [line for line in (tmp_path / "sent.asc").read_text().splitlines() if "20 00 01 02 03" in line]
    assert len(sent) == 1 and " Tx " in sent[0]


def test_recv_reads_the_urgent_fifo_first_and_logs_as_python_can_does(caplog: pytest.LogCaptureFixture) -> None:
    """``SimBus.recv`` skips python-can's loop (issue 31), not what it does: the urgent FIFO first, a level-9 log
    line per frame received, None when nothing comes."""
    channel = fresh_name("simbus-recv")
    sender, receiver = SimBus(channel=channel), SimBus(channel=channel)
    try:
        sender.send(can.Message(arbitration_id=0x1C000001, is_extended_id=True, data=b"a"))
        sender.send(can.Message(arbitration_id=0x00000042, is_extended_id=True, data=b"stop"))
        with caplog.at_level(9, logger="can.bus"):
            first, second = receiver.recv(timeout=1), receiver.recv(timeout=1)
        assert first is not None and second is not None
        assert [first.arbitration_id, second.arbitration_id] == [0x42, 0x1C000001]
        assert [r.getMessage().startswith("Received: ") for r in caplog.records if r.name == "can.bus"] == [True] * 2
        began = time.monotonic()
        assert receiver.recv(timeout=0.05) is None and time.monotonic() - began >= 0.04
    finally:
        sender.shutdown()
        receiver.shutdown()


def test_flush_returns_once_every_frame_sent_before_it_was_handled_and_counts_the_replies_sent_meanwhile() -> None:
    """``SimBus.flush``: what a simulation waits on between ticks (gaits.sim.Simulation.settle) instead of sleeping.
    A slow handler holds the dispatch thread; flush returns only after it, and the reply that handler sent (queued
    behind flush's mark) is counted by the next call, so a caller flushing until the count stops knows the bus is
    quiet."""
    channel = fresh_name("simbus-flush")
    assert SimBus.flush(channel) == 0  # no pushed bus: nothing to wait for
    tool, module = SimBus(channel=channel), SimBus(channel=channel)
    module.set_filters([{"can_id": 0x100, "can_mask": 0xF00, "extended": True}])
    tool.set_filters([{"can_id": 0x200, "can_mask": 0xF00, "extended": True}])
    heard: list[int] = []
    gate = threading.Event()

    def answer(frame: can.Message) -> None:
        gate.wait(10)  # the first request holds the dispatch thread until flush's mark is queued behind the others
        heard.append(frame.arbitration_id)
        module.send(can.Message(arbitration_id=0x10000200 | frame.arbitration_id & 0xFF, is_extended_id=True))

    module.push_to(answer)
    tool.push_to(lambda frame: heard.append(frame.arbitration_id))
    flushed: list[int] = []
    flusher = threading.Thread(target=lambda: flushed.append(SimBus.flush(channel)))
    try:
        for k in range(3):
            tool.send(can.Message(arbitration_id=0x10000100 | k, is_extended_id=True))
        queued = SimBus._dispatchers[channel]._normal
        assert wait_until(lambda: queued.qsize() == 2)  # the first request is being handled, two wait
        flusher.start()
        assert wait_until(lambda: queued.qsize() == 3) and not flushed  # the mark waits behind them
        gate.set()
        flusher.join(10)
        requests = [0x10000100, 0x10000101, 0x10000102]
        assert heard[:3] == requests and flushed == [3]  # every request handled when flush returned, no reply
        assert SimBus.flush(channel) == 6 and heard == [*requests, *(r + 0x100 for r in requests)]  # the next: all
        assert SimBus.flush(channel) == 6  # then quiet: the count stops
        with SimBus.holding(channel), pytest.raises(RuntimeError, match="held by this thread"):
            SimBus.flush(channel)  # its own held frames would wait for the block's end: never flushed
    finally:
        module.shutdown()
        tool.shutdown()


def test_flush_times_out_when_a_handler_blocks() -> None:
    channel = fresh_name("simbus-flush")
    sender, receiver = SimBus(channel=channel), SimBus(channel=channel)
    gate = threading.Event()
    receiver.push_to(lambda frame: gate.wait(10))
    try:
        sender.send(can.Message(arbitration_id=0x10000001, is_extended_id=True))
        with pytest.raises(TimeoutError, match="in flight"):
            SimBus.flush(channel, timeout=0.2)
    finally:
        gate.set()
        receiver.shutdown()
        sender.shutdown()


def test_flush_from_a_callback_is_refused_and_a_bus_hooked_again_gets_no_frame_meant_for_its_old_callback() -> None:
    """A callback that flushed would wait for itself (it used to stall the channel for the whole timeout). A bus
    unhooked while frames waited for it and hooked again does not get them: the old dispatch thread, still draining,
    would hand them to the new callback beside the new thread, out of order."""
    channel = fresh_name("simbus-flush")
    sender, receiver = SimBus(channel=channel), SimBus(channel=channel)
    refused: list[str] = []

    def flushing(frame: can.Message) -> None:
        try:
            SimBus.flush(channel, timeout=5)
        except RuntimeError as exc:
            refused.append(str(exc))

    receiver.push_to(flushing)
    try:
        sender.send(can.Message(arbitration_id=0x10000001, is_extended_id=True))
        assert SimBus.flush(channel) == 1 and refused and "waits for itself" in refused[0]
        gate, inside, old, new = threading.Event(), threading.Event(), [], []
        receiver.push_to(lambda frame: (inside.set(), gate.wait(10), old.append(frame.arbitration_id)))
        for k in range(2, 5):
            sender.send(can.Message(arbitration_id=0x10000000 | k, is_extended_id=True))
        assert inside.wait(5)  # the old callback holds the first; two wait behind it
        receiver.push_to(None)  # the old dispatch thread ends after what it holds
        receiver.push_to(lambda frame: new.append(frame.arbitration_id))
        sender.send(can.Message(arbitration_id=0x10000009, is_extended_id=True))
        gate.set()
        assert wait_until(lambda: new == [0x10000009], timeout=5)
        time.sleep(0.1)
        assert new == [0x10000009] and old == [0x10000002]  # the frames queued for the old callback: not handed on
    finally:
        gate.set()
        receiver.shutdown()
        sender.shutdown()
