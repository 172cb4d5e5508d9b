"""The bridge's Zenoh clients as the CAN bus sees them: an alias node ID each, their queries waiting for CAN replies,
their queues of messages for the bus, and the pace at which those go out.

A Zenoh session C (its name and its session ID) gets an alias node ID from a pool, least recently used reused first,
so two sessions that share a name never receive each other's replies. Every bound of docs/protocol.md §7, "Bridge
to Zenoh", is enforced here before a frame reaches the bus: queries waiting per client and in all, messages queued
per client. Queues are served round-robin, one message per client in turn, at a bounded frame rate, so one client
flooding the bridge delays only itself.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from asm_py.canbus.ids import check_node_id
from asm_py.protocol import HEADER_SIZE, MAX_TXN, Status, decode_timeout, encode_timeout, has_timeout, txn_of, with_txn

REPLY_MARGIN = 5.0
"""Seconds a forwarded query waits for its CAN reply beyond the request's own timeout."""
MAX_BLOCK = 60.0
"""The longest a forwarded request may ask a CAN node to block: a longer (or endless) timeout byte is capped."""
MAX_BLOCK_CODE = encode_timeout(MAX_BLOCK)
DEFAULT_FRAME_RATE = 4000.0
"""Frames per second the bridge puts on the bus for Zenoh clients, at most: about half of what a 1 Mbit/s bus
carries (~7,700 frames of 8 bytes), so the modules' own traffic always has room and no receiver falls behind."""
BURST_FRAMES = 600
"""Frames the bridge may send at once after a quiet spell (one maximum-size message and some)."""


class Refusal(Exception):
    """A request the bridge answers itself (status None: dropped without an answer)."""

    def __init__(self, status: int | None, text: str) -> None:
        super().__init__(text)
        self.status = status
        self.text = text


@dataclass
class Pending:
    """A forwarded query waiting for its CAN reply."""

    query: Any
    """The Zenoh query to answer."""
    key: str
    """The key its reply carries: the mirrored node's own."""
    txn: int
    """The client's own transaction id, put back into the reply."""
    deadline: float


@dataclass
class Client:
    """One Zenoh session as the bus sees it: an alias node ID and a bounded queue of messages to send."""

    alias: int
    queue: deque[tuple[int, int, bytes]] = field(default_factory=deque)
    pending: int = 0


class ClientTable:
    """Aliases, pending queries and queues of the bridge's Zenoh clients; every method but :meth:`next_batch` and
    :meth:`expire` is called with ``lock`` held (the bridge's lock, shared with its sender's condition)."""

    def __init__(
        self,
        aliases: Sequence[int],
        *,
        max_pending: int,
        max_pending_per_client: int,
        max_queued_per_client: int,
    ) -> None:
        self.lock = threading.Lock()
        self.ready = threading.Condition(self.lock)
        self.alias_pool = [check_node_id(a) for a in aliases]
        self.clients: OrderedDict[tuple[str, bytes], Client] = OrderedDict()  # (name, session) -> client, LRU
        self.pending: dict[tuple[int, int, int], Pending] = {}  # (alias, CAN node ID, bridge txn) -> query
        self.max_pending = max_pending
        self.max_pending_per_client = max_pending_per_client
        self.max_queued_per_client = max_queued_per_client
        self._next_txn = 0

    def client(self, name: str, session: bytes) -> Client:
        """The client for a Zenoh session: its alias, least recently used reused first."""
        key = (name, session)
        client = self.clients.get(key)
        if client is not None:
            self.clients.move_to_end(key)
            return client
        used = {c.alias for c in self.clients.values()}
        free = [a for a in self.alias_pool if a not in used]
        if free:
            alias = free[0]
        else:  # reuse the alias of the least recently used client without work in flight
            idle = next((k for k, c in self.clients.items() if not c.pending and not c.queue), None)
            if idle is None:
                raise Refusal(Status.BUSY, "the bridge has no free alias: too many clients at work")
            alias = self.clients.pop(idle).alias
        client = self.clients[key] = Client(alias)
        return client

    def await_reply(self, client: Client, node_id: int, query: Any, data: bytes, key: str) -> bytes:
        """Register ``query`` as waiting for its reply; the request as it goes on the bus: a bridge transaction id,
        and a timeout byte of at most MAX_BLOCK."""
        if client.pending >= self.max_pending_per_client or len(self.pending) >= self.max_pending:
            raise Refusal(Status.BUSY, f"too many requests in flight through the bridge ({client.pending} of yours)")
        for _ in range(MAX_TXN + 1):
            txn, self._next_txn = self._next_txn, (self._next_txn + 1) & MAX_TXN
            if (client.alias, node_id, txn) not in self.pending:
                break
        else:
            raise Refusal(Status.BUSY, "all transaction ids to this node are in use")
        timed = has_timeout(data) and len(data) > HEADER_SIZE
        limit = decode_timeout(data[HEADER_SIZE]) if timed else 0.0
        if limit is None or limit > MAX_BLOCK:
            data = data[:HEADER_SIZE] + bytes((MAX_BLOCK_CODE,)) + data[HEADER_SIZE + 1 :]
            limit = MAX_BLOCK
        deadline = time.monotonic() + limit + REPLY_MARGIN
        self.pending[(client.alias, node_id, txn)] = Pending(query, key, txn_of(data), deadline)
        client.pending += 1
        return with_txn(data, txn)

    def enqueue(self, client: Client, dest_kind: int, dest: int, data: bytes) -> None:
        """Queue a message for the bus; BUSY when the client's queue is full."""
        if len(client.queue) >= self.max_queued_per_client:
            raise Refusal(Status.BUSY, "your queue at the bridge is full")
        client.queue.append((dest_kind, dest, data))
        self.ready.notify()

    def answered(self, alias: int, node_id: int, txn: int) -> Pending | None:
        """The query a CAN reply (to ``alias``, from ``node_id``, bridge transaction ``txn``) answers, if any."""
        waiting = self.pending.pop((alias, node_id, txn), None)
        if waiting is not None:
            self._release(alias)
        return waiting

    def _release(self, alias: int) -> None:
        for client in self.clients.values():
            if client.alias == alias:
                client.pending = max(0, client.pending - 1)
                return

    def next_batch(self, stop: threading.Event) -> list[tuple[int, tuple[int, int, bytes]]] | None:
        """Wait for queued messages and take one per client (round-robin); None once ``stop`` is set."""
        with self.lock:
            while not stop.is_set() and not any(c.queue for c in self.clients.values()):
                self.ready.wait(0.5)
            if stop.is_set():
                return None
            return [(c.alias, c.queue.popleft()) for c in self.clients.values() if c.queue]

    def expire(self) -> list[Any]:
        """Forget the queries whose deadline passed; they are returned to be dropped (outside the lock)."""
        now = time.monotonic()
        with self.lock:
            expired = [k for k, p in self.pending.items() if p.deadline < now]
            queries = []
            for key in expired:
                queries.append(self.pending.pop(key).query)
                self._release(key[0])
        return queries

    def clear(self) -> list[Any]:
        """Forget everything (closing); the queries still waiting, to be dropped."""
        with self.lock:
            queries = [p.query for p in self.pending.values()]
            self.pending.clear()
            self.clients.clear()
            self.ready.notify_all()
        return queries


class Pacer:
    """A token bucket of BURST_FRAMES frames refilled at ``rate`` frames a second (None: no limit)."""

    def __init__(self, rate: float | None) -> None:
        self.rate = rate
        self._budget = float(BURST_FRAMES)
        self._time = time.monotonic()

    def wait(self, frames: int, stop: threading.Event) -> None:
        """Wait until ``frames`` fit the rate (or ``stop`` is set)."""
        rate = self.rate
        if rate is None:
            return
        now = time.monotonic()
        self._budget = min(BURST_FRAMES, self._budget + (now - self._time) * rate)
        self._time = now
        if self._budget < frames:
            stop.wait((frames - self._budget) / rate)
            self._time = time.monotonic()
            self._budget = 0.0
        else:
            self._budget -= frames
