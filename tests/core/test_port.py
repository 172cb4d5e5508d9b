"""The client port's ways of completing a call (issue 31 made a caller outside a service thread wait on a lock of
its own): a reply, a deadline, a peer that left, a stopped service, and all 128 transaction IDs in use.

The remote is a bare transport whose handler keeps the requests; the test answers them by hand, in any order.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest

from asm_py import Service
from asm_py.errors import AsmTimeout
from asm_py.node import Node
from asm_py.protocol import MAX_TXN, Kind, Method, Status, decode, first_byte
from asm_py.transport import MemoryNetwork, MemoryTransport
from asm_py.transport.base import Responder

from ..helpers import run_in_thread, wait_until

CLASS_ID, OBJECT_ID = 0x11, 3


class Silent:
    """A remote node that answers only when the test tells it to."""

    def __init__(self, network: MemoryNetwork) -> None:
        self.transport = MemoryTransport(network)
        self.requests: list[bytes] = []
        self._lock = threading.Lock()
        self.transport.attach("silent", self._keep)

    def _keep(self, source: str, data: bytes, respond: Responder | None) -> None:
        with self._lock:
            self.requests.append(data)

    def answer(self, request: bytes, data: bytes) -> None:
        message = decode(request)
        reply = bytes((first_byte(Kind.REPLY, message.method), message.txn, Status.OK, message.object_id)) + data
        self.transport.send("client", reply)


@pytest.fixture
def pair() -> Iterator[tuple[Node, Silent]]:
    network = MemoryNetwork()
    client = Node("client", MemoryTransport(network))
    silent = Silent(network)
    yield client, silent
    client.close()
    silent.transport.close()


def get(client: Node, timeout: float) -> bytes:
    return client.port("silent").call(Method.GET, CLASS_ID, OBJECT_ID, timeout=timeout).data


def test_a_reply_completes_the_call_with_its_data(pair) -> None:
    client, silent = pair
    thread, box = run_in_thread(get, client, 30.0)
    assert wait_until(lambda: len(silent.requests) == 1)
    request = decode(silent.requests[0])
    assert (request.kind, request.method, request.class_id, request.object_id) == (
        Kind.REQUEST_REPLY, Method.GET, CLASS_ID, OBJECT_ID)  # fmt: skip
    silent.answer(silent.requests[0], b"\x01\x02")
    thread.join(10)
    assert box == {"result": b"\x01\x02"}
    assert client.port("silent")._pending == {}


def test_no_reply_times_out_at_its_deadline_and_frees_the_transaction(pair) -> None:
    client, silent = pair
    began = time.monotonic()
    with pytest.raises(AsmTimeout, match=r"no reply within 0\.3s"):
        get(client, 0.3)
    assert 0.25 <= time.monotonic() - began < 10
    assert client.port("silent")._pending == {}
    silent.answer(silent.requests[0], b"late")  # the caller gave up: a late reply is counted, not delivered
    assert wait_until(lambda: client.port("silent").stale_replies == 1)


def test_a_peer_that_leaves_fails_the_call_at_once(pair) -> None:
    client, silent = pair
    thread, box = run_in_thread(get, client, 60.0)
    assert wait_until(lambda: len(silent.requests) == 1)
    began = time.monotonic()
    client.port("silent").fail_all("node 'silent' left")
    thread.join(10)
    assert time.monotonic() - began < 10
    assert isinstance(box.get("error"), AsmTimeout) and "left" in str(box["error"])


def test_stop_interrupts_a_service_waiting_for_a_reply(pair) -> None:
    client, silent = pair
    ended: list[str] = []

    class Caller(Service):
        def run(self, *params: object) -> None:
            try:
                get(client, 60.0)
            finally:
                ended.append("finally ran")

    service = Caller("caller")
    service.start()
    assert wait_until(lambda: len(silent.requests) == 1 and service._blocked_on is not None)
    service.stop(timeout=10)
    assert ended == ["finally ran"]
    assert service.last_error is None, "an interrupted remote call is a stop, not a failure"
    assert client.port("silent")._pending == {}


def test_a_caller_beyond_the_transaction_ids_waits_for_one_to_free(pair) -> None:
    client, silent = pair
    calls = [run_in_thread(get, client, 60.0) for _ in range(MAX_TXN + 2)]
    assert wait_until(lambda: len(silent.requests) == MAX_TXN + 1, timeout=30)
    assert len(client.port("silent")._pending) == MAX_TXN + 1
    time.sleep(0.2)  # a negative check: the last caller must not have sent anything
    assert len(silent.requests) == MAX_TXN + 1
    first = silent.requests[0]
    silent.answer(first, bytes((decode(first).txn,)))
    assert wait_until(lambda: len(silent.requests) == MAX_TXN + 2, timeout=30), "a freed ID lets the last one send"
    for request in silent.requests[1:]:
        silent.answer(request, bytes((decode(request).txn,)))
    for thread, _ in calls:
        thread.join(30)
    results = sorted(box["result"][0] for _, box in calls)
    txns = sorted(decode(r).txn for r in silent.requests)
    assert results == txns, "each caller got the reply to its own transaction"
    assert client.port("silent")._pending == {}
