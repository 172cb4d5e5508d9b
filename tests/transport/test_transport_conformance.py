"""The conformance suite every transport passes: memory, Zenoh and CAN (python-can's virtual bus)."""

from __future__ import annotations

import threading
from collections.abc import Callable

import pytest

from asm_py.transport import Transport
from asm_py.transport.base import check_name

from ..helpers import wait_until
from ..transports import FACTORIES


class Inbox:
    """Records what a transport delivers to its node."""

    def __init__(self) -> None:
        self.messages: list[tuple[str, bytes]] = []
        self.responders: list[object] = []
        self.lock = threading.Lock()

    def __call__(self, source: str, data: bytes, respond: object) -> None:
        with self.lock:
            self.messages.append((source, data))
            self.responders.append(respond)


@pytest.fixture(params=sorted(FACTORIES))
def network(request):
    """A function that attaches a new transport under a name and returns (transport, inbox); all closed after."""
    opened: list[Transport] = []
    with FACTORIES[request.param]() as make:

        def attach(name: str) -> tuple[Transport, Inbox]:
            transport = make()
            inbox = Inbox()
            transport.attach(name, inbox)
            opened.append(transport)
            return transport, inbox

        yield attach
        for transport in opened:
            transport.close()


def connected(*transports: Transport) -> bool:
    names = {t.name for t in transports}
    return wait_until(lambda: all(names <= set(t.peers()) for t in transports), timeout=10)


def test_point_to_point_in_order(network: Callable) -> None:
    a, _ = network("a")
    b, inbox_b = network("b")
    assert connected(a, b)
    for i in range(100):
        a.send("b", bytes([0x40, i, 0, 0]))  # kind 0: a request that wants no reply
    assert wait_until(lambda: len(inbox_b.messages) == 100)
    assert inbox_b.messages == [("a", bytes([0x40, i, 0, 0])) for i in range(100)]


def test_groups_and_broadcast(network: Callable) -> None:
    a, inbox_a = network("a")
    b, inbox_b = network("b")
    c, inbox_c = network("c")
    assert connected(a, b, c)
    b.join_group("legs")
    c.join_group("legs")
    b.join_group("legs")  # joining twice is harmless
    assert b.groups == {"all", "legs"}
    payload = bytes([0x44, 0, 0x24, 0])
    # group subscriptions propagate asynchronously: send until both members have it
    assert wait_until(lambda: (a.send_group("legs", payload), inbox_b.messages and inbox_c.messages)[1], timeout=10)
    assert {m for m in inbox_b.messages} == {("a", payload)} == {m for m in inbox_c.messages}
    assert inbox_a.messages == []
    a.send_group("all", b"\x40\x01\x00\x00")
    assert wait_until(lambda: ("a", b"\x40\x01\x00\x00") in inbox_b.messages + inbox_c.messages)
    assert wait_until(lambda: ("a", b"\x40\x01\x00\x00") in inbox_c.messages)
    assert all(source != "a" for source, _ in inbox_a.messages), "a broadcast does not return to its sender"


def test_publish_subscribe(network: Callable) -> None:
    a, _ = network("a")
    b, _ = network("b")
    assert connected(a, b)
    received: list[bytes] = []
    remove = b.subscribe("a", "joint.angle", received.append, object_id=1)
    assert wait_until(
        lambda: (a.publish("joint.angle", b"\xf0\x00\x11\x01", lambda: '{"value": 1}'), received)[1], timeout=10
    )
    a.publish("other", b"\xf0\x00\x11\x02")
    remove()
    a.publish("joint.angle", b"\xf0\x01\x11\x01")
    assert not wait_until(lambda: set(received) != {b"\xf0\x00\x11\x01"}, timeout=0.5), received


def test_emergency_stop_reaches_every_node_and_the_sender(network: Callable) -> None:
    transports = [network(name)[0] for name in ("a", "b", "c")]
    assert connected(*transports)
    stops: dict[str, list[tuple[str, str]]] = {t.name: [] for t in transports}
    for t in transports:
        t.on_estop(lambda source, reason, name=t.name: stops[name].append((source, reason)))
    transports[1].estop("operator")
    assert wait_until(lambda: all(s == [("b", "operator")] for s in stops.values()), timeout=10), stops


def test_peers_and_discovery_events(network: Callable) -> None:
    a, _ = network("a")
    events: list[tuple[str, bool]] = []
    a.on_peer(lambda name, alive: events.append((name, alive)))
    b, _ = network("b")
    assert connected(a, b)
    assert {"a", "b"} <= set(a.peers())
    assert wait_until(lambda: ("b", True) in events)
    b.close()
    assert wait_until(lambda: ("b", False) in events, timeout=5)
    assert wait_until(lambda: "b" not in a.peers(), timeout=5)


def test_request_reply_path(network: Callable) -> None:
    """A request that wants a reply reaches the node with a way back: its responder or a plain send."""
    a, inbox_a = network("a")
    b, inbox_b = network("b")
    assert connected(a, b)
    request = bytes([0x51, 0x05, 0x11, 0x01])  # version 1, kind 1 (reply wanted), GET, txn 5
    reply = bytes([0x61, 0x05, 0x00, 0x01, 0x2A])
    if a.direct_requests:
        thread_result: list[bytes | None] = []
        t = threading.Thread(target=lambda: thread_result.append(a.request("b", request, 5.0)))
        t.start()
        assert wait_until(lambda: inbox_b.messages)
        respond = inbox_b.responders[0]
        assert callable(respond)
        respond(reply)
        t.join(5)
        assert thread_result == [reply]
        a.send("b", request)  # the message path works as well
        assert wait_until(lambda: len(inbox_b.messages) == 2)
        inbox_b.responders[1](reply)
    else:
        a.send("b", request)
        assert wait_until(lambda: inbox_b.messages)
        assert inbox_b.messages[0] == ("a", request) and inbox_b.responders[0] is None
        b.send("a", reply)
    assert wait_until(lambda: ("b", reply) in inbox_a.messages)


def test_a_failing_handler_does_not_break_the_transport(network: Callable) -> None:
    a, _ = network("a")
    b, inbox_b = network("b")
    assert connected(a, b)
    calls = {"n": 0}
    original = b._on_message

    def flaky(source: str, data: bytes, respond: object) -> None:
        calls["n"] += 1
        if calls["n"] == 1:
            raise RuntimeError("handler bug")
        original(source, data, respond)  # type: ignore[misc]

    b._on_message = flaky
    a.send("b", b"\x40\x00\x00\x01")
    a.send("b", b"\x40\x00\x00\x02")
    assert wait_until(lambda: inbox_b.messages == [("a", b"\x40\x00\x00\x02")])
    assert b.handler_errors == 1


def test_close_is_idempotent_and_names_are_checked(network: Callable) -> None:
    a, _ = network("a")
    a.close()
    a.close()
    for bad in ("", "a/b", "x*", "with space", "é", "n" * 65):
        with pytest.raises(ValueError):
            check_name(bad)
    with pytest.raises(RuntimeError):
        a.attach("again", lambda *args: None)
