"""A caller reads the CAN bus itself while it waits for its reply (asm_py.transport.can_reader, issue 31): its own
reply on its own thread, everything else on the receive thread, in order; deadlines, followers and closing."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import can
import pytest

from asm_py import Attribute, Service
from asm_py.canbus.ids import CanId, Dest, FrameType, Priority, SystemCode
from asm_py.errors import AsmTimeout
from asm_py.node import Node
from asm_py.protocol import Kind, Method, first_byte
from asm_py.transport.can import CanTransport

from ..helpers import run_in_thread, wait_until
from ..transports import FAST_BEATS, fresh_name


class Pair:
    """A module (node 1) and a tool (node 2) on a fresh virtual channel, and a raw bus for a third party (node 9)."""

    def __init__(self, **options: float) -> None:
        self.channel = fresh_name("asm-reader")
        settings = {**FAST_BEATS, **options}
        self.module = Node("m1", CanTransport(1, interface="virtual", channel=self.channel, **settings))
        self.tool = Node("tool", CanTransport(2, interface="virtual", channel=self.channel, **settings))
        self.raw = can.Bus(interface="virtual", channel=self.channel)

    @property
    def reader(self):
        return self.tool.transport._reader  # type: ignore[attr-defined]

    def send_raw(self, priority: int, dest_kind: int, dest: int, data: bytes) -> None:
        ident = CanId(priority, dest_kind, dest, 9, FrameType.SINGLE).pack()
        self.raw.send(can.Message(arbitration_id=ident, is_extended_id=True, data=data))

    def close(self) -> None:
        self.tool.close()
        self.module.close()
        self.raw.shutdown()


@pytest.fixture
def pair() -> Iterator[Pair]:
    made = Pair()
    yield made
    made.close()


def asm_threads() -> set[str]:
    return {t.name for t in threading.enumerate() if t.name.startswith("asm-can")}


def test_a_caller_handles_its_own_reply_on_its_own_thread(pair: Pair) -> None:
    pair.module.register(Attribute("joint.angle", 1.5, codec="float32"))
    angle = pair.tool.lookup("m1", "joint.angle", timeout=5)
    threads: list[str] = []
    original = pair.tool._on_message

    def spy(source: str, data: bytes, respond: object) -> None:
        if data[0] >> 4 & 3 == Kind.REPLY:
            threads.append(threading.current_thread().name)
        original(source, data, respond)  # type: ignore[arg-type]

    pair.tool.transport._on_message = spy  # type: ignore[attr-defined]
    time.sleep(0.2)  # the receive thread reads the bus again (no caller led for a while)
    values = [angle.get() for _ in range(50)]
    assert values == [1.5] * 50
    mine = threading.current_thread().name
    # the first call of a burst may find the receive thread reading; the rest find the lead free
    assert threads.count(mine) >= 40, threads
    assert pair.reader.led >= 40


def test_what_is_not_the_callers_reply_runs_on_the_receive_thread_in_order() -> None:
    """While a caller leads (here waiting for a blocking get), a request to its node, an e-stop and a publication
    arrive: each is handled on the receive thread — never on the caller, which may hold locks of its own — in the
    order they came, and the call still completes (slower heartbeats: the test's frames mostly come first)."""
    pair = Pair(heartbeat_period=0.5)
    try:
        fresh = Attribute("fresh", sync_get=True, codec="int16")
        pair.module.register(fresh)
        pair.module.register(Attribute("joint.angle", 1.5, codec="float32"))
        mode = pair.tool.register(Attribute("tool.mode", 7, codec="uint8"))
        remote, angle = pair.tool.lookup("m1", "fresh", timeout=5), pair.tool.lookup("m1", "joint.angle", timeout=5)
        seen: list[tuple[str, str]] = []
        pair.tool.on_estop(lambda source, reason: seen.append(("estop", threading.current_thread().name)))
        pair.tool.transport.subscribe("can.9", "x", lambda data: seen.append(("pub", threading.current_thread().name)),
                                      object_id=5)  # fmt: skip
        get_mode = bytes((first_byte(Kind.REQUEST_REPLY, Method.GET), 3, mode.class_id, mode.object_id))

        def call() -> int:
            for _ in range(3):  # a burst first: the receive thread stands aside and the blocking get leads
                angle.get()
            return remote.get(5.0)

        for value in range(5):  # on a loaded machine the get may start late and follow: then again
            seen.clear()
            listener = can.Bus(interface="virtual", channel=pair.channel)
            try:
                caller, box = run_in_thread(call)
                assert wait_until(lambda: pair.module.server.blocking("tool") == 1, timeout=5)
                handed = pair.reader.handed
                pair.send_raw(Priority.REQUEST, Dest.NODE, 2, get_mode)
                pair.send_raw(Priority.ESTOP, Dest.SYSTEM, SystemCode.ESTOP, b"test")
                pair.send_raw(Priority.PUBLICATION, Dest.BROADCAST, 0, bytes((0xF0, 0, 0x11, 5, 1)))
                assert wait_until(lambda: len(seen) == 2, timeout=5), seen
                fresh.set(value)
                caller.join(10)
                assert box == {"result": value}
                replies = []
                deadline = time.monotonic() + 0.3
                while time.monotonic() < deadline:
                    frame = listener.recv(timeout=0.1)
                    if frame is not None and CanId.unpack(frame.arbitration_id).dest == 9:
                        replies.append(bytes(frame.data))
            finally:
                listener.shutdown()
            assert replies == [bytes((first_byte(Kind.REPLY, Method.GET), 3, 0, mode.object_id, 7))]
            assert [kind for kind, _ in seen] == ["estop", "pub"]
            assert {name for _, name in seen} == {"asm-can:tool"}
            if pair.reader.handed > handed:
                break  # the caller led, and handed the first frame over with the lead
        assert pair.reader.handed > handed
    finally:
        pair.close()


def test_a_deadline_fires_while_the_caller_reads_a_busy_bus(pair: Pair) -> None:
    """Nothing answers (node 9 is a raw bus), while frames for the tool keep coming: the deadline still fires."""
    pair.tool.transport._names[9] = "raw"  # type: ignore[attr-defined]
    pair.tool.transport._ids["raw"] = 9  # type: ignore[attr-defined]
    stop = threading.Event()

    def chatter() -> None:
        while not stop.is_set():
            pair.send_raw(Priority.PUBLICATION, Dest.BROADCAST, 0, bytes((0xF0, 0, 0x11, 5, 1)))
            time.sleep(0.001)

    talker = threading.Thread(target=chatter, daemon=True)
    talker.start()
    try:
        began = time.monotonic()
        with pytest.raises(AsmTimeout, match=r"no reply within 0\.3s"):
            pair.tool.port("raw").call(Method.GET, 0x11, 1, timeout=0.3)
        assert 0.25 <= time.monotonic() - began < 5
        stop.set()
        talker.join(5)
        began = time.monotonic()
        with pytest.raises(AsmTimeout, match=r"no reply within 0\.3s"):  # and on a quiet bus, to a node never heard
            pair.tool.port("can.10").call(Method.GET, 0x11, 1, timeout=0.3)
        assert 0.25 <= time.monotonic() - began < 5
    finally:
        stop.set()
        talker.join(5)


def test_the_receive_thread_reads_again_after_a_burst(pair: Pair) -> None:
    pair.module.register(Attribute("joint.angle", 1.5, codec="float32"))
    angle = pair.tool.lookup("m1", "joint.angle", timeout=5)
    for _ in range(20):
        angle.get()
    got: list[str] = []
    pair.tool.on_estop(lambda source, reason: got.append(threading.current_thread().name))
    time.sleep(0.05)  # nobody calls: the e-stop must not wait for the next caller
    pair.send_raw(Priority.ESTOP, Dest.SYSTEM, SystemCode.ESTOP, b"after")
    assert wait_until(lambda: got == ["asm-can:tool"], timeout=2), got


def test_many_callers_and_a_service_thread_at_once(pair: Pair) -> None:
    """Leaders and followers together: callers on plain threads and a service thread's calls (which follow, so a
    stop interrupts them) all complete with their own values."""
    for i in range(4):
        pair.module.register(Attribute(f"a{i}", i, codec="int32"))
    remotes = [pair.tool.lookup("m1", f"a{i}", timeout=5) for i in range(4)]
    results: dict[int, list[int]] = {i: [] for i in range(4)}

    class Poller(Service):
        def run(self) -> None:
            for _ in range(200):
                results[3].append(remotes[3].get())

    poller = Poller("poller")
    poller.start()
    threads = [threading.Thread(target=lambda i=i: results[i].extend(remotes[i].get() for _ in range(200)))
               for i in range(3)]  # fmt: skip
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(30)
    assert wait_until(lambda: not poller.running, timeout=30)
    assert poller.last_error is None
    assert all(results[i] == [i] * 200 for i in range(4)), {i: len(r) for i, r in results.items()}


def test_closing_leaves_no_thread_and_fails_a_waiting_call() -> None:
    before = asm_threads()
    made = Pair()
    made.module.register(Attribute("fresh", sync_get=True, codec="int16"))
    remote = made.tool.lookup("m1", "fresh", timeout=5)
    caller, box = run_in_thread(remote.get, 30.0)
    assert wait_until(lambda: made.module.server.blocking("tool") == 1, timeout=5)
    time.sleep(0.05)
    made.close()
    caller.join(10)
    assert not caller.is_alive()
    assert isinstance(box.get("error"), AsmTimeout) and "closed" in str(box["error"])
    assert wait_until(lambda: asm_threads() <= before, timeout=5), asm_threads() - before
