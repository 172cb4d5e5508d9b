"""Client objects: remote attributes, events and services with the local interface (paper section 3).

A client object is made by ``Node.lookup`` and talks through a :class:`Port`, the client port to one remote node,
shared by every client object and thread of the node (transaction ids pair replies with requests, so any number of
calls may be in flight at once). Gets, lookups and status reads always wait for their reply; ``set``, ``reset``,
``start``, ``stop``, ``suspend`` and ``resume`` return at once unless the caller passes ``wait=True``.

Errors come back as status codes and are raised as the local types: TimeoutError (``AsmTimeout``), ServiceError,
TypeError, ValueError, LookupError; anything else as ``RemoteError``. A call whose peer is gone raises TimeoutError
when its deadline passes, or as soon as discovery reports that the peer left.

Location transparency has one price: ``valid``, ``started``, ``running`` and ``last_error`` are properties, as on
local objects, but on a client object each read is a round trip (and may raise TimeoutError).
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ._contract import TIMEOUT_LONGEST
from .clock import WALL_CLOCK, Clock, Monitor
from .codec import Codec, codec_from_descriptor
from .errors import AsmTimeout, EstopLatched, Locked, MessageTooLarge, ReadOnlyError, RemoteError, ServiceError
from .protocol import (
    HEADER_SIZE,
    MAX_TXN,
    Kind,
    Message,
    Method,
    ObjectKind,
    ProtocolError,
    Status,
    check_size,
    encode,
    encode_timeout,
    first_byte,
    has_timeout,
)
from .service import ServiceStatus

if TYPE_CHECKING:
    from .node import Entry, Node

MAX_TIMEOUT_CODE = TIMEOUT_LONGEST
REPLY_MARGIN = 1.0
"""Seconds a client waits for a reply beyond the time the server may block."""


@dataclass(frozen=True)
class ObjectInfo:
    """What a lookup reply tells about an object."""

    class_id: int
    object_id: int
    kind: ObjectKind
    sync_get: bool
    sync_set: bool
    published: bool
    codec: Codec
    name: str
    class_name: str
    read_only: bool = False
    """Only the node writes it: a remote set or reset is answered READ_ONLY."""


def describe_entry(entry: Entry) -> bytes:
    """The data of a LOOKUP reply (docs/protocol.md, "Lookup")."""
    obj = entry.obj
    published = getattr(obj, "publish_policy", None) is not None or entry.kind == ObjectKind.EVENT
    flags = (int(getattr(obj, "sync_get", False)) | int(getattr(obj, "sync_set", False)) << 1 | int(published) << 2
             | int(entry.read_only) << 3)  # fmt: skip
    descriptor = entry.codec.descriptor()
    name = entry.name.encode("utf-8")
    return (bytes([entry.class_id, entry.object_id, entry.kind, flags, len(descriptor)]) + descriptor
            + bytes([len(name)]) + name + entry.class_name.encode("utf-8"))  # fmt: skip


def parse_description(data: bytes) -> ObjectInfo:
    try:
        class_id, object_id, kind, flags, length = data[:5]
        descriptor = data[5 : 5 + length]
        offset = 5 + length
        name_length = data[offset]
        name = data[offset + 1 : offset + 1 + name_length].decode("utf-8")
        class_name = data[offset + 1 + name_length :].decode("utf-8")
        return ObjectInfo(class_id, object_id, ObjectKind(kind), bool(flags & 1), bool(flags & 2), bool(flags & 4),
                          codec_from_descriptor(descriptor), name, class_name, bool(flags & 8))  # fmt: skip
    except (ValueError, IndexError) as exc:
        raise ProtocolError(f"malformed lookup reply: {exc}") from None


def make_client(port: Port, description: bytes) -> RemoteObject:
    info = parse_description(description)
    cls = {ObjectKind.ATTRIBUTE: RemoteAttribute, ObjectKind.EVENT: RemoteEvent, ObjectKind.SERVICE: RemoteService}
    return cls[info.kind](port, info)


_STATUS_ERRORS: dict[int, type[Exception]] = {
    Status.TIMEOUT: AsmTimeout,
    Status.SERVICE_ERROR: ServiceError,
    Status.TYPE_ERROR: TypeError,
    Status.VALUE_ERROR: ValueError,
    Status.NOT_FOUND: LookupError,
    Status.READ_ONLY: ReadOnlyError,
    Status.ESTOP: EstopLatched,
    Status.LOCKED: Locked,
    Status.TOO_LARGE: MessageTooLarge,
}


class _What:
    """Names a call in error messages; formatted only when an error is raised (off the hot path)."""

    __slots__ = ("method", "subject")

    def __init__(self, method: int, subject: str) -> None:
        self.method = method
        self.subject = subject

    def __str__(self) -> str:
        method = Method(self.method).name.lower() if self.method in Method._value2member_map_ else self.method
        return f"{method} on {self.subject}"


def raise_for_status(reply: Message, what: object) -> None:
    if reply.status == Status.OK:
        return
    text = f"{what}: {reply.data.decode('utf-8', errors='replace')}"
    error = _STATUS_ERRORS.get(reply.status)
    if error is not None:
        raise error(text)
    name = Status(reply.status).name if reply.status in Status._value2member_map_ else str(reply.status)
    raise RemoteError(f"{text} (status {name})", reply.status)


class _Call:
    __slots__ = ("failure", "method", "object_id", "reply")

    def __init__(self, method: int, object_id: int) -> None:
        self.method = method
        self.object_id = object_id
        self.reply: Message | None = None
        self.failure: str | None = None


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
        self.node.transport.send(self.remote, check_size(encode(message), _What(method, self.remote)))

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
        what = _What(method, subject or self.remote)
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
        raw = check_size(encode(Message(Kind.REQUEST_REPLY, method, 0, class_id, object_id, timeout=code, data=data)),
                          what)  # fmt: skip
        call = _Call(method, object_id)
        with mon:
            if not mon.wait_for(lambda: len(self._pending) <= MAX_TXN, wait):
                raise AsmTimeout(f"{what}: all {MAX_TXN + 1} transaction ids of the port are in use")
            txn = self._next_txn
            while txn in self._pending:
                txn = (txn + 1) & MAX_TXN
            self._next_txn = (txn + 1) & MAX_TXN
            self._pending[txn] = call
        try:
            self.node.transport.send(self.remote, raw[:1] + bytes((raw[1] | txn,)) + raw[2:])
            with mon:
                mon.wait_for(lambda: call.reply is not None or call.failure is not None, wait)
        finally:
            with mon:
                if self._pending.get(txn) is call:
                    del self._pending[txn]
                mon.notify_all()
        if call.reply is None:
            reason = call.failure or f"no reply within {wait:.3g}s"  # done without a reply means a failure
            raise AsmTimeout(f"{what} timed out: {reason}")
        raise_for_status(call.reply, what)
        return call.reply

    def _direct(self, method: int, class_id: int, object_id: int, data: bytes, wait: float, what: object) -> Message:
        """A round trip in the caller's thread, on transports that can (requests that cannot block).

        The hot path of a remote get: the 4-byte header is built in place and the reply checked by its header bytes.
        """
        txn = next(self._direct_txns) & MAX_TXN  # atomic; these replies never pass through _pending
        head = bytes((first_byte(Kind.REQUEST_REPLY, method), txn, class_id, object_id))
        raw = self.node.transport.request(self.remote, check_size(head + data, what), wait)
        if raw is None:
            raise AsmTimeout(f"{what} timed out: no reply within {wait:.3g}s")
        if len(raw) < HEADER_SIZE or raw[0] != first_byte(Kind.REPLY, method) or raw[1] != txn or raw[3] != object_id:
            raise ProtocolError(f"{what}: answer is not the reply to transaction {txn}")
        reply = Message(Kind.REPLY, method, txn, 0, raw[3], raw[2], None, raw[HEADER_SIZE:])
        if reply.status:
            raise_for_status(reply, what)
        return reply

    def deliver(self, reply: Message) -> None:
        """A reply arrived for this port (from the node's receive path)."""
        with self._mon:
            call = self._pending.get(reply.txn)
            if call is None or call.method != reply.method or call.object_id != reply.object_id:
                self.stale_replies += 1  # its caller gave up already, or it answers another request
                return
            del self._pending[reply.txn]
            call.reply = reply
            self._mon.notify_all()

    def fail_all(self, reason: str) -> None:
        """Fail every call in flight (the peer left, or the node closed)."""
        with self._mon:
            for call in self._pending.values():
                call.failure = reason
            self._pending.clear()
            self._mon.notify_all()


class RemoteObject:
    """What every client object has: identity, and the port it talks through."""

    def __init__(self, port: Port, info: ObjectInfo) -> None:
        self._port = port
        self.info = info
        self._subject = f"{port.remote}/{info.name}"

    @property
    def name(self) -> str:
        return self.info.name

    @property
    def node(self) -> str:
        """The name of the node the object lives on."""
        return self._port.remote

    @property
    def clock(self) -> Clock:
        """The local node's clock (what event-driven services built on this object run on)."""
        return self._port.node.clock

    def _call(
        self, method: Method, data: bytes = b"", *, timeout: float | None = None, blocking: bool = False
    ) -> bytes:
        info = self.info
        return self._port.call(method, info.class_id, info.object_id, data, timeout=timeout, blocking=blocking,
                               subject=self._subject).data  # fmt: skip

    def _request(self, method: Method, data: bytes, wait: bool, *, timeout: float | None = None, blocks: bool = False):
        """A request that replies only when the caller waits for it."""
        if wait:
            self._call(method, data, timeout=timeout, blocking=blocks)
            return
        code = encode_timeout(timeout) if blocks and timeout is not None else None
        self._port.send(method, self.info.class_id, self.info.object_id, data, timeout=code)

    def __repr__(self) -> str:
        return (
            f"<{type(self).__name__} {self.node}/{self.name} class={self.info.class_id:#04x} id={self.info.object_id}>"
        )


class RemoteAttribute(RemoteObject):
    """An attribute on another node, with the Attribute interface; see the module docstring."""

    @property
    def codec(self) -> Codec:
        return self.info.codec

    @property
    def sync_get(self) -> bool:
        return self.info.sync_get

    @property
    def sync_set(self) -> bool:
        return self.info.sync_set

    def get(self, timeout: float | None = None) -> Any:
        return self.codec.decode(self._call(Method.GET, timeout=timeout, blocking=self.sync_get))

    def set(self, value: Any, timeout: float | None = None, *, wait: bool | None = None) -> None:
        """Set the remote value. Returns at once, unless ``wait`` — which a ``timeout`` implies: "up to this long"."""
        data = self.codec.encode(value)  # a bad value fails here, before anything is sent
        self._request(Method.SET, data, timeout is not None if wait is None else wait, timeout=timeout,
                      blocks=self.sync_set)  # fmt: skip

    def reset(self, *, wait: bool = False) -> None:
        self._request(Method.RESET, b"", wait)

    @property
    def valid(self) -> bool:
        """Whether the remote value is valid (a round trip)."""
        return bool(self._call(Method.STATUS)[0] & 1)

    def peek(self, timeout: float | None = None) -> Any:
        """The remote value without consuming it (``timeout``: how long to wait for the reply, at most)."""
        return self.codec.decode(self._call(Method.PEEK, timeout=timeout))

    def on_change(self, callback: Callable[[Any], None]) -> Callable[[], None]:
        """Call ``callback(value)`` for every publication of the remote attribute; returns a remover."""
        return self._subscribe(callback)

    def _subscribe(self, deliver: Callable[[Any], None]) -> Callable[[], None]:
        decode_value = self.codec.decode
        head0 = first_byte(Kind.PUBLICATION, Method.PUBLISH)

        def on_publication(data: bytes) -> None:
            # A publication never carries a timeout byte: header byte 0 says all, the value starts at byte 4.
            if len(data) >= HEADER_SIZE and data[0] == head0 and not has_timeout(data):
                try:
                    value = decode_value(data[HEADER_SIZE:])
                except ValueError:
                    return  # a malformed value is dropped, like any malformed message
                deliver(value)

        return self._port.node.transport.subscribe(self.node, self.name, on_publication, object_id=self.info.object_id)


class RemoteEvent(RemoteAttribute):
    """An event on another node: ``waiting`` blocks until its next firing; ``on_change`` sees every firing."""

    def waiting(self, timeout: float | None = None) -> Any:
        return self.codec.decode(self._call(Method.WAIT, timeout=timeout, blocking=True))


class RemoteService(RemoteObject):
    """A service on another node, with the Service interface; parameters travel as a JSON array."""

    def start(self, *params: Any, wait: bool = False) -> None:
        data = json.dumps(list(params)).encode("utf-8") if params else b""
        self._request(Method.START, data, wait)

    def stop(self, timeout: float | None = None, *, wait: bool = False) -> None:
        self._request(Method.STOP, b"", wait, timeout=timeout, blocks=True)

    def suspend(self, *, wait: bool = False) -> None:
        self._request(Method.SUSPEND, b"", wait)

    def resume(self, *, wait: bool = False) -> None:
        self._request(Method.RESUME, b"", wait)

    continue_ = resume

    def reset(self, *, wait: bool = False) -> None:
        self._request(Method.RESET, b"", wait)

    def status(self, timeout: float | None = None) -> ServiceStatus:
        """started, running and the last error in one round trip (``timeout``: how long to wait, at most)."""
        data = self._call(Method.STATUS, timeout=timeout)
        error = (data[1:].decode("utf-8", errors="replace") or None) if data[0] & 8 else None
        return ServiceStatus(bool(data[0] & 2), bool(data[0] & 4), error)

    @property
    def started(self) -> bool:
        return self.status().started

    @property
    def running(self) -> bool:
        return self.status().running

    @property
    def last_error(self) -> str | None:
        """The remote service's last error, as text (the exception itself stays on its node)."""
        return self.status().error
