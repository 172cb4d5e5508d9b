"""A node's Zenoh queryable runs on Zenoh's own thread (issue 31): a request served without user code or blocking
(a get, a lookup) is answered there, with no hand-off to a Python thread; any other (a set, whose change callbacks
may block or call other nodes) goes to the transport's worker thread, in order, so Zenoh's thread is never held."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from asm_py import Attribute, Node
from asm_py.node import Registrable

from ..helpers import wait_until
from ..transports import FACTORIES


@pytest.fixture
def trio() -> Iterator[tuple[Node, Node, Node]]:
    with FACTORIES["zenoh"]() as make:
        nodes = (Node("server", make()), Node("other", make()), Node("client", make()))
        try:
            names = {node.name for node in nodes}
            assert wait_until(lambda: all(names <= set(node.discover()) for node in nodes), timeout=10)
            yield nodes
        finally:
            for node in nodes:
                node.close()


def threads_serving(node: Node) -> list[tuple[int, threading.Thread]]:
    """Records (method, thread) for every request the node serves."""
    seen: list[tuple[int, threading.Thread]] = []
    original = node._on_message

    def spy(source: str, data: bytes, respond: object) -> None:
        seen.append((data[0] & 0x0F, threading.current_thread()))
        original(source, data, respond)  # type: ignore[arg-type]

    node.transport._on_message = spy  # type: ignore[attr-defined]
    return seen


def test_a_get_is_served_on_zenohs_own_thread_and_a_set_on_the_worker(trio) -> None:
    server, _, client = trio
    server.register(Attribute("goal", 1.5, codec="float32"))
    goal = client.lookup("server", "goal", timeout=5)
    seen = threads_serving(server)
    assert goal.get() == 1.5
    goal.set(2.5, wait=True)
    assert goal.get() == 2.5
    (get_method, get_thread), (_, set_thread), _ = seen
    assert isinstance(get_thread, threading._DummyThread), get_thread  # a thread Python did not start: Zenoh's
    assert set_thread.name == "asm-zenoh:server"


def test_a_set_whose_callback_calls_another_node_completes(trio) -> None:
    """The set's change callback makes a remote call: served on the worker, Zenoh's thread stays free to bring
    that call's reply."""
    server, other, client = trio
    other.register(Attribute("limit", 9.0, codec="float32"))
    limit = server.lookup("other", "limit", timeout=5)
    goal = Attribute("goal", 1.5, codec="float32")
    clamped: list[float] = []
    goal.on_change(lambda value: clamped.append(min(value, limit.get())))
    server.register(goal)
    remote = client.lookup("server", "goal", timeout=5)
    for value in (3.0, 12.0):
        remote.set(value, wait=True)
    assert clamped == [3.0, 9.0]


def test_a_get_behind_a_blocked_set_waits_for_it(trio) -> None:
    """Order: while a set's callback blocks on the worker, the same client's next get is not answered first."""
    server, _, client = trio
    release = threading.Event()
    goal = Attribute("goal", 1.5, codec="float32")
    goal.on_change(lambda value: release.wait(10))
    server.register(goal)
    remote = client.lookup("server", "goal", timeout=5)
    remote.set(4.0)  # no reply wanted: returns at once; its callback blocks on the worker
    got: list[float] = []
    reader = threading.Thread(target=lambda: got.append(remote.peek(timeout=10)))
    reader.start()
    assert not wait_until(lambda: got, timeout=0.5)  # the peek waits behind the set
    release.set()
    reader.join(10)
    assert got == [4.0]


def test_the_worker_ends_with_the_transport(trio) -> None:
    server, _, _ = trio
    assert any(t.name == "asm-zenoh:server" for t in threading.enumerate())
    server.close()
    assert wait_until(lambda: not any(t.name == "asm-zenoh:server" for t in threading.enumerate()), timeout=5)


def test_which_requests_are_served_inline(trio) -> None:
    server, _, _ = trio

    class Measured(Attribute):
        def get(self, timeout: float | None = None) -> object:  # a read that may do anything
            return super().get(timeout)

    entries: dict[str, Registrable] = {"plain": Attribute("plain", 1, codec="int32"), "measured": Measured("m")}
    ids = {name: server.register(obj) for name, obj in entries.items()}
    inline = server.server.inline

    def request(method: int, entry: str | None) -> bytes:
        found = ids[entry] if entry else None
        return bytes((0x50 | method, 1, found.class_id if found else 0, found.object_id if found else 0))

    assert inline(request(1, "plain"))  # GET
    assert inline(request(8, "plain"))  # STATUS
    assert not inline(request(1, "measured"))  # its get is its own code
    assert not inline(request(2, "plain"))  # SET: change callbacks
    assert inline(request(0, None))  # LOOKUP
    assert inline(bytes((0x51, 1, 0x99, 77)))  # a get of nothing: answered NOT_FOUND
