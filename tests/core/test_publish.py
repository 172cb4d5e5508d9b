"""Publish/subscribe: the server's policies on the simulation clock, and the subscriber side."""

from __future__ import annotations

import json
import math
import threading

import pytest

from asm_py import Attribute, SimClock
from asm_py.node import Node
from asm_py.publisher import distance
from asm_py.transport import MemoryNetwork, MemoryTransport

from ..helpers import wait_until


@pytest.fixture
def pair():
    """A publishing node on a simulation clock and a subscribing node, on an in-memory network."""
    clock = SimClock()
    network = MemoryNetwork()
    server = Node("module", MemoryTransport(network), clock=clock)
    client = Node("monitor", MemoryTransport(network))
    yield clock, server, client
    client.close()
    server.close()


def subscribed_copy(server: Node, client: Node, attr: Attribute) -> tuple[Attribute, list]:
    server.register(attr)
    remote = client.lookup("module", attr.name, timeout=5)
    copy = Attribute(f"copy.{attr.name}", codec=attr.codec)
    received: list = []
    copy.on_change(received.append)
    copy.subscribe(remote)
    return copy, received


def test_every_set_without_policy_arguments(pair) -> None:
    clock, server, client = pair
    angle = Attribute("joint.angle", 0.0, codec="float32")
    copy, received = subscribed_copy(server, client, angle)
    angle.publish()
    for value in (1.0, 1.0, 2.5, -3.0):
        angle.set(value)
    assert wait_until(lambda: len(received) == 4)
    assert received == [1.0, 1.0, 2.5, -3.0]
    assert copy.valid and copy.get(timeout=1) == -3.0


def test_deadband(pair) -> None:
    clock, server, client = pair
    angle = Attribute("joint.angle", 0.0, codec="float32")
    _, received = subscribed_copy(server, client, angle)
    angle.publish(deadband=1.0)
    for value in (0.0, 0.5, 1.25, 1.5, 2.5, 2.0, -1.0):
        angle.set(value)
    assert wait_until(lambda: len(received) == 4)
    assert received == [0.0, 1.25, 2.5, -1.0]


def test_fixed_rate_on_the_simulation_clock(pair) -> None:
    clock, server, client = pair
    angle = Attribute("joint.angle", 0.0, codec="float32")
    _, received = subscribed_copy(server, client, angle)
    angle.publish(rate=10)
    publisher = server.entry("joint.angle").publisher
    angle.set(5.0)
    angle.set(6.0)  # changes are not published by themselves at a fixed rate
    clock.advance(0.05)
    assert publisher.published == 0
    clock.advance(0.05)
    assert publisher.published == 1
    angle.set(7.0)
    clock.advance(0.9)
    assert publisher.published == 10
    assert wait_until(lambda: len(received) == 10)
    assert received == [6.0] + [7.0] * 9


@pytest.mark.parametrize("deadband", [None, 0.5])
def test_an_event_never_fired_publishes_nothing_at_its_rate_and_its_timer_lives_on(pair, deadband, caplog) -> None:
    """Reproduces a defect: gait.tick's once-a-second refresh before the first tick encoded None (struct.error),
    which ended the refresh for good."""
    from asm_py import Event

    clock, server, client = pair
    tick = Event("gait.tick", codec="float64")
    _, received = subscribed_copy(server, client, tick)
    tick.publish(rate=10, deadband=deadband)
    publisher = server.entry("gait.tick").publisher
    clock.advance(0.35)
    assert publisher.published == 0 and "failed" not in caplog.text
    tick.set(1.5)
    clock.advance(0.5)
    assert publisher.published >= 4 if deadband is None else publisher.published >= 1
    assert wait_until(lambda: received and received[-1] == 1.5)


def test_deadband_with_minimum_rate(pair) -> None:
    clock, server, client = pair
    angle = Attribute("joint.angle", 0.0, codec="float32")
    _, received = subscribed_copy(server, client, angle)
    angle.publish(rate=2, deadband=1.0)
    times: list[float] = []
    publisher = server.entry("joint.angle").publisher
    original = publisher.publish
    publisher.publish = lambda value: (times.append(round(clock.now(), 6)), original(value))  # type: ignore[method-assign]
    clock.advance(0.2)
    angle.set(3.0)  # a large change: published at once (t = 0.2)
    clock.advance(0.1)
    angle.set(3.2)  # small: not published
    clock.advance(1.0)  # refreshes one period after the last publication: 0.7, 1.2
    assert times == [0.2, 0.7, 1.2]
    assert wait_until(lambda: len(received) == 3)
    assert received == pytest.approx([3.0, 3.2, 3.2])


def test_a_limit_spaces_the_publications_of_a_fast_change(pair) -> None:
    clock, server, client = pair
    angle = Attribute("joint.angle", 0.0, codec="float32")
    _, received = subscribed_copy(server, client, angle)
    angle.publish(rate=2, deadband=0.1, limit=20)  # at most one every 0.05 s
    times: list[float] = []
    publisher = server.entry("joint.angle").publisher
    original = publisher.publish
    publisher.publish = lambda value: (times.append(round(clock.now(), 6)), original(value))  # type: ignore[method-assign]
    for k in range(1, 11):  # a joint moving at every 0.02 s control tick
        clock.advance(0.02)
        angle.set(float(k))
    clock.advance(0.6)  # the last value, 10, also comes with the refresh 0.5 s after the last publication
    assert times == [0.02, 0.08, 0.14, 0.2, 0.7]
    assert wait_until(lambda: len(received) == 5)
    assert received == pytest.approx([1.0, 4.0, 7.0, 10.0, 10.0])


def test_policy_can_change_and_stop(pair) -> None:
    clock, server, client = pair
    angle = Attribute("joint.angle", 0.0, codec="float32")
    angle.publish(rate=5)  # before registration: applied when registered
    _, received = subscribed_copy(server, client, angle)
    clock.advance(1.0)
    assert server.entry("joint.angle").publisher.published == 5
    angle.publish()
    angle.set(1.0)
    angle.unpublish()
    angle.set(2.0)
    clock.advance(1.0)
    assert wait_until(lambda: len(received) == 6)
    assert not wait_until(lambda: len(received) > 6, timeout=0.2)
    assert received[-1] == 1.0


def test_subscription_wakes_sync_get_waiters_and_unsubscribe(pair) -> None:
    clock, server, client = pair
    angle = Attribute("joint.angle", 0.0, codec="float32")
    server.register(angle)
    angle.publish()
    remote = client.lookup("module", "joint.angle", timeout=5)
    copy = Attribute("angle.copy", sync_get=True, codec="float32")
    copy.subscribe(remote)
    got: list[float] = []

    def read_three() -> None:
        for _ in range(3):
            got.append(copy.get(timeout=10))

    reader = threading.Thread(target=read_three)
    reader.start()
    for value in (1.0, 2.0, 3.0):
        angle.set(value)
        assert wait_until(lambda v=value: v in got, timeout=5)
    reader.join(10)
    assert got == [1.0, 2.0, 3.0]
    copy.unsubscribe()
    angle.set(4.0)
    assert not wait_until(lambda: copy.valid, timeout=0.2)


def test_subscriber_type_must_match(pair) -> None:
    clock, server, client = pair
    server.register(Attribute("joint.angle", 0.0, codec="float32"))
    remote = client.lookup("module", "joint.angle", timeout=5)
    with pytest.raises(TypeError):
        Attribute("wrong", codec="int8").subscribe(remote)


def test_bad_policies_are_refused() -> None:
    attr = Attribute("x")
    for kwargs in (
        {"rate": 0},
        {"rate": -1},
        {"rate": math.inf},
        {"deadband": -0.1},
        {"deadband": math.nan},
        {"limit": 10},
        {"deadband": 0.1, "limit": 0},
    ):
        with pytest.raises(ValueError):
            attr.publish(**kwargs)


def test_distance() -> None:
    assert distance(1.0, 3.5) == 2.5
    assert distance((0.0, 1.0), (0.5, -1.0)) == 2.0
    assert distance({"a": 1, "b": 2}, {"a": 1, "b": 5}) == 3
    assert distance("x", "y") == math.inf and distance("x", "x") == 0.0
    assert distance(math.nan, math.nan) == 0.0


@pytest.mark.parametrize(
    ("codec", "deadband", "values"),
    [
        ("float64", 0.5, [0.0, math.nan, math.nan, 1.0, 1.25, math.inf, math.inf, -math.inf, 5.0, 5.5, 5.75, -0.0]),
        ("uint16", 0, [0, 0, 3, 3, 4, 65535, 65535, 0]),
        ("int32", 2, [0, 1, 3, 6, 4, 7, -7]),
    ],
)
def test_a_deadband_publishes_exactly_what_distance_says(codec: str, deadband: float, values: list) -> None:
    """The publisher's shortcut for two numbers (issue 31) decides as distance() does, NaNs and infinities too."""
    sent: list = []

    class Recording(MemoryTransport):
        def publish(self, object_name: str, data: bytes, json_text=None) -> None:
            sent.append(data)

    node = Node("module", Recording(MemoryNetwork()))
    try:
        attr = Attribute("x", codec=codec)
        node.register(attr)
        attr.publish(deadband=deadband)
        expected, last = 0, None
        for value in values:
            attr.set(value)
            if last is None or not distance(last, value) <= deadband:  # (a NaN distance publishes)
                expected, last = expected + 1, value
            assert len(sent) == expected, f"after {value!r} (last published {last!r})"
    finally:
        node.close()


def test_json_view_of_publications() -> None:
    seen: list[str] = []

    class Recording(MemoryTransport):
        def publish(self, object_name: str, data: bytes, json_text=None) -> None:
            seen.append(json_text() if json_text is not None else "")
            super().publish(object_name, data, json_text)

    node = Node("module", Recording(MemoryNetwork()))
    try:
        pose = Attribute("pose", (0.0, 0.0, 0.0), codec="float32[3]")
        node.register(pose)
        pose.publish()
        pose.set((1.0, 2.0, 0.5))
        view = json.loads(seen[-1])
        assert view["node"] == "module" and view["object"] == "pose" and view["value"] == [1.0, 2.0, 0.5]
    finally:
        node.close()


@pytest.mark.parametrize("spec, value", [("float32", -2.5), ("float64", 1e300), ("int8", -128), ("uint16", 65535),
                                         ("int32", -7), ("uint64", 2**64 - 1), ("bool", True)])  # fmt: skip
def test_numbers_arrive_whole_and_malformed_publications_are_dropped(pair, spec, value) -> None:
    """A number's publication is unpacked in place (Codec.plain_struct, issue 31): what it delivers must be what
    the general decoding delivers, and what that drops it must drop — a short or long value, another kind's first
    byte, a timeout flag."""
    clock, server, client = pair
    attr = Attribute("x", codec=spec)
    copy, received = subscribed_copy(server, client, attr)
    attr.publish()
    good = bytes([0x7B, 1, 0, 0]) + attr.codec.encode(value)
    for bad in (good[:-1], good + b"\x00", bytes([0x7A]) + good[1:], good[:1] + bytes([good[1] | 0x80]) + good[2:],
                good[:3]):  # fmt: skip
        server.transport.publish("x", bad)
    server.transport.publish("x", good)
    assert wait_until(lambda: len(received) == 1)
    attr.set(value)
    assert wait_until(lambda: len(received) == 2)
    assert received == [value, value] and type(received[0]) is type(value)
    assert copy.get(timeout=1) == value


def test_an_untyped_attribute_subscribes_to_a_typed_one(pair) -> None:
    clock, server, client = pair
    attr = Attribute("x", codec="float32")
    server.register(attr)
    copy = Attribute("copy")
    received: list = []
    copy.on_change(received.append)
    copy.subscribe(client.lookup("module", "x", timeout=5))
    attr.publish()
    attr.set(0.1)  # float32's 0.1, as the source holds it
    assert wait_until(lambda: len(received) == 1)
    assert received == [attr.peek()] != [0.1]


def test_a_checked_attribute_checks_what_a_publication_brings(pair) -> None:
    """CheckedAttribute's promise (every value, however it arrives, passes its check) holds for publications: the
    delivery's fast path (issue 31) once stored a published 5.0 past a clamp to 1.0 and past a refusal."""
    from asm_py.attribute import CheckedAttribute

    clock, server, client = pair
    source = Attribute("goal", 0.0, codec="float32")
    server.register(source)
    remote = client.lookup("module", "goal", timeout=5)

    def refuse(value: float) -> float:
        if value > 1.0:
            raise ValueError("too far")
        return value

    clamped = CheckedAttribute("clamped", 0.0, codec="float32", check=lambda v: min(v, 1.0))
    refusing = CheckedAttribute("refusing", 0.0, codec="float32", check=refuse)
    seen: list = []
    for copy in (clamped, refusing):
        copy.on_change(seen.append)
        copy.subscribe(remote)
    source.publish()
    source.set(0.5)
    assert wait_until(lambda: seen.count(0.5) == 2)
    source.set(5.0)
    assert wait_until(lambda: clamped.peek() == 1.0, timeout=5), clamped.peek()
    assert refusing.peek() == 0.5
    source.set(0.25)  # a refusal ends nothing: the next publication arrives
    assert wait_until(lambda: refusing.peek() == 0.25 and clamped.peek() == 0.25, timeout=5)


def test_the_publication_count_is_exact_under_concurrent_sets() -> None:
    """``published`` is read from the sequence counter every publication takes a number from (stop 47): four
    threads' 20,000 sets are 20,000 publications, past many wraps of the 8-bit sequence number."""
    node = Node("module", MemoryTransport(MemoryNetwork()))
    try:
        attribute = Attribute("x", 0.0, codec="float32")
        node.register(attribute)
        attribute.publish()
        publisher = node.entry("x").publisher
        assert publisher is not None and publisher.published == 0

        def setter() -> None:
            for i in range(5000):
                attribute.set(float(i))

        threads = [threading.Thread(target=setter) for _ in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        assert publisher.published == 20000
    finally:
        node.close()
