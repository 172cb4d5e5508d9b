"""What a node's Zenoh queryable promises whatever thread serves it (issue 31 measured serving on Zenoh's own thread,
and kept zenoh-python's Python thread): a set whose change callback calls another node completes (Zenoh's network
thread is not held), and a client's get behind its blocked set waits for it (requests are served in order)."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from asm_py import Attribute, Node

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
