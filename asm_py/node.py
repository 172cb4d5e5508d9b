"""The node: the lookup table of local objects, the server side of the protocol, and the way to remote objects.

``node.register(obj)`` gives an attribute, event or service a (class ID, object ID). The node then answers
protocol requests for it from any transport (paper section 3, Figure 3). Requests that cannot block (lookups,
plain gets and sets, start, suspend, …) are answered at once on the transport's receive thread. A request that
may block — a get on a sync_get attribute without a valid value, a set on a sync_set attribute while valid, an
stop whose caller waits — is handed to a *server daemon* of its own (a service, interruptible by ``close``), so one
client's blocking call never stalls another client or another object. An event WAIT needs no thread: it is a
listener on the event with a deadline (asm_py.waits). Each client may hold ``max_daemons_per_client`` blocking
requests at once, and the node ``max_daemons`` in all (many clients must not exhaust a module's memory); beyond that
a client gets BUSY.

``node.lookup(remote, name)`` returns a client object with the local interface (asm_py.remote).
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ._contract import MAX_PARAMS_DEPTH
from .attribute import Attribute, PublishPolicy
from .classes import well_known
from .clock import WALL_CLOCK, Clock
from .codec import JSON, Codec
from .errors import AsmTimeout, EstopLatched, Locked, MessageTooLarge, ReadOnlyError, RemoteError, ServiceError
from .event import Event
from .group import GroupPort
from .keys import parse_address
from .protocol import (
    LOCAL_CLASS_BASE,
    MAX_MESSAGE,
    VERSION,
    Kind,
    Message,
    Method,
    ObjectKind,
    ProtocolError,
    Status,
    decode,
    first_byte,
    kind_of,
    reply_head,
    too_large,
    version_of,
)
from .publisher import Publisher
from .remote import Port, RemoteObject, describe_entry, make_client
from .service import Service
from .transport.base import BROADCAST, Responder, Transport, check_name
from .waits import EventWaits, PendingWait

log = logging.getLogger("asm_py.node")

Registrable = Attribute | Service
Guard = Callable[[int], None]
"""Called with the method of each request that would change an object, before it runs; raises to refuse it."""
WRITES = frozenset({Method.SET, Method.RESET, Method.START, Method.STOP, Method.SUSPEND, Method.RESUME})
"""The methods that change an object (what read-only attributes and guards refuse)."""


@dataclass
class Entry:
    """One row of the lookup table."""

    obj: Registrable
    name: str
    class_name: str
    class_id: int
    object_id: int
    kind: ObjectKind
    codec: Codec
    """Codec of the value (attributes, events) or of the start parameters (services: JSON)."""
    publisher: Publisher | None = None
    read_only: bool = False
    """Remote SET and RESET are refused (READ_ONLY): only the node itself writes the value."""
    guard: Guard | None = None
    """Called before every remote request that would change the object; may refuse it by raising."""


class Node:
    """An ASM node on a transport; see the module docstring."""

    def __init__(
        self,
        name: str,
        transport: Transport,
        *,
        clock: Clock | None = None,
        call_timeout: float = 2.0,
        max_daemons_per_client: int = 8,
        max_daemons: int = 16,
    ) -> None:
        self.name = check_name(name)
        self.transport = transport
        self.clock = clock if clock is not None else WALL_CLOCK
        self.call_timeout = call_timeout
        self.max_daemons_per_client = max_daemons_per_client
        self.max_daemons = max_daemons
        self._lock = threading.Lock()
        self._by_id: dict[int, Entry] = {}
        self._by_name: dict[str, Entry] = {}
        self._local_classes: dict[str, int] = {}
        self._ports: dict[str, Port] = {}
        self._daemons: dict[str, set[Service | PendingWait]] = {}  # blocking requests being served, per client
        self._waits: EventWaits | None = None
        self._closed = False
        self._seen: set[str] = set()
        self.dropped = 0
        transport.attach(name, self._on_message)
        self._unpeer = transport.on_peer(self._peer_changed)

    # -- registration ---------------------------------------------------------------------------------------------

    def register(
        self,
        obj: Registrable,
        *,
        name: str | None = None,
        class_name: str | None = None,
        read_only: bool = False,
        guard: Guard | None = None,
    ) -> Entry:
        """Enter ``obj`` in the lookup table; its class defaults to its name (the kind of object it is).

        ``read_only``: remote SET and RESET are answered READ_ONLY (a measurement, a checksum, a state that only the
        node's own code writes; the lookup reply says so). ``guard(method)`` runs before every remote request that
        would change the object (set, reset, start, stop, suspend, resume) and refuses it by raising — a module
        refuses what would move its joint while its emergency stop is latched.
        """
        if isinstance(obj, Event):
            kind, codec = ObjectKind.EVENT, obj.codec or JSON
        elif isinstance(obj, Attribute):
            kind, codec = ObjectKind.ATTRIBUTE, obj.codec or JSON
        elif isinstance(obj, Service):
            kind, codec = ObjectKind.SERVICE, JSON
        else:
            raise TypeError(f"only attributes, events and services can be registered, not {type(obj).__name__}")
        name = check_name(name or obj.name, "object name")
        class_name = check_name(class_name or name, "class name")
        with self._lock:
            if name in self._by_name:
                raise ValueError(f"node {self.name!r} already has an object named {name!r}")
            object_id = len(self._by_id) + 1
            if object_id > 0xFF:
                raise ValueError(f"node {self.name!r} is full: at most 255 objects")
            class_id = self._class_id(class_name)
            entry = Entry(obj, name, class_name, class_id, object_id, kind, codec, read_only=read_only, guard=guard)
            self._by_id[object_id] = entry
            self._by_name[name] = entry
        if isinstance(obj, Attribute):
            obj._add_policy_hook(lambda policy: self._set_policy(entry, policy))
            if obj.publish_policy is not None:
                self._set_policy(entry, obj.publish_policy)
            elif kind == ObjectKind.EVENT:
                self._set_policy(entry, PublishPolicy())  # every firing is published: remote waiters need them
        return entry

    def _class_id(self, class_name: str) -> int:
        known = well_known()
        if class_name in known:
            return known[class_name]
        if class_name not in self._local_classes:
            class_id = LOCAL_CLASS_BASE + len(self._local_classes)
            if class_id > 0xFF:
                raise ValueError(f"node {self.name!r} has too many classes")
            self._local_classes[class_name] = class_id
        return self._local_classes[class_name]

    def entry(self, key: str | int) -> Entry:
        """The lookup-table row for an object name or ID; LookupError if there is none."""
        table: dict[Any, Entry] = self._by_name if isinstance(key, str) else self._by_id
        try:
            return table[key]
        except KeyError:
            raise LookupError(f"node {self.name!r} has no object {key!r}") from None

    @property
    def entries(self) -> list[Entry]:
        with self._lock:
            return list(self._by_id.values())

    def _set_policy(self, entry: Entry, policy: PublishPolicy | None) -> None:
        old, entry.publisher = entry.publisher, None
        if old is not None:
            old.close()
        if policy is not None and not self._closed:
            entry.publisher = Publisher(self, entry, policy)

    # -- the client side ------------------------------------------------------------------------------------------

    def port(self, remote: str) -> Port:
        """The client port to node ``remote`` (one per remote node, shared by every client object and thread).

        ``remote`` is an address (asm_py.keys): ``m3``, a tool's ``~studio``, or ``b/m3`` on a medium with robots."""
        if remote not in self._ports:
            parse_address(remote)
        with self._lock:
            port = self._ports.get(remote)
            if port is None:
                port = self._ports[remote] = Port(self, remote)
            return port

    def lookup(self, remote: str, object_name: str, *, timeout: float | None = None) -> RemoteObject:
        """A client object for ``object_name`` on node ``remote``: RemoteAttribute, RemoteEvent or RemoteService."""
        check_name(object_name, "object name")
        port = self.port(remote)
        self._await_peer(remote, self.call_timeout if timeout is None else timeout)
        reply = port.call(
            Method.LOOKUP, 0, 0, object_name.encode("utf-8"), timeout=timeout, subject=f"{remote}/{object_name}"
        )
        return make_client(port, reply.data)

    def _await_peer(self, remote: str, timeout: float) -> None:
        """Give discovery up to ``timeout`` to see ``remote`` (a just-opened session may not have met it yet)."""
        if remote in self._seen:
            return
        address = parse_address(remote)
        if address.robot is not None and address.robot != self.transport.robot:
            return  # discovery lists this node's own robot: another robot's node answers or times out
        if address.robot is not None:  # this robot's node, named with its robot: discovery lists its segment
            remote = address.segment
            if remote in self._seen:
                return
        deadline = WALL_CLOCK.now() + timeout
        while remote not in self.discover():
            if WALL_CLOCK.now() >= deadline:
                return  # the request itself will time out and say so
            WALL_CLOCK.sleep(0.02)
        self._seen.add(remote)

    def group(self, group: str = BROADCAST) -> GroupPort:
        """The one-to-many port to ``group`` (default "all": every node); see asm_py.group."""
        return GroupPort(self, group)

    def join_group(self, group: str) -> None:
        """Receive the group messages sent to ``group`` from now on (every node is in "all")."""
        self.transport.join_group(group)

    def list_objects(self, remote: str, *, timeout: float | None = None) -> list[RemoteObject]:
        """Client objects for everything node ``remote`` has registered (lookup by ID, 1, 2, … until not found)."""
        port = self.port(remote)
        self._await_peer(remote, self.call_timeout if timeout is None else timeout)
        found: list[RemoteObject] = []
        for object_id in range(1, 256):
            try:
                reply = port.call(Method.LOOKUP, 0, object_id, timeout=timeout)
            except LookupError:
                break
            found.append(make_client(port, reply.data))
        return found

    def discover(self) -> list[str]:
        """The names of the live nodes reachable on the transport (this one included)."""
        return self.transport.peers()

    def on_discovery(self, callback: Callable[[str, bool], None]) -> Callable[[], None]:
        """Call ``callback(node_name, alive)`` when a node joins or leaves; returns a remover."""
        return self.transport.on_peer(callback)

    def estop(self, reason: str = "", *, lab: bool = False) -> None:
        """Emergency stop: every node of this node's robot (this one included) runs its e-stop handlers at once;
        with ``lab``, every node of every robot on the medium (the lab-wide stop)."""
        self.transport.estop(reason, lab=lab)

    def on_estop(self, callback: Callable[[str, str], None]) -> Callable[[], None]:
        """Call ``callback(source, reason)`` on every emergency stop; returns a remover."""
        return self.transport.on_estop(callback)

    def close(self) -> None:
        """Stop publishing, stop the server daemons, fail pending calls, leave the transport."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            entries = list(self._by_id.values())
            daemons = [d for group in self._daemons.values() for d in group]
            ports = list(self._ports.values())
            waits = self._waits
        for entry in entries:
            if entry.publisher is not None:
                entry.publisher.close()
        for daemon in daemons:
            if isinstance(daemon, PendingWait):
                assert waits is not None
                waits.cancel(daemon)
            else:
                daemon.stop(timeout=5)
        if waits is not None:
            waits.stop(timeout=5)
        for port in ports:
            port.fail_all(f"node {self.name!r} closed")
        self._unpeer()
        self.transport.close()

    def __enter__(self) -> Node:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the server side ------------------------------------------------------------------------------------------

    def _peer_changed(self, name: str, alive: bool) -> None:
        if not alive:
            self._seen.discard(name)
            port = self._ports.get(name)
            if port is not None:
                port.fail_all(f"node {name!r} left")

    def _on_message(self, source: str, data: bytes, respond: Responder | None = None) -> None:
        if len(data) > MAX_MESSAGE:
            self._refuse_oversized(source, data, respond)
            return
        try:
            message = decode(data)
        except ProtocolError as exc:
            self.dropped += 1
            log.debug("dropped a message from %r: %s", source, exc)
            return
        if message.kind == Kind.REPLY:
            port = self._ports.get(source)
            if port is not None:
                port.deliver(message)
            return
        if message.kind == Kind.PUBLICATION:
            return  # publications reach subscribers through transport.subscribe
        if respond is None:
            transport = self.transport

            def respond(reply: bytes) -> None:
                transport.send(source, reply)

        self._serve(source, message, respond)

    def _refuse_oversized(self, source: str, data: bytes, respond: Responder | None) -> None:
        """A message over MAX_MESSAGE is not decoded; a request that wants a reply is told why (TOO_LARGE)."""
        self.dropped += 1
        if version_of(data) != VERSION or kind_of(data) != Kind.REQUEST_REPLY:
            return
        reply = reply_head(data, Status.TOO_LARGE) + too_large(len(data)).encode()
        if respond is None:
            self.transport.send(source, reply)
        else:
            respond(reply)

    @staticmethod
    def _reply(respond: Responder, request: Message, status: int = Status.OK, data: bytes = b"") -> None:
        if request.wants_reply:  # the reply header in place (protocol.reply_to + encode, without re-validation)
            head = bytes((first_byte(Kind.REPLY, request.method), request.txn, status, request.object_id))
            respond(head + data)

    def _serve(self, source: str, request: Message, respond: Responder) -> None:
        try:
            entry = self._target(request)
            result = self._execute_now(source, entry, request, respond)
        except Exception as exc:  # every failure becomes a status; nothing escapes into the transport
            self._reply(respond, request, *self._failure(exc))
            return
        if result is not _DEFERRED:
            self._reply(respond, request, Status.OK, result)

    def _target(self, request: Message) -> Entry | None:
        if request.method == Method.LOOKUP and request.object_id == 0:
            return None
        if request.object_id == 0:  # group addressing: "the object of this class" on this node
            for entry in self.entries:
                if entry.class_id == request.class_id:
                    return entry
            raise LookupError(f"node {self.name!r} has no object of class {request.class_id:#04x}")
        entry = self.entry(request.object_id)
        if request.method != Method.LOOKUP and request.class_id != entry.class_id:
            raise LookupError(
                f"object {request.object_id} of node {self.name!r} is of class {entry.class_id:#04x}, "
                f"not {request.class_id:#04x} (did the node restart with other objects?)"
            )
        return entry

    def _execute_now(self, source: str, entry: Entry | None, request: Message, respond: Responder) -> bytes | object:
        """Run a request that cannot block and return its reply data, or hand it to a daemon (_DEFERRED)."""
        method = request.method
        if method == Method.LOOKUP:
            if entry is None:
                name = request.data.decode("utf-8", errors="strict") if request.data else ""
                if not name:
                    return bytes([len(self._by_id)]) + self.name.encode("utf-8")
                entry = self.entry(name)
            return describe_entry(entry)
        assert entry is not None
        obj = entry.obj
        if method in WRITES:
            if entry.read_only and method in (Method.SET, Method.RESET):
                raise ReadOnlyError(f"{entry.name!r} on node {self.name!r} is read-only: only the node writes it")
            if entry.guard is not None:
                entry.guard(method)
        if isinstance(obj, Attribute):
            if method == Method.GET:
                try:
                    return entry.codec.encode(obj.get(timeout=0))
                except AsmTimeout:
                    if request.timeout_seconds == 0:
                        raise
                return self._defer(
                    source, request, respond, lambda: entry.codec.encode(obj.get(request.timeout_seconds))
                )
            if method == Method.SET:
                value = entry.codec.decode(request.data)
                try:
                    obj.set(value, timeout=0)
                    return b""
                except AsmTimeout:
                    if request.timeout_seconds == 0:
                        raise
                return self._defer(source, request, respond, lambda: obj.set(value, request.timeout_seconds) or b"")
            if method == Method.RESET:
                obj.reset()
                return b""
            if method == Method.PEEK:
                return entry.codec.encode(obj.peek())
            if method == Method.STATUS:
                return bytes([1 if obj.valid else 0])
            if method == Method.WAIT and isinstance(obj, Event):
                return self._wait(source, request, respond, obj, entry.codec)
        elif isinstance(obj, Service):
            if method == Method.START:
                params = _parse_params(request.data)
                obj.start(*params)
                return b""
            if method == Method.STOP:
                if request.wants_reply:
                    return self._defer(source, request, respond, lambda: obj.stop(request.timeout_seconds) or b"")
                try:
                    obj.stop(timeout=0)
                except AsmTimeout:
                    pass  # asked to stop; it ends at its next checkpoint
                return b""
            if method == Method.SUSPEND:
                obj.suspend()
                return b""
            if method == Method.RESUME:
                obj.resume()
                return b""
            if method == Method.RESET:
                obj.reset()
                return b""
            if method == Method.STATUS:
                flags = (1 << 1 if obj.started else 0) | (1 << 2 if obj.running else 0)
                error = obj.last_error
                flags |= 1 << 3 if error is not None else 0
                return bytes([flags]) + (repr(error).encode("utf-8")[:200] if error is not None else b"")
        raise RemoteError(f"method {method} is not supported by {entry.kind.name.lower()} {entry.name!r}", 0)

    def _defer(self, source: str, request: Message, respond: Responder, operation: Callable[[], bytes]) -> object:
        with self._lock:
            daemon = _ServerDaemon(self, source, request, respond, operation)
            self._admit(source).add(daemon)
        daemon.start()
        return _DEFERRED

    def _wait(self, source: str, request: Message, respond: Responder, event: Event, codec: Codec) -> object:
        timeout = request.timeout_seconds
        wait = PendingWait(source, request, respond, None if timeout is None else self.clock.now() + timeout)
        with self._lock:
            self._admit(source).add(wait)
            if self._waits is None:
                self._waits = EventWaits(self.name, self._wait_answered, clock=self.clock)
            waits = self._waits
        waits.add(wait, event, codec)
        return _DEFERRED

    def _wait_answered(self, wait: PendingWait, failure: Exception | None, data: bytes) -> None:
        self._daemon_done(wait)
        if failure is None:
            self._reply(wait.respond, wait.request, Status.OK, data)
        else:
            self._reply(wait.respond, wait.request, *self._failure(failure))

    def _admit(self, source: str) -> set[Service | PendingWait]:
        """The client's set of blocking requests, if it and the node may take one more (lock held); BUSY if not."""
        active = self._daemons.setdefault(source, set())
        if len(active) >= self.max_daemons_per_client or self._closed:
            raise _Busy(f"client {source!r} already has {len(active)} blocking requests on node {self.name!r}")
        if sum(len(d) for d in self._daemons.values()) >= self.max_daemons:
            raise _Busy(f"node {self.name!r} already serves {self.max_daemons} blocking requests")
        return active

    def _daemon_done(self, daemon: Service | PendingWait) -> None:
        with self._lock:
            self._daemons.get(daemon.source, set()).discard(daemon)

    @staticmethod
    def _failure(exc: Exception) -> tuple[int, bytes]:
        """The status for a failed request (the inverse of remote.py's status-to-exception table)."""
        text = str(exc).encode("utf-8")[:120]
        for kind, status in _FAILURE_STATUS:
            if isinstance(exc, kind):
                return status, text
        log.error("request failed inside the node", exc_info=exc)
        return Status.INTERNAL, text


_DEFERRED = object()


class _Busy(Exception):
    pass


class _BadMessage(Exception):
    pass


def _parse_params(data: bytes) -> list[Any]:
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
        raise _BadMessage(f"service parameters nest deeper than {MAX_PARAMS_DEPTH} levels")
    try:
        params = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise _BadMessage(f"service parameters are not UTF-8: {exc}") from None
    except ValueError as exc:
        raise _BadMessage(f"service parameters are not JSON: {exc}") from None
    if not isinstance(params, list):
        raise ValueError("service parameters travel as a JSON array")
    return params


# First match wins: UnicodeDecodeError is a ValueError, so it must come before it.
_FAILURE_STATUS: tuple[tuple[type[Exception], int], ...] = (
    (TimeoutError, Status.TIMEOUT),
    (ServiceError, Status.SERVICE_ERROR),
    (_Busy, Status.BUSY),
    (RemoteError, Status.UNSUPPORTED),
    (_BadMessage, Status.BAD_MESSAGE),
    (UnicodeDecodeError, Status.BAD_MESSAGE),
    (RecursionError, Status.BAD_MESSAGE),
    (ReadOnlyError, Status.READ_ONLY),
    (EstopLatched, Status.ESTOP),
    (Locked, Status.LOCKED),
    (MessageTooLarge, Status.TOO_LARGE),
    (TypeError, Status.TYPE_ERROR),
    (ValueError, Status.VALUE_ERROR),
    (LookupError, Status.NOT_FOUND),
)


class _ServerDaemon(Service):
    """Serves one blocking request of one client (the paper's server daemon), then ends."""

    def __init__(
        self, node: Node, source: str, request: Message, respond: Responder, operation: Callable[[], bytes]
    ) -> None:
        super().__init__(f"daemon:{node.name}:{source}:{request.txn}", clock=node.clock)
        self.node = node
        self.source = source
        self.request = request
        self.respond = respond
        self.operation = operation

    def run(self) -> None:
        try:
            data = self.operation()
        except Exception as exc:
            self.node._reply(self.respond, self.request, *self.node._failure(exc))
            return
        self.node._reply(self.respond, self.request, Status.OK, data or b"")

    def on_stop(self) -> None:
        self.node._daemon_done(self)
