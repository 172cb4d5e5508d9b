"""A node's Zenoh requests, handed to the node's own thread without ever blocking Zenoh's receiving.

zenoh-python's default for a queryable's Python callback is a channel of 256 to a Python thread, and a full channel
blocks the sender: Zenoh's receive task. A request handler that hangs (a set whose change listener waits on
something) then stopped the node's whole session after 256 more requests — every reply and every e-stop on that
link (tests/transport/test_zenoh_hung_handlers.py). Dropping what does not fit (as a publication's ring does) is
not an answer for requests: a set lost without its sender knowing, a caller left waiting for a reply that will
never come.

So the queryable's callback never blocks (it only appends), the requests wait in a queue of ``REQUEST_BACKLOG`` in
arrival order for the node's request thread, and a request that finds the queue full is refused there and then:
one that wants a reply gets BUSY at once, one that wants none is dropped and counted (its sender asked for no
answer; a log line says so, at most one a second).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Generic, TypeVar

import zenoh

from ..protocol import HEADER_SIZE, Kind, Status, kind_of, reply_head

log = logging.getLogger("asm_py.transport.zenoh")

Item = TypeVar("Item")

REQUEST_BACKLOG = 1024
"""Requests a node holds for its request thread; one more is refused (BUSY) rather than block Zenoh's thread."""


class RequestQueue(Generic[Item]):
    """The hand-off: ``put`` on zenoh-python's thread, ``serve`` on the node's request thread, in arrival order.
    An item is a query (a request) or a sample (a message to the node or one of its groups: a group's set or call);
    each subscription has a queue and a thread of its own, as zenoh-python gave each one a thread (a group set
    whose listener waits for a set sent to another group of the node must not wait behind itself)."""

    def __init__(
        self,
        serve: Callable[[Item], None],
        refuse: Callable[[Item, bool], None] | None,
        name: str,
        *,
        discard: Callable[[Item], None] = lambda _: None,
    ) -> None:
        self._serve = serve
        self._refuse = refuse
        """Told of an item refused, and whether because the queue is closed (else: full)."""
        self._discard = discard
        """What ends an item still waiting at close (a query is dropped: its caller's timeout tells it)."""
        self.name = name
        # a C queue: a Condition over a deque (pure Python) made a remote get's round trip ~60 µs longer here
        self._queue: queue.SimpleQueue[Item | None] = queue.SimpleQueue()
        self._lock = threading.Lock()  # the bound and the close: a check and its put as one
        self._closed = False
        self._serving = False
        self.refused = 0
        """Items refused because the queue was full or closed (each also logged: see :meth:`_tell`)."""
        self._said = 0
        self._last_said = 0.0
        self._thread = threading.Thread(target=self._run, name=f"asm-zenoh {name}", daemon=True)
        self._thread.start()

    def callback(self) -> Callable[[Item], None]:
        """The entity's handler: ``put``, on zenoh-python's thread for the entity (its channel of 256 never stays
        full, since ``put`` never blocks). Run on Zenoh's own thread instead (a direct callback), a remote get took
        60-100 µs longer here than with zenoh-python's channel. What this hand-off costs is not settled: 0-40 µs
        measured interleaved against the handler it replaced, +0.2-0.3 of bench/remote.py's ratio
        (docs/benchmarks.md)."""
        return self.put

    def put(self, item: Item) -> None:
        with self._lock:
            closed = self._closed
            if not closed and self._queue.qsize() < REQUEST_BACKLOG:
                self._queue.put(item)
                return
            self.refused += 1
        self._tell(closed)
        try:
            if self._refuse is not None:
                self._refuse(item, closed)
        except BaseException:  # nothing may escape into zenoh-python's thread
            log.exception("refusing %s failed", self.name)

    def _tell(self, closed: bool, *, last: bool = False) -> None:
        """A warning with the count refused so far: at the first refusal, then at most once a second, and at close."""
        now = time.monotonic()
        if self.refused > self._said and (last or now - self._last_said >= 1.0):
            self._last_said, self._said = now, self.refused
            why = "the node is closing" if closed else f"{REQUEST_BACKLOG} wait for a handler that has not returned"
            log.warning("%s: %d refused so far (%s)", self.name, self.refused, why)

    def _run(self) -> None:
        get = self._queue.get
        while (item := get()) is not None:
            self._serving = True
            try:
                self._serve(item)
            except BaseException:  # SystemExit too: one failing handler must not end the node's serving
                log.exception("%s: a handler failed", self.name)
            self._serving = False
            if self._closed:  # close() found this thread in a handler and did not wait for it
                break
        self._drop_waiting()

    def _drop_waiting(self) -> None:
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return
            if item is not None:
                self._discard(item)

    def close(self) -> None:
        """Refuse what arrives from now on, drop what still waits, and end the thread: at once if it is idle; one
        inside a handler that has not returned ends when it returns (a daemon: not waited for, as zenoh-python's
        own thread was not)."""
        with self._lock:
            self._closed = True
            self._queue.put(None)
        if not self._serving and threading.current_thread() is not self._thread:
            self._thread.join(timeout=5)
        self._drop_waiting()
        self._tell(True, last=True)


def refuse_busy(query: zenoh.Query, key: zenoh.KeyExpr, node: str) -> None:
    """Answer BUSY to ``query`` if it wants a reply, and end it (the queue was full)."""
    data = query.payload.to_bytes() if query.payload is not None else b""
    try:
        if len(data) >= HEADER_SIZE and kind_of(data) == Kind.REQUEST_REPLY:
            busy = f"node {node!r} holds {REQUEST_BACKLOG} requests behind one that has not returned"
            query.reply(key, reply_head(data, Status.BUSY) + busy.encode(), express=True)
    finally:
        query.drop()


class ReplyKeys:
    """The key a reply to each source carries (the replier's own, concrete key), made once per source: a reply
    given a str key has it parsed and checked again (7-10 µs each)."""

    def __init__(self, key_of: Callable[[str], str], limit: int = 4096) -> None:
        self._key_of = key_of
        self._limit = limit
        self._keys: dict[str, zenoh.KeyExpr] = {}

    def __call__(self, source: str) -> zenoh.KeyExpr:
        key = self._keys.get(source)
        if key is None:
            if len(self._keys) > self._limit:  # bounded: sources come from the network
                self._keys.clear()
            key = self._keys[source] = zenoh.KeyExpr(self._key_of(source))
        return key
