"""The hand-off of a node's Zenoh requests (asm_py/transport/zenoh_requests.py), without Zenoh: served in arrival
order on one thread, refused when the queue is full (never blocking the caller: Zenoh's thread), the waiting ones
dropped at close."""

from __future__ import annotations

import threading
import time
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

    queue = RequestQueue(serve, None, "m1 requests")
    try:
        for n in range(500):
            queue.put(_Query(n))
        assert wait_until(lambda: len(served) == 500, timeout=10)
        assert served == list(range(500)) and threads == {"asm-zenoh m1 requests"} and queue.refused == 0
    finally:
        queue.close()


def test_a_full_queue_refuses_at_once_and_close_drops_what_waits(monkeypatch) -> None:
    monkeypatch.setattr(zenoh_requests, "REQUEST_BACKLOG", 8)
    release, entered = threading.Event(), threading.Event()
    refused: list[int] = []

    def serve(query: Any) -> None:
        entered.set()
        release.wait(30)

    def refuse(query: Any, closed: bool) -> None:
        refused.append(query.n if not closed else -query.n)
        if query.n == 10:
            raise RuntimeError("a refusal that fails must not reach Zenoh's thread")

    queue = RequestQueue(serve, refuse, "m2 requests", discard=_Query.drop)
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
    assert refused[-1] == -99  # refused as closed
    assert wait_until(lambda: not any(t.name == "asm-zenoh m2 requests" for t in threading.enumerate()), timeout=10)


def test_close_drops_the_requests_still_waiting() -> None:
    release, entered = threading.Event(), threading.Event()
    served: list[int] = []

    def serve(query: Any) -> None:
        served.append(query.n)
        entered.set()
        release.wait(30)

    queue = RequestQueue(serve, None, "m3 requests", discard=_Query.drop)
    queue.put(_Query(0))
    assert entered.wait(10)
    waiting = [_Query(n) for n in range(1, 4)]
    for query in waiting:
        queue.put(query)
    began = time.monotonic()
    queue.close()  # at once: the thread inside a hung handler is not waited for
    assert time.monotonic() - began < 1 and all(q.dropped for q in waiting)
    assert any(t.name == "asm-zenoh m3 requests" for t in threading.enumerate())
    release.set()  # the handler returns: its thread ends, serving nothing more
    assert wait_until(lambda: not any(t.name == "asm-zenoh m3 requests" for t in threading.enumerate()), timeout=10)
    assert served == [0]


def test_a_handler_may_close_its_own_queue() -> None:
    closed = threading.Event()
    holder: list[RequestQueue] = []

    def serve(query: Any) -> None:
        holder[0].close()  # a request that ends the node: no join of its own thread
        closed.set()

    holder.append(RequestQueue(serve, None, "m4 requests"))
    holder[0].put(_Query(0))
    assert closed.wait(10)
    assert wait_until(lambda: not any(t.name == "asm-zenoh m4 requests" for t in threading.enumerate()), timeout=10)


def test_a_handler_that_raises_even_systemexit_does_not_end_the_serving() -> None:
    served: list[int] = []

    def serve(query: Any) -> None:
        served.append(query.n)
        if query.n == 0:
            raise SystemExit("a listener that exits once")
        if query.n == 1:
            raise KeyboardInterrupt

    queue = RequestQueue(serve, None, "m5 requests")
    try:
        for n in range(3):
            queue.put(_Query(n))
        assert wait_until(lambda: served == [0, 1, 2], timeout=10)
    finally:
        queue.close()


def test_puts_from_many_threads_never_pass_the_bound(monkeypatch) -> None:
    monkeypatch.setattr(zenoh_requests, "REQUEST_BACKLOG", 16)
    release, entered = threading.Event(), threading.Event()
    queue = RequestQueue(lambda q: (entered.set(), release.wait(30)), None, "m6 messages")
    try:
        queue.put(_Query(-1))
        assert entered.wait(10)
        threads = [threading.Thread(target=lambda: [queue.put(_Query(n)) for n in range(200)]) for _ in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(10)
        assert queue._queue.qsize() == 16 and queue.refused == 4 * 200 - 16
    finally:
        release.set()
        queue.close()
