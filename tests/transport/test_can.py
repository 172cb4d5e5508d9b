"""ASM over CAN on python-can's virtual bus: identifiers, fragmentation, frame counts, groups, e-stop, heartbeats,
bounded reassembly, and hostile frames. (The transport also runs the conformance and location-transparency suites.)"""

from __future__ import annotations

import itertools
import json
import os
import struct
import time
from collections.abc import Iterator

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from asm_py import Attribute, Service
from asm_py.canbus.fragments import FD_SIZES, Reassembler, fragment, frame_count, wire_bytes
from asm_py.canbus.ids import CanId, Dest, FrameType, Priority, SystemCode, frame_priority
from asm_py.node import Node
from asm_py.transport.can import CanTransport, group_id

from ..helpers import VECTORS, wait_until
from ..transports import FAST_BEATS, fresh_name
from .virtual_can import Bus, not_heartbeat


class Gait(Service):
    def run(self) -> None:
        while self.sleep(0.01):
            pass


# -- identifiers and fragmentation ------------------------------------------------------------------------------


@given(st.integers(0, 7), st.integers(0, 3), st.integers(0, 255), st.integers(0, 255), st.integers(0, 3),
       st.integers(0, 63))  # fmt: skip
def test_identifier_round_trip(priority, dest_kind, dest, source, frame, counter) -> None:
    cid = CanId(priority, dest_kind, dest, source, frame, counter)
    packed = cid.pack()
    assert packed < 1 << 29 and CanId.unpack(packed) == cid


def test_more_urgent_frames_win_arbitration() -> None:
    def ident(priority: int) -> int:
        return CanId(priority, Dest.NODE, 1, 254, FrameType.SINGLE).pack()

    order = [Priority.ESTOP, Priority.REPLY, Priority.REQUEST, Priority.PUBLICATION, Priority.BULK, Priority.HEARTBEAT]
    assert [ident(p) for p in order] == sorted(ident(p) for p in order)
    with pytest.raises(ValueError):
        CanId(8, 0, 0, 0, 0).pack()


@settings(max_examples=200)
@given(st.binary(max_size=3000), st.sampled_from([8, 64]))
def test_fragments_reassemble_to_the_message(message: bytes, frame_size: int) -> None:
    frames = list(fragment(message, frame_size=frame_size))
    assert len(frames) == frame_count(len(message), frame_size=frame_size)
    assert all(len(data) <= frame_size and (frame_size == 8 or len(data) in FD_SIZES) for _, _, data in frames)
    reassembler = Reassembler(max_message=4096)
    out = [reassembler.feed((1, 0, 2), t, c, d, 0.0) for t, c, d in frames]
    assert out[-1] == message and all(o is None for o in out[:-1]) and reassembler.partials == 0


def test_payload_efficiency_of_a_1kib_message() -> None:
    assert 1024 / wire_bytes(1024, frame_size=8) >= 7 / 8
    assert 1024 / wire_bytes(1024, frame_size=64) >= 62 / 64
    assert frame_count(8) == 1 and frame_count(9) == 2 and frame_count(1024) == 129
    assert frame_count(64, frame_size=64) == 1 and frame_count(1024, frame_size=64) == 17


def test_reassembly_detects_gaps_corruption_and_timeouts() -> None:
    message = bytes(range(200))
    frames = list(fragment(message))
    r = Reassembler(timeout=0.5)
    key = (3, 0, 1)
    for t, c, d in frames[:5] + frames[6:]:  # one fragment lost
        assert r.feed(key, t, c, d, 0.0) is None
    assert r.dropped.get("fragment gap") == 1 and r.partials == 0
    bad = [(t, c, bytes([d[0] ^ 1]) + d[1:] if i == 3 else d) for i, (t, c, d) in enumerate(frames)]
    assert [r.feed(key, t, c, d, 0.0) for t, c, d in bad][-1] is None
    assert r.dropped.get("crc mismatch") == 1
    for t, c, d in frames[:4]:  # a sender that dies mid-message
        r.feed(key, t, c, d, 1.0)
    assert r.partials == 1 and r.buffered_bytes > 0
    r.expire(1.4)
    assert r.partials == 1
    r.expire(1.6)
    assert r.partials == 0 and r.dropped.get("reassembly timeout") == 1
    first = next(fragment(bytes(5000)))
    assert r.feed(key, *first, 2.0) is None and r.dropped.get("message too long") == 1


def test_an_immediately_repeated_fragment_is_ignored() -> None:
    message = bytes(range(40))
    frames = list(fragment(message))
    doubled = [f for frame in frames for f in (frame, frame)]  # every frame received twice
    r = Reassembler()
    out = [r.feed((1, 0, 2), t, c, d, 0.0) for t, c, d in doubled]
    assert [o for o in out if o is not None] == [message]
    assert r.dropped == {"duplicate fragment": len(frames) - 1, "orphan fragment": 1}


def test_reassembly_memory_is_bounded_under_many_senders() -> None:
    r = Reassembler(max_message=1000, max_partials=8)
    first = next(fragment(bytes(1000)))
    for source in range(1, 255):
        for dest in range(4):
            r.feed((source, 0, dest), *first, 0.0)
    assert r.partials == 8 and r.buffered_bytes <= r.bound
    assert r.dropped["too many partial messages"] == 254 * 4 - 8


# -- the transport on the virtual bus ---------------------------------------------------------------------------


def test_get_and_set_of_a_4_byte_value_are_one_frame_each_way(bus: Bus) -> None:
    module = bus.node("m1", 1)
    tool = bus.node("tool", 2)
    angle = Attribute("joint.angle", 0.5, codec="float32")
    module.register(angle)
    assert wait_until(lambda: "m1" in tool.discover(), timeout=5)
    remote = tool.lookup("m1", "joint.angle", timeout=5)
    bus.drain()
    assert remote.get() == 0.5
    frames = [f for f in bus.drain() if not_heartbeat(f)]
    assert len(frames) == 2 and [len(f.data) for f in frames] == [4, 8], frames
    assert [CanId.unpack(f.arbitration_id).priority for f in frames] == [Priority.REQUEST, Priority.REPLY]
    remote.set(1.25, wait=True)
    frames = [f for f in bus.drain() if not_heartbeat(f)]
    assert len(frames) == 2 and frames[0].data[4:] == struct.pack("<f", 1.25) and len(frames[1].data) == 4
    remote.set(2.0)  # no reply wanted: one frame
    assert wait_until(lambda: angle.peek() == 2.0)
    assert len([f for f in bus.drain() if not_heartbeat(f)]) == 1


def test_large_values_travel_fragmented_both_ways(bus: Bus) -> None:
    module = bus.node("m1", 1)
    tool = bus.node("tool", 2)
    table = Attribute("gait.table", b"", codec="bytes")
    module.register(table)
    remote = tool.lookup("m1", "gait.table", timeout=5)
    payload = bytes(range(256)) * 12
    remote.set(payload, wait=True)
    assert table.peek() == payload and remote.peek() == payload


def test_fd_frames_carry_up_to_64_bytes() -> None:
    bus = Bus(fd=True)
    try:
        module = bus.node("m1", 1)
        tool = bus.node("tool", 2)
        pose = Attribute("pose", (0.0,) * 12, codec="float32[12]")
        module.register(pose)
        remote = tool.lookup("m1", "pose", timeout=5)
        bus.drain()
        remote.set(tuple(float(i) for i in range(12)), wait=True)
        frames = [f for f in bus.drain() if not_heartbeat(f)]
        assert frames[0].is_fd and len(frames) == 2 and pose.peek()[11] == 11.0
    finally:
        bus.close()


def test_starting_a_service_on_every_module_is_one_broadcast_frame(bus: Bus) -> None:
    gaits = []
    for i in range(1, 6):
        node = bus.node(f"m{i}", i)
        gait = Gait(f"gait{i}")
        node.register(gait, class_name="gait.service")
        gaits.append(gait)
    tool = bus.node("tool", 100)
    bus.drain()
    tool.group().service("gait.service").start()
    assert wait_until(lambda: all(g.running for g in gaits), timeout=5)
    frames = [f for f in bus.drain() if not_heartbeat(f)]
    assert len(frames) == 1 and CanId.unpack(frames[0].arbitration_id).dest_kind == Dest.BROADCAST
    for node in bus.nodes[:2]:
        node.join_group("front")
    tool.group("front").service("gait.service").stop()
    assert wait_until(lambda: not gaits[0].started and not gaits[1].started, timeout=5)
    frames = [f for f in bus.drain() if not_heartbeat(f)]
    cid = CanId.unpack(frames[0].arbitration_id)
    assert len(frames) == 1 and (cid.dest_kind, cid.dest) == (Dest.GROUP, group_id("front"))
    assert all(g.running for g in gaits[2:])
    for gait in gaits:
        gait.stop(timeout=5)


def test_estop_is_one_highest_priority_broadcast_every_node_acts_on(bus: Bus) -> None:
    nodes = [bus.node(f"m{i}", i) for i in range(1, 5)]
    stopped: list[str] = []
    for node in nodes:
        node.on_estop(lambda source, reason, n=node.name: stopped.append(n))
    bus.drain()
    nodes[0].estop("button")
    assert wait_until(lambda: sorted(stopped) == ["m1", "m2", "m3", "m4"], timeout=5)
    frames = [f for f in bus.drain() if not_heartbeat(f)]
    cid = CanId.unpack(frames[0].arbitration_id)
    assert len(frames) == 1 and cid.priority == 0 and (cid.dest_kind, cid.dest) == (Dest.SYSTEM, SystemCode.ESTOP)


def test_heartbeats_report_a_silent_node_lost_and_back(bus: Bus) -> None:
    from asm_py.canbus.faults import FaultyBus

    faulty = FaultyBus(can.Bus(interface="virtual", channel=bus.channel))
    a = bus.node("a", 1, missed_heartbeats=4)  # the loss this test is about: 0.2 s, not FAST_BEATS' 2 s
    b = Node("b", CanTransport(2, bus=faulty, heartbeat_period=0.05, missed_heartbeats=4))
    events: list[tuple[str, bool]] = []
    a.on_discovery(lambda name, alive: events.append((name, alive)))
    try:
        assert wait_until(lambda: "b" in a.discover(), timeout=5)
        faulty.unplugged = True
        assert wait_until(lambda: ("b", False) in events, timeout=5)
        assert "b" not in a.discover()
        faulty.unplugged = False
        assert wait_until(lambda: events.count(("b", True)) >= 1 and events[-1] == ("b", True), timeout=5)
    finally:
        b.close()
        faulty.shutdown()


def test_subscription_by_source_and_object(bus: Bus) -> None:
    module = bus.node("m1", 1)
    other = bus.node("m2", 2)
    tool = bus.node("tool", 3)
    angle, decoy = Attribute("joint.angle", 0.0, codec="float32"), Attribute("joint.angle", 0.0, codec="float32")
    module.register(angle)
    other.register(decoy)
    angle.publish()
    decoy.publish()
    copy = Attribute("copy", codec="float32")
    copy.subscribe(tool.lookup("m1", "joint.angle", timeout=5))
    decoy.set(9.0)
    angle.set(1.5)
    assert wait_until(lambda: copy.peek() == 1.5, timeout=5)
    decoy.set(8.0)
    time.sleep(0.1)
    assert copy.peek() == 1.5
    copy.unsubscribe()


# -- hostile frames ----------------------------------------------------------------------------------------------


@pytest.fixture
def target() -> Iterator[tuple[Bus, Node, CanTransport]]:
    made = Bus()
    node = made.node("m1", 1, max_partials=4, max_message=512)
    node.register(Attribute("joint.angle", 0.5, codec="float32"))
    node.register(Attribute("fresh", sync_get=True, codec="int16"))
    yield made, node, node.transport  # type: ignore[misc]
    made.close()


frames = st.builds(
    lambda ident, data, fd: can.Message(arbitration_id=ident, data=data[: 64 if fd else 8], is_fd=fd),
    st.integers(0, (1 << 29) - 1) | st.builds(lambda s, f, c: CanId(3, 0, 1, s, f, c).pack(),
                                              st.integers(0, 255), st.integers(0, 3), st.integers(0, 63)),
    st.binary(max_size=64),
    st.booleans(),
)  # fmt: skip


@settings(max_examples=400, suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
@given(batch=st.lists(frames, max_size=20))
def test_random_frames_never_crash_a_node(target, batch: list[can.Message]) -> None:
    _, node, transport = target
    for frame in batch:
        transport.on_frame(frame)
    assert transport.reassembler.buffered_bytes <= transport.reassembler.bound
    assert transport.handler_errors == 0


def test_node_answers_after_random_frames_and_a_sender_killed_mid_message(target) -> None:
    made, node, transport = target
    raw = made.raw()
    try:
        for frame in itertools.islice(fragment(bytes(400)), 5):  # a 400-byte message that never finishes
            t, c, d = frame
            raw.send(can.Message(arbitration_id=CanId(5, 0, 1, 77, t, c).pack(), data=d))
        assert wait_until(lambda: transport.reassembler.partials == 1, timeout=5)
        assert wait_until(lambda: transport.reassembler.partials == 0, timeout=5)  # its timeout expired
        assert transport.reassembler.dropped.get("reassembly timeout") == 1
        tool = made.node("tool", 2)
        assert tool.lookup("m1", "joint.angle", timeout=5).get() == 0.5
    finally:
        raw.shutdown()


# -- golden vectors (tests/vectors/can_frames.json), shared with firmware implementations -------------------------

FRAME_VECTORS = json.loads((VECTORS / "can_frames.json").read_text())["frames"]


@pytest.mark.parametrize("vector", FRAME_VECTORS, ids=[v["name"][:40] for v in FRAME_VECTORS])
def test_golden_can_frames(vector: dict) -> None:
    message = bytes.fromhex(vector["message_hex"])
    size = 64 if vector["fd"] else 8
    parts = list(fragment(message, frame_size=size))
    priority = frame_priority(vector["priority"], len(parts))
    made = [{"id": f"{CanId(priority, vector['dest_kind'], vector['dest'], vector['source'], t, c).pack():08x}",
             "data": d.hex()} for t, c, d in parts]  # fmt: skip
    assert made == vector["frames"]
    r = Reassembler()
    out = []
    for frame in vector["frames"]:
        cid = CanId.unpack(int(frame["id"], 16))
        key = (cid.source, cid.dest_kind, cid.dest)
        out.append(r.feed(key, cid.frame, cid.counter, bytes.fromhex(frame["data"]), 0))
    assert out[-1] == message


def test_the_transport_puts_the_golden_frames_on_the_bus(bus: Bus) -> None:
    vector = next(v for v in FRAME_VECTORS if v["name"].startswith("lookup of"))
    node = bus.node("tool", vector["source"])
    bus.drain()
    node.transport.send_message(vector["dest_kind"], vector["dest"], bytes.fromhex(vector["message_hex"]),  # type: ignore[attr-defined]
                                vector["priority"])  # fmt: skip
    seen = [{"id": f"{f.arbitration_id:08x}", "data": bytes(f.data).hex()} for f in bus.drain() if not_heartbeat(f)]
    assert seen == vector["frames"]


def test_bus_configured_from_python_can_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    """With no interface given, python-can's own configuration (file or CAN_* environment) chooses the bus."""
    channel = f"asm-env-{os.getpid()}"
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", channel)
    module = Node("m1", CanTransport(1))
    tool = Node("tool", CanTransport(2, interface="virtual", channel=channel))
    try:
        module.register(Attribute("joint.angle", 0.5, codec="float32"))
        assert tool.lookup("m1", "joint.angle", timeout=5).get() == 0.5
        assert module.transport.bus.channel_info.endswith(channel)  # type: ignore[attr-defined]
    finally:
        tool.close()
        module.close()


def test_a_quiet_module_hears_only_what_it_must_act_on() -> None:
    """watch_bus=False: requests to it, broadcast requests and e-stops pass its filters; the other nodes'
    publications (fragmented ones too: a float64 takes two frames) and heartbeats do not, until it subscribes to
    something."""
    from asm_py import Attribute
    from asm_py.canbus.ids import Priority

    from ..helpers import wait_until

    channel = fresh_name("asm-quiet")
    options = {"interface": "asm_sim", "channel": channel, **FAST_BEATS}
    talker = Node("talker", CanTransport(1, **options))
    quiet = Node("quiet", CanTransport(2, watch_bus=False, **options))
    tool = Node("tool", CanTransport(3, **options))
    try:
        angle = Attribute("joint.angle", 0.0, codec="float32")
        talker.register(angle)
        angle.publish()
        tick = Attribute("gait.tick", 0.0, codec="float64")  # 12 bytes published: two frames at priority 7
        talker.register(tick)
        tick.publish()
        goal = Attribute("joint.goal", 0.0, codec="float32")
        quiet.register(goal)
        for k in range(20):
            angle.set(float(k))
            tick.set(k / 50)
        time.sleep(0.3)
        assert quiet.transport.frames_received == 0  # nobody's publications or heartbeats reached it
        assert wait_until(lambda: "quiet" in tool.discover())
        tool.lookup("quiet", "joint.goal", timeout=2).set(1.5, wait=True)  # a request to it
        tool.group().attribute("joint.goal", "float32").set(2.5)  # a broadcast request
        assert wait_until(lambda: goal.peek() == 2.5)
        stops: list[str] = []
        quiet.on_estop(lambda source, reason: stops.append(source))
        tool.estop("x")
        assert wait_until(lambda: stops == ["can.3"])  # it knows no names: the sender is can.<its ID>
        copy = Attribute("copy", codec="float32")
        copy.subscribe(quiet.lookup("can.1", "joint.angle", timeout=2))
        angle.set(42.0)
        assert wait_until(lambda: copy.peek() == 42.0)  # subscribing turned publications on
        ticks = Attribute("ticks", codec="float64")
        ticks.subscribe(quiet.lookup("can.1", "gait.tick", timeout=2))
        tick.set(7.25)
        assert wait_until(lambda: ticks.peek() == 7.25)  # fragmented ones too
        assert (Priority.PUBLICATION, Priority.BULK_PUBLICATION) == (4, 7)
    finally:
        for node in (tool, quiet, talker):
            node.close()


def test_peers_read_while_the_receive_thread_adds_and_drops_nodes() -> None:
    """A fresh-clone run (stop 49): peers() iterated the set of live node IDs while the receive thread added one,
    and raised "Set changed size during iteration". Here another thread adds and drops nodes as fast as it can."""
    import threading

    transport = CanTransport(7, interface="virtual", channel=fresh_name("peers"), **FAST_BEATS)
    transport.attach("seven", lambda source, data, respond=None: None)
    stop, failures = threading.Event(), []

    def churn() -> None:
        k = 0
        while not stop.is_set():
            transport._alive.add(10 + k % 200)
            transport._alive.discard(10 + (k + 100) % 200)
            k += 1

    thread = threading.Thread(target=churn)
    thread.start()
    try:
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            try:
                transport.peers()
            except RuntimeError as exc:
                failures.append(exc)
                break
    finally:
        stop.set()
        thread.join(5)
        transport.close()
    assert not failures, failures
