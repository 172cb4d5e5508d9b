"""The server side of every method: a request for a registered object becomes a call on it, and its reply.

Dispatch is a table per kind of object (attribute, event, service) from method to handler. A handler returns the
reply's data, or DEFERRED when the answer comes later. Requests that cannot block (lookups, plain gets and sets,
start, suspend, …) are answered at once on the transport's receive thread. A request that may block — a get on a
sync_get attribute without a valid value, a set on a sync_set attribute while valid, a stop whose caller waits —
is handed to a *server daemon* of its own (a service, interruptible by ``close``), so one client's blocking call
never stalls another client or another object. An event WAIT needs no thread: it is a listener on the event with a
deadline (asm_py.waits). Each client may hold ``max_daemons_per_client`` blocking requests at once, and the node
``max_daemons`` in all (many clients must not exhaust a module's memory); beyond that a client gets BUSY.
Whatever a handler raises becomes a status through the one table in asm_py.status.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from typing import Any

from ._contract import MAX_PARAMS_DEPTH
from .attribute import Attribute
from .clock import Clock
from .errors import AsmTimeout, ReadOnlyError, RemoteError
from .event import Event
from .lookup import describe_entry, describe_node
from .protocol import (
    WRITES,
    Kind,
    Message,
    Method,
    ObjectKind,
    Status,
    StatusFlag,
    first_byte,
)
from .registry import Entry, Registry
from .service import Service
from .status import BadMessage, Busy, status_of
from .transport.base import Responder
from .waits import EventWaits, PendingWait

DEFERRED = b"\x00deferred"
"""A handler's answer when the reply comes later (from a daemon or a wait); compared by identity."""
Handler = Callable[["Server", str, Entry, Message, Responder], bytes]


_REPLY_BYTE = tuple(first_byte(Kind.REPLY, method) for method in range(16))
"""Byte 0 of the reply to each method (built once: a reply's header is made on every request)."""
_REQUEST_REPLY, _LOOKUP, _OK = int(Kind.REQUEST_REPLY), int(Method.LOOKUP), int(Status.OK)


def reply(respond: Responder, request: Message, status: int = _OK, data: bytes = b"") -> None:
    """Answer ``request`` if it wants a reply (the header in place, without re-validation)."""
    if request[0] == _REQUEST_REPLY:  # request.wants_reply, without the property
        respond(bytes((_REPLY_BYTE[request.method], request.txn, status, request.object_id)) + data)


class Server:
    """Answers the requests of every client for one node's registry; see the module docstring."""

    def __init__(
        self, node_name: str, registry: Registry, clock: Clock, *, max_daemons_per_client: int, max_daemons: int
    ) -> None:
        self.node_name = node_name
        self.registry = registry
        self.clock = clock
        self.max_daemons_per_client = max_daemons_per_client
        self.max_daemons = max_daemons
        self._lock = threading.Lock()
        self._daemons: dict[str, set[_ServerDaemon | PendingWait]] = {}  # blocking requests being served, per client
        self._waits: EventWaits | None = None
        self._closed = False

    def serve(self, source: str, request: Message, respond: Responder) -> None:
        """Run one request from ``source`` and answer it through ``respond`` (now, or when it completes)."""
        try:
            data = self._execute(source, request, respond)
        except Exception as exc:  # every failure becomes a status; nothing escapes into the transport
            reply(respond, request, *status_of(exc))
            return
        if data is not DEFERRED:
            reply(respond, request, _OK, data)

    def _execute(self, source: str, request: Message, respond: Responder) -> bytes:
        method = request.method
        if method == _LOOKUP:
            return self._lookup(request)
        entry = self._target(request)
        if method in WRITES:
            if entry.read_only and method in (Method.SET, Method.RESET):
                raise ReadOnlyError(f"{entry.name!r} on node {self.node_name!r} is read-only: only the node writes it")
            if entry.guard is not None:
                entry.guard(method)
        handler = DISPATCH[entry.kind].get(method)
        if handler is None:
            raise RemoteError(f"method {method} is not supported by {entry.kind.name.lower()} {entry.name!r}", 0)
        return handler(self, source, entry, request, respond)

    def _lookup(self, request: Message) -> bytes:
        if request.object_id:
            return describe_entry(self.registry.by_id(request.object_id))
        name = request.data.decode("utf-8", errors="strict") if request.data else ""
        if not name:
            return describe_node(self.node_name, len(self.registry))
        return describe_entry(self.registry.by_name(name))

    def _target(self, request: Message) -> Entry:
        if request.object_id == 0:  # group addressing: "the object of this class" on this node
            return self.registry.by_class(request.class_id)
        entry = self.registry.by_id(request.object_id)
        if request.class_id != entry.class_id:
            raise LookupError(
                f"object {request.object_id} of node {self.node_name!r} is of class {entry.class_id:#04x}, "
                f"not {request.class_id:#04x} (did the node restart with other objects?)"
            )
        return entry

    # -- attributes and events ------------------------------------------------------------------------------------

    def _get(self, source: str, entry: Entry, request: Message, respond: Responder) -> bytes:
        obj = _attribute(entry)
        try:
            return entry.codec.encode(obj.get(timeout=0))
        except AsmTimeout:
            if request.timeout_seconds == 0:
                raise
        return self._defer(source, request, respond, lambda: entry.codec.encode(obj.get(request.timeout_seconds)))

    def _set(self, source: str, entry: Entry, request: Message, respond: Responder) -> bytes:
        obj = _attribute(entry)
        value = entry.codec.decode(request.data)
        try:
            obj.set(value, timeout=0)
            return b""
        except AsmTimeout:
            if request.timeout_seconds == 0:
                raise
        return self._defer(source, request, respond, lambda: obj.set(value, request.timeout_seconds) or b"")

    def _reset(self, source: str, entry: Entry, request: Message, respond: Responder) -> bytes:
        entry.obj.reset()
        return b""

    def _peek(self, source: str, entry: Entry, request: Message, respond: Responder) -> bytes:
        return entry.codec.encode(_attribute(entry).peek())

    def _attribute_status(self, source: str, entry: Entry, request: Message, respond: Responder) -> bytes:
        return bytes([StatusFlag.VALID if _attribute(entry).valid else 0])

    def _wait(self, source: str, entry: Entry, request: Message, respond: Responder) -> bytes:
        event = entry.obj
        assert isinstance(event, Event)
        timeout = request.timeout_seconds
        wait = PendingWait(source, request, respond, None if timeout is None else self.clock.now() + timeout)
        with self._lock:
            self._admit(source).add(wait)
            if self._waits is None:
                self._waits = EventWaits(self.node_name, self._wait_answered, clock=self.clock)
            waits = self._waits
        waits.add(wait, event, entry.codec)
        return DEFERRED

    def _wait_answered(self, wait: PendingWait, failure: Exception | None, data: bytes) -> None:
        self._done(wait)
        if failure is None:
            reply(wait.respond, wait.request, Status.OK, data)
        else:
            reply(wait.respond, wait.request, *status_of(failure))

    # -- services -------------------------------------------------------------------------------------------------

    def _start(self, source: str, entry: Entry, request: Message, respond: Responder) -> bytes:
        _service(entry).start(*parse_params(request.data))
        return b""

    def _stop(self, source: str, entry: Entry, request: Message, respond: Responder) -> bytes:
        service = _service(entry)
        if request.wants_reply:
            return self._defer(source, request, respond, lambda: service.stop(request.timeout_seconds) or b"")
        try:
            service.stop(timeout=0)
        except AsmTimeout:
            pass  # asked to stop; it ends at its next checkpoint
        return b""

    def _suspend(self, source: str, entry: Entry, request: Message, respond: Responder) -> bytes:
        _service(entry).suspend()
        return b""

    def _resume(self, source: str, entry: Entry, request: Message, respond: Responder) -> bytes:
        _service(entry).resume()
        return b""

    def _service_status(self, source: str, entry: Entry, request: Message, respond: Responder) -> bytes:
        service = _service(entry)
        flags = (StatusFlag.STARTED if service.started else 0) | (StatusFlag.RUNNING if service.running else 0)
        error = service.last_error
        if error is None:
            return bytes([flags])
        return bytes([flags | StatusFlag.FAILED]) + repr(error).encode("utf-8")[:200]

    # -- blocking requests ----------------------------------------------------------------------------------------

    def _defer(self, source: str, request: Message, respond: Responder, operation: Callable[[], bytes]) -> bytes:
        with self._lock:
            daemon = _ServerDaemon(self, source, request, respond, operation)
            self._admit(source).add(daemon)
        daemon.start()
        return DEFERRED

    def _admit(self, source: str) -> set[_ServerDaemon | PendingWait]:
        """The client's set of blocking requests, if it and the node may take one more (lock held); BUSY if not."""
        active = self._daemons.setdefault(source, set())
        if len(active) >= self.max_daemons_per_client or self._closed:
            raise Busy(f"client {source!r} already has {len(active)} blocking requests on node {self.node_name!r}")
        if sum(len(d) for d in self._daemons.values()) >= self.max_daemons:
            raise Busy(f"node {self.node_name!r} already serves {self.max_daemons} blocking requests")
        return active

    def _done(self, daemon: _ServerDaemon | PendingWait) -> None:
        with self._lock:
            self._daemons.get(daemon.source, set()).discard(daemon)

    def blocking(self, source: str) -> int:
        """How many blocking requests of ``source`` are being served."""
        with self._lock:
            return len(self._daemons.get(source, ()))

    def close(self) -> None:
        """Admit nothing more; stop every daemon and cancel every wait (their clients time out)."""
        with self._lock:
            self._closed = True
            daemons = [d for group in self._daemons.values() for d in group]
            waits = self._waits
        for daemon in daemons:
            if isinstance(daemon, PendingWait):
                assert waits is not None
                waits.cancel(daemon)
            else:
                daemon.stop(timeout=5)
        if waits is not None:
            waits.stop(timeout=5)


_ATTRIBUTE: dict[int, Handler] = {
    Method.GET: Server._get,
    Method.SET: Server._set,
    Method.RESET: Server._reset,
    Method.PEEK: Server._peek,
    Method.STATUS: Server._attribute_status,
}
DISPATCH: dict[ObjectKind, dict[int, Handler]] = {
    ObjectKind.ATTRIBUTE: _ATTRIBUTE,
    ObjectKind.EVENT: {**_ATTRIBUTE, Method.WAIT: Server._wait},
    ObjectKind.SERVICE: {
        Method.START: Server._start,
        Method.STOP: Server._stop,
        Method.SUSPEND: Server._suspend,
        Method.RESUME: Server._resume,
        Method.RESET: Server._reset,
        Method.STATUS: Server._service_status,
    },
}
"""Per kind of object, the handler of each method it supports (anything else is UNSUPPORTED)."""


def _attribute(entry: Entry) -> Attribute:
    obj = entry.obj
    assert isinstance(obj, Attribute)
    return obj


def _service(entry: Entry) -> Service:
    obj = entry.obj
    assert isinstance(obj, Service)
    return obj


def parse_params(data: bytes) -> list[Any]:
    """START parameters: a JSON array, at most MAX_PARAMS_DEPTH deep (checked before parsing, so hostile nesting
    costs one pass over the bytes and never a recursion)."""
    if not data:
        return []
    depth = deepest = 0
    for byte in data:  # brackets inside strings count too: a conservative bound is enough here
        if byte in b"[{":
            depth += 1
            deepest = max(deepest, depth)
        elif byte in b"]}":
            depth -= 1
    if deepest > MAX_PARAMS_DEPTH:
        raise BadMessage(f"service parameters nest deeper than {MAX_PARAMS_DEPTH} levels")
    try:
        params = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise BadMessage(f"service parameters are not UTF-8: {exc}") from None
    except ValueError as exc:
        raise BadMessage(f"service parameters are not JSON: {exc}") from None
    if not isinstance(params, list):
        raise ValueError("service parameters travel as a JSON array")
    return params


class _ServerDaemon(Service):
    """Serves one blocking request of one client (the paper's server daemon), then ends."""

    def __init__(
        self, server: Server, source: str, request: Message, respond: Responder, operation: Callable[[], bytes]
    ) -> None:
        super().__init__(f"daemon:{server.node_name}:{source}:{request.txn}", clock=server.clock)
        self.server = server
        self.source = source
        self.request = request
        self.respond = respond
        self.operation = operation

    def run(self, *params: Any) -> None:
        try:
            data = self.operation()
        except Exception as exc:
            reply(self.respond, self.request, *status_of(exc))
            return
        reply(self.respond, self.request, Status.OK, data or b"")

    def on_stop(self) -> None:
        self.server._done(self)
