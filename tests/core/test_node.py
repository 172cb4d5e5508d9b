"""The node's server side: registration, lookups by name and ID, status codes, daemons, and hostile input."""

from __future__ import annotations

import threading
from collections.abc import Callable

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from asm_py import Attribute, Event, RemoteError, Service
from asm_py.clock import SimClock
from asm_py.node import Node
from asm_py.protocol import Kind, Message, Method, Status, decode, encode
from asm_py.transport import MemoryNetwork, MemoryTransport

from ..helpers import mutations, wait_until


class Idle(Service):
    def run(self) -> None:
        while self.sleep(0.01):
            pass


@pytest.fixture
def world():
    network = MemoryNetwork()
    server = Node("module", MemoryTransport(network), max_daemons_per_client=3)
    client = Node("client", MemoryTransport(network))
    objects = {
        "angle": Attribute("joint.angle", 0.5, codec="float32"),
        "fresh": Attribute("fresh", sync_get=True, codec="int16"),
        "contact": Event("sensor.contact", codec="bool"),
        "idle": Idle("idle"),
    }
    for obj in objects.values():
        server.register(obj)
    yield server, client, objects
    client.close()
    server.close()
    objects["idle"].stop(timeout=5)


def test_registration_gives_class_and_object_ids(world) -> None:
    server, _, objects = world
    angle = server.entry("joint.angle")
    assert (angle.class_id, angle.object_id) == (0x11, 1)  # a well-known class: the same on every module
    fresh = server.entry("fresh")
    assert fresh.class_id >= 0x80 and fresh.object_id == 2
    assert server.entry(2) is fresh
    with pytest.raises(ValueError):
        server.register(Attribute("fresh"))
    with pytest.raises(LookupError):
        server.entry("nothing")
    with pytest.raises(TypeError):
        server.register(object())  # type: ignore[arg-type]
    other = Attribute("second.angle", codec="float32")
    assert server.register(other, class_name="joint.angle").class_id == 0x11


def test_lookup_by_name_and_listing(world) -> None:
    _, client, _ = world
    angle = client.lookup("module", "joint.angle", timeout=5)
    assert angle.codec.spec == "float32" and angle.info.class_name == "joint.angle"
    names = [obj.name for obj in client.list_objects("module", timeout=5)]
    assert names == ["joint.angle", "fresh", "sensor.contact", "idle"]
    with pytest.raises(LookupError):
        client.lookup("module", "missing", timeout=5)


def test_unsupported_methods_and_stale_ids(world) -> None:
    server, client, _ = world
    idle = client.lookup("module", "idle", timeout=5)
    port = client.port("module")
    with pytest.raises(RemoteError) as info:
        port.call(Method.GET, idle.info.class_id, idle.info.object_id, timeout=5)
    assert info.value.status == Status.UNSUPPORTED
    with pytest.raises(LookupError, match="class"):
        port.call(Method.GET, 0x42, 1, timeout=5)  # object 1 exists but is not of class 0x42: stale client
    with pytest.raises(LookupError):
        port.call(Method.GET, 0x11, 200, timeout=5)


def test_a_blocking_get_does_not_stall_other_clients_or_objects(world) -> None:
    server, client, objects = world
    other = Node("other", MemoryTransport(server.transport.network))  # type: ignore[attr-defined]
    try:
        fresh = client.lookup("module", "fresh", timeout=5)
        box: list[int] = []
        blocked = threading.Thread(target=lambda: box.append(fresh.get(timeout=10)))
        blocked.start()
        assert wait_until(lambda: server.server._daemons.get("client"))
        angle_from_client = client.lookup("module", "joint.angle", timeout=5)
        assert angle_from_client.get(timeout=2) == 0.5, "the same client's other object is served"
        fresh_from_other = other.lookup("module", "fresh", timeout=5)
        fresh_from_other.set(9, wait=True)
        blocked.join(10)
        assert box == [9]
    finally:
        other.close()


def test_daemons_per_client_are_bounded(world) -> None:
    server, client, _ = world
    fresh = client.lookup("module", "fresh", timeout=5)
    errors: list[BaseException] = []

    def blocked_get() -> None:
        try:
            fresh.get(timeout=5)
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=blocked_get) for _ in range(3)]
    for t in threads:
        t.start()
    assert wait_until(lambda: len(server.server._daemons.get("client", ())) == 3)
    with pytest.raises(RemoteError) as info:
        fresh.get(timeout=5)
    assert info.value.status == Status.BUSY
    server.close()  # closing interrupts the daemons; their callers see the failure, not a hang
    for t in threads:
        t.join(10)
    assert not any(t.is_alive() for t in threads)
    assert len(errors) == 3


def test_event_waits_hold_no_thread_each(world) -> None:
    """Pending WAITs are listeners with deadlines: three of them cost at most the node's one timing thread."""
    server, client, objects = world
    contact = client.lookup("module", "sensor.contact", timeout=5)
    results: list[object] = []

    def wait_for_contact(timeout: float) -> None:
        try:
            results.append(contact.waiting(timeout=timeout))
        except BaseException as exc:
            results.append(exc)

    baseline = threading.active_count()
    listeners = objects["contact"]._listeners  # its publisher's
    waiters = [threading.Thread(target=wait_for_contact, args=(30,)) for _ in range(3)]
    for t in waiters:
        t.start()
    assert wait_until(lambda: len(server.server._daemons.get("client", ())) == 3)
    assert threading.active_count() <= baseline + len(waiters) + 1  # the callers' threads, and one for the node
    with pytest.raises(RemoteError) as info:
        contact.waiting(timeout=5)
    assert info.value.status == Status.BUSY  # the per-client cap counts waits
    objects["contact"].set(True)  # one firing answers every pending wait, once
    for t in waiters:
        t.join(10)
    assert results == [True, True, True]
    assert wait_until(lambda: not server.server._daemons.get("client"))
    objects["contact"].set(False)
    assert results == [True, True, True]
    assert objects["contact"]._listeners == listeners, "an answered wait leaves no listener on the event"
    assert not server.server._waits._timed, "nor a deadline behind it: what a node keeps is bounded by what it admits"

    wait_for_contact(0.3)
    assert isinstance(results[-1], TimeoutError), "a wait that sees no firing ends at its deadline"
    assert wait_until(lambda: not server.server._daemons.get("client"))
    assert objects["contact"]._listeners == listeners


def test_wait_deadlines_run_on_the_node_clock() -> None:
    """On a SimClock a pending WAIT ends exactly when simulated time passes its deadline, not on the wall."""
    network = MemoryNetwork()
    clock = SimClock()
    server = Node("module", MemoryTransport(network), clock=clock)
    client = Node("client", MemoryTransport(network))
    contact = Event("sensor.contact", codec="bool", clock=clock)
    server.register(contact)
    box: list[BaseException] = []
    try:
        remote = client.lookup("module", "sensor.contact", timeout=5)
        waiter = threading.Thread(target=lambda: _catch(box, lambda: remote.waiting(timeout=60)))
        waiter.start()
        assert wait_until(lambda: server.server._daemons.get("client"))
        clock.advance(59.0)
        assert server.server._daemons.get("client"), "59 s of 60 simulated: still waiting"
        clock.advance(2.0)
        assert wait_until(lambda: not server.server._daemons.get("client"))
        waiter.join(10)
        assert box and isinstance(box[0], TimeoutError)
    finally:
        client.close()
        server.close()


def _catch(box: list[BaseException], call: Callable[[], object]) -> None:
    try:
        call()
    except BaseException as exc:
        box.append(exc)


@pytest.mark.parametrize("name", ["fresh", "sensor.contact"])  # a daemon's get, a thread-less wait
def test_peer_gone_fails_calls_within_their_deadline(world, name: str) -> None:
    server, client, objects = world
    remote = client.lookup("module", name, timeout=5)
    box: list[BaseException] = []
    listeners = objects["contact"]._listeners
    waiter = threading.Thread(target=lambda: _catch(box, remote.waiting if name == "sensor.contact" else remote.get))
    waiter.start()
    assert wait_until(lambda: server.server._daemons.get("client"))
    server.close()
    waiter.join(5)
    assert box and isinstance(box[0], TimeoutError)
    assert set(objects["contact"]._listeners) <= set(listeners), "a forgotten wait leaves no listener"
    with pytest.raises(TimeoutError):
        client.lookup("module", "joint.angle", timeout=0.3)


VALID = [
    encode(Message(Kind.REQUEST_REPLY, Method.LOOKUP, 1, 0, 0, data=b"joint.angle")),
    encode(Message(Kind.REQUEST_REPLY, Method.GET, 2, 0x11, 1)),
    encode(Message(Kind.REQUEST_REPLY, Method.SET, 3, 0x11, 1, data=b"\x00\x00\x80\x3f")),
    encode(Message(Kind.REQUEST_REPLY, Method.START, 4, 0x83, 4, data=b"[]")),
    encode(Message(Kind.REQUEST_REPLY, Method.WAIT, 5, 0x82, 3, timeout=1)),
]


@settings(max_examples=300, suppress_health_check=[HealthCheck.function_scoped_fixture], deadline=None)
@given(data=st.binary(max_size=48) | mutations(VALID))
def test_hostile_input_gets_an_error_reply_or_is_dropped(world, data: bytes) -> None:
    server, _, _ = world
    replies: list[bytes] = []
    server._on_message("fuzzer", data, replies.append)
    for raw in replies:
        reply = decode(raw)
        assert reply.kind == Kind.REPLY


def test_still_answers_after_hostile_input(world) -> None:
    server, client, objects = world
    for data in [*VALID, b"\xff" * 9, b"", b"\x51", bytes(range(40))]:
        server._on_message("fuzzer", data, lambda reply: None)
    angle = client.lookup("module", "joint.angle", timeout=5)
    objects["angle"].set(2.0)
    assert angle.get(timeout=5) == 2.0
