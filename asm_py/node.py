"""The node: one name on a transport, with a local side (registry and server) and a client side.

``node.register(obj)`` gives an attribute, event or service a (class ID, object ID) in the node's registry
(asm_py.registry); the server (asm_py.server) then answers protocol requests for it from any transport (paper
section 3, Figure 3). ``node.lookup(remote, name)`` returns a client object with the local interface
(asm_py.client, asm_py.remote). ``_on_message`` is the one place where a received message becomes a protocol call:
a reply goes to the port that waits for it, a request to the server.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from .attribute import PublishPolicy
from .client import Client
from .clock import WALL_CLOCK, Clock
from .group import GroupPort
from .port import Port
from .protocol import (
    MAX_MESSAGE,
    VERSION,
    WRITES,
    Kind,
    ProtocolError,
    Status,
    decode,
    kind_of,
    reply_head,
    too_large,
    version_of,
)
from .publisher import Publisher
from .registry import Entry, Guard, Registrable, Registry
from .remote import RemoteObject
from .server import Server
from .speedups import speedups
from .transport.base import BROADCAST, Responder, Transport, check_name

log = logging.getLogger("asm_py.node")
_REPLY, _PUBLICATION = int(Kind.REPLY), int(Kind.PUBLICATION)

__all__ = ["WRITES", "Entry", "Guard", "Node", "Registrable"]


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
        self.registry = Registry(self.name, self._publisher)
        self.server = Server(
            self.name,
            self.registry,
            self.clock,
            max_daemons_per_client=max_daemons_per_client,
            max_daemons=max_daemons,
        )
        self.client = Client(self)
        self._closed = False
        self._decode = speedups.decode if speedups is not None and transport.compiled else None
        """The C decoder (None for a message it refuses: the Python decoder then says why), or None."""
        self.dropped = 0
        """Messages dropped unread: malformed, or over MAX_MESSAGE."""
        transport.attach(name, self._on_message)
        self._unpeer = transport.on_peer(self.client.peer_changed)

    def _publisher(self, entry: Entry, policy: PublishPolicy) -> Publisher:
        return Publisher(self, entry, policy)

    # -- the local side -------------------------------------------------------------------------------------------

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
        return self.registry.register(obj, name=name, class_name=class_name, read_only=read_only, guard=guard)

    def entry(self, key: str | int) -> Entry:
        """The lookup-table row for an object name or ID; LookupError if there is none."""
        return self.registry.by_name(key) if isinstance(key, str) else self.registry.by_id(key)

    @property
    def entries(self) -> list[Entry]:
        return self.registry.entries()

    # -- the client side ------------------------------------------------------------------------------------------

    def port(self, remote: str) -> Port:
        """The client port to node ``remote`` (one per remote node, shared by every client object and thread).

        ``remote`` is an address (asm_py.keys): ``m3``, a tool's ``~studio``, or ``b/m3`` on a medium with robots."""
        return self.client.port(remote)

    def lookup(self, remote: str, object_name: str, *, timeout: float | None = None) -> RemoteObject:
        """A client object for ``object_name`` on node ``remote``: RemoteAttribute, RemoteEvent or RemoteService."""
        return self.client.lookup(remote, object_name, timeout)

    def list_objects(self, remote: str, *, timeout: float | None = None) -> list[RemoteObject]:
        """Client objects for everything node ``remote`` has registered (lookup by ID, 1, 2, … until not found)."""
        return self.client.list_objects(remote, timeout)

    def group(self, group: str = BROADCAST) -> GroupPort:
        """The one-to-many port to ``group`` (default "all": every node); see asm_py.group."""
        return GroupPort(self, group)

    def join_group(self, group: str) -> None:
        """Receive the group messages sent to ``group`` from now on (every node is in "all")."""
        self.transport.join_group(group)

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
        if self._closed:
            return
        self._closed = True
        self.registry.close()
        self.server.close()
        self.client.close(f"node {self.name!r} closed")
        self._unpeer()
        self.transport.close()

    def __enter__(self) -> Node:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the receive path -----------------------------------------------------------------------------------------

    def _on_message(self, source: str, data: bytes, respond: Responder | None = None) -> None:
        if len(data) > MAX_MESSAGE:
            self._refuse_oversized(source, data, respond)
            return
        fast = self._decode
        message = None if fast is None else fast(data)
        if message is None:
            try:
                message = decode(data)
            except ProtocolError as exc:
                self.dropped += 1
                log.debug("dropped a message from %r: %s", source, exc)
                return
        kind = message[0]
        if kind == _REPLY:
            port = self.client.existing_port(source)
            if port is not None:
                port.deliver(message)
            return
        if kind == _PUBLICATION:
            return  # publications reach subscribers through transport.subscribe
        if respond is None:
            transport = self.transport

            def send_back(reply: bytes) -> None:
                transport.send(source, reply)

            respond = send_back
        self.server.serve(source, message, respond)

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
