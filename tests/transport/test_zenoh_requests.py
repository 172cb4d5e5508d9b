"""The hand-off of a node's Zenoh requests (asm_py/transport/zenoh_requests.py), without Zenoh: served in arrival
order on one thread, refused when the queue is full (never blocking the caller: Zenoh's thread), the waiting ones
dropped at close."""

from __future__ import annotations

import threading
from typing import Any

from asm_py.transport import zenoh_requests
from asm_py.transport.zenoh_requests import RequestQueue

from ..helpers import wait_until


class _Query:
    def __init__(self, n: int) -> None:
        self.n = n
        self.dropped = False

    def drop(self) -> None:
        self.dropped = True


def test_requests_are_served_in_arrival_order_on_one_thread() -> None:
    served: list[int] = []
    threads: set[str] = set()

    def serve(query: Any) -> None:
        threads.add(threading.current_thread().name)
        served.append(query.n)

    queue = RequestQueue(serve, lambda q: None, "m1")
    try:
        for n in range(500):
            queue.put(_Query(n))
        assert wait_until(lambda: len(served) == 500, timeout=10)
        assert served == list(range(500)) and threads == {"asm-zenoh requests m1"} and queue.refused == 0
    finally:
        queue.close()


def test_a_full_queue_refuses_at_once_and_close_drops_what_waits(monkeypatch) -> None:
    monkeypatch.setattr(zenoh_requests, "REQUEST_BACKLOG", 8)
    release, entered = threading.Event(), threading.Event()
    refused: list[int] = []

    def serve(query: Any) -> None:
        entered.set()
        release.wait(30)

    def refuse(query: Any) -> None:
        refused.append(query.n)
        if query.n == 10:
            raise RuntimeError("a refusal that fails must not reach Zenoh's thread")

    queue = RequestQueue(serve, refuse, "m2", discard=_Query.drop)
    first = _Query(0)
    queue.put(first)
    assert entered.wait(10)  # the handler hangs on the first
    waiting = [_Query(n) for n in range(1, 9)]
    for query in waiting:
        queue.put(query)
    done = threading.Event()
    threading.Thread(target=lambda: ([queue.put(_Query(n)) for n in range(9, 12)], done.set())).start()
    assert done.wait(5)  # never blocked
    assert refused == [9, 10, 11] and queue.refused == 3
    release.set()
    queue.close()
    assert not first.dropped  # the one being served is its handler's to end
    late = _Query(99)
    queue.put(late)
    assert refused[-1] == 99  # refused once closed
    assert not any(t.name == "asm-zenoh requests m2" for t in threading.enumerate())


def test_close_drops_the_requests_still_waiting() -> None:
    release, entered = threading.Event(), threading.Event()
    served: list[int] = []

    def serve(query: Any) -> None:
        served.append(query.n)
        entered.set()
        release.wait(30)

    queue = RequestQueue(serve, None, "m3", discard=_Query.drop)
    queue.put(_Query(0))
    assert entered.wait(10)
    waiting = [_Query(n) for n in range(1, 4)]
    for query in waiting:
        queue.put(query)
    closer = threading.Thread(target=queue.close)
    closer.start()
    assert wait_until(lambda: all(q.dropped for q in waiting), timeout=10)
    release.set()
    closer.join(10)
    assert served == [0] and not closer.is_alive()


def test_a_handler_may_close_its_own_queue() -> None:
    closed = threading.Event()
    holder: list[RequestQueue] = []

    def serve(query: Any) -> None:
        holder[0].close()  # a request that ends the node: no join of its own thread
        closed.set()

    holder.append(RequestQueue(serve, lambda q: None, "m4"))
    holder[0].put(_Query(0))
    assert closed.wait(10)
    assert wait_until(lambda: not any(t.name == "asm-zenoh requests m4" for t in threading.enumerate()), timeout=10)
