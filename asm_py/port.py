"""The client port from a node to one remote node: requests out, replies paired with them by transaction ID.

One port per remote node, shared by every client object and thread of the node, so any number of calls may be in
flight at once (MAX_TXN + 1 per port). A call whose peer is gone raises TimeoutError when its deadline passes, or
as soon as discovery reports that the peer left (``fail_all``). A failed reply is raised as its local exception by
the one table in asm_py.status.
"""

from __future__ import annotations

import itertools
import threading
import time
from typing import TYPE_CHECKING

from ._contract import TIMEOUT_LONGEST
from .clock import WALL_CLOCK, Monitor, current_service
from .errors import AsmTimeout
from .protocol import (
    HEADER_SIZE,
    MAX_MESSAGE,
    MAX_TXN,
    METHOD_MASK,
    Kind,
    Message,
    ProtocolError,
    check_size,
    encode,
    encode_timeout,
    first_byte,
)
from .status import What, raise_for_status

if TYPE_CHECKING:
    from .node import Node

MAX_TIMEOUT_CODE = TIMEOUT_LONGEST
REPLY_MARGIN = 1.0
"""Seconds a client waits for a reply beyond the time the server may block."""


_new_tuple = tuple.__new__  # a Message without NamedTuple's own __new__, a Python function
_REPLY = int(Kind.REPLY)
_ASK = tuple(first_byte(Kind.REQUEST_REPLY, method) for method in range(METHOD_MASK + 1))
_ANSWER = tuple(first_byte(Kind.REPLY, method) for method in range(METHOD_MASK + 1))
"""Byte 0 of a request that wants a reply, and of its reply, per method (built once)."""


class _Call:
    """One call in flight. ``done`` is held from the start and released once by whoever completes the call (the
    reply's delivery or ``fail_all``): a caller outside a service thread waits on it alone, the cheapest hand-off
    from the receive thread (no condition, no re-taking the port's lock to return; issue 31)."""

    __slots__ = ("done", "failure", "method", "object_id", "reply")

    def __init__(self, method: int, object_id: int) -> None:
        self.method = method
        self.object_id = object_id
        self.reply: Message | None = None
        self.failure: str | None = None
        self.done = threading.Lock()
        self.done.acquire()


class Port:
    """The client port from a node to one remote node."""

    def __init__(self, node: Node, remote: str) -> None:
        self.node = node
        self.remote = remote
        self._mon = Monitor(WALL_CLOCK)
        self._pending: dict[int, _Call] = {}
        self._next_txn = 0
        self._direct_txns = itertools.count()
        self.stale_replies = 0

    def send(
        self, method: int, class_id: int, object_id: int, data: bytes = b"", *, timeout: int | None = None
    ) -> None:
        """Send a request that wants no reply."""
        message = Message(Kind.REQUEST, method, 0, class_id, object_id, timeout=timeout, data=data)
        self.node.transport.send(self.remote, check_size(encode(message), What(method, self.remote)))

    def call(
        self,
        method: int,
        class_id: int,
        object_id: int,
        data: bytes = b"",
        *,
        timeout: float | None = None,
        blocking: bool = False,
        subject: str = "",
    ) -> Message:
        """Send a request and wait for its reply; raise the reply's error as its local exception type.

        ``blocking``: the server may block up to ``timeout`` (None: without limit); the client waits that long plus
        a margin. Otherwise the client waits ``timeout`` or the node's ``call_timeout``.
        """
        what = What(method, subject or self.remote)
        if not blocking:
            wait = timeout or self.node.call_timeout
            if self.node.transport.direct_requests:
                return self._direct(method, class_id, object_id, data, wait, what)
            return self._round_trip(method, class_id, object_id, data, None, wait, what)
        deadline = None if timeout is None else WALL_CLOCK.now() + timeout
        while True:
            remaining = None if deadline is None else max(0.0, deadline - WALL_CLOCK.now())
            code = None if remaining is None else encode_timeout(remaining)
            wait = None if remaining is None else remaining + REPLY_MARGIN
            try:
                return self._round_trip(method, class_id, object_id, data, code, wait, what)
            except AsmTimeout:
                # A timeout beyond what one timeout byte holds (0xFE): the server gave up early; ask for the rest.
                if code != MAX_TIMEOUT_CODE or deadline is None or deadline <= WALL_CLOCK.now():
                    raise

    def _round_trip(
        self,
        method: int,
        class_id: int,
        object_id: int,
        data: bytes,
        code: int | None,
        wait: float | None,
        what: object,
    ) -> Message:
        mon = self._mon
        simple = code is None and 0 <= method <= METHOD_MASK  # the header built in place, once its txn is known
        encoded = b""
        if not simple:
            encoded = check_size(encode(Message(Kind.REQUEST_REPLY, method, 0, class_id, object_id, timeout=code,
                                                data=data)), what)  # fmt: skip
        elif len(data) > MAX_MESSAGE - HEADER_SIZE:
            check_size(bytes(HEADER_SIZE) + data, what)  # raises MessageTooLarge
        call = _Call(method, object_id)
        with mon.lock:
            if len(self._pending) > MAX_TXN and not mon.wait_for(lambda: len(self._pending) <= MAX_TXN, wait):
                raise AsmTimeout(f"{what}: all {MAX_TXN + 1} transaction ids of the port are in use")
            txn = self._next_txn
            while txn in self._pending:
                txn = (txn + 1) & MAX_TXN
            self._next_txn = (txn + 1) & MAX_TXN
            self._pending[txn] = call
        try:
            transport = self.node.transport
            if simple:  # bytes() checks the IDs' range
                transport.send(self.remote, bytes((_ASK[method], txn, class_id, object_id)) + data)
            else:
                transport.send(self.remote, encoded[:1] + bytes((encoded[1] | txn,)) + encoded[2:])
            if current_service() is None:  # on CAN, this thread may read its reply itself
                transport.wait_reply(call.done, wait, self.remote, bytes((_ANSWER[method], txn)))
            else:  # a service thread waits on the monitor, where its service's stop() can interrupt it
                with transport.waiting(call.done), mon:
                    mon.wait_for(lambda: call.reply is not None or call.failure is not None, wait)
        finally:
            if call.reply is None and call.failure is None:  # completed calls left _pending when completed
                with mon.lock:
                    if self._pending.get(txn) is call:
                        del self._pending[txn]
                    mon.notify_all()
        if call.reply is None:
            reason = call.failure or f"no reply within {wait:.3g}s"  # done without a reply means a failure
            raise AsmTimeout(f"{what} timed out: {reason}")
        reply = call.reply
        if reply.status:
            raise_for_status(reply, what)
        return reply

    def _direct(self, method: int, class_id: int, object_id: int, data: bytes, wait: float, what: object) -> Message:
        """A round trip in the caller's thread, on transports that can (requests that cannot block).

        The hot path of a remote get: the 4-byte header is built in place and the reply checked by its header bytes.
        """
        txn = next(self._direct_txns) & MAX_TXN  # atomic; these replies never pass through _pending
        head = bytes((_ASK[method], txn, class_id, object_id))
        began = time.monotonic()
        raw = self.node.transport.request(self.remote, check_size(head + data, what), wait)
        if raw is None:
            waited = time.monotonic() - began
            if waited < 0.9 * wait:  # over at once: Zenoh found nothing to ask, or only an error answered
                raise AsmTimeout(f"{what} failed: nothing answered after {waited:.2g}s ({self.remote} is not "
                                 "reachable now)")  # fmt: skip
            raise AsmTimeout(f"{what} timed out: no reply within {wait:.3g}s")
        if len(raw) < HEADER_SIZE or raw[0] != _ANSWER[method] or raw[1] != txn or raw[3] != object_id:
            raise ProtocolError(f"{what}: answer is not the reply to transaction {txn}")
        reply = _new_tuple(Message, (_REPLY, method, txn, 0, object_id, raw[2], None, raw[HEADER_SIZE:]))
        if reply.status:
            raise_for_status(reply, what)
        return reply

    def deliver(self, reply: Message) -> None:
        """A reply arrived for this port (from the node's receive path)."""
        mon = self._mon
        with mon.lock:
            call = self._pending.get(reply.txn)
            if call is None or call.method != reply.method or call.object_id != reply.object_id:
                self.stale_replies += 1  # its caller gave up already, or it answers another request
                return
            del self._pending[reply.txn]
            call.reply = reply
            call.done.release()
            if mon._waiters:  # a service thread waiting for this reply, or a caller for a free transaction id
                mon.notify_all()

    def fail_all(self, reason: str) -> None:
        """Fail every call in flight (the peer left, or the node closed)."""
        with self._mon.lock:
            for call in self._pending.values():
                call.failure = reason
                call.done.release()
            self._pending.clear()
            self._mon.notify_all()
