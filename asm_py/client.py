"""The client side of a node: its ports to other nodes, lookups, and the wait for discovery.

``lookup`` turns a name into a client object with the local interface (asm_py.remote) through the port to the
remote node; a node just joined may not have met its peer yet, so the first lookup of a peer waits up to its timeout
for discovery to list it. When discovery reports that a peer left, every call in flight to it fails at once.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

from .clock import WALL_CLOCK
from .keys import parse_address
from .port import Port
from .protocol import Method
from .remote import RemoteObject, make_client
from .transport.base import check_name

if TYPE_CHECKING:
    from .node import Node

DISCOVERY_POLL = 0.02
"""Seconds between looks at discovery while a first lookup waits for its peer."""


class Client:
    """Ports, lookups and discovery for one node; see the module docstring."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self._lock = threading.Lock()
        self._ports: dict[str, Port] = {}
        self._seen: set[str] = set()

    def port(self, remote: str) -> Port:
        """The port to node ``remote`` (see Node.port)."""
        if remote not in self._ports:
            parse_address(remote)
        with self._lock:
            port = self._ports.get(remote)
            if port is None:
                port = self._ports[remote] = Port(self.node, remote)
            return port

    def existing_port(self, remote: str) -> Port | None:
        """The port to ``remote`` if one was made (a reply from a node never asked has none)."""
        return self._ports.get(remote)

    def lookup(self, remote: str, object_name: str, timeout: float | None) -> RemoteObject:
        check_name(object_name, "object name")
        port = self.port(remote)
        self.await_peer(remote, self.node.call_timeout if timeout is None else timeout)
        reply = port.call(
            Method.LOOKUP, 0, 0, object_name.encode("utf-8"), timeout=timeout, subject=f"{remote}/{object_name}"
        )
        return make_client(port, reply.data)

    def list_objects(self, remote: str, timeout: float | None) -> list[RemoteObject]:
        port = self.port(remote)
        self.await_peer(remote, self.node.call_timeout if timeout is None else timeout)
        found: list[RemoteObject] = []
        for object_id in range(1, 256):
            try:
                reply = port.call(Method.LOOKUP, 0, object_id, timeout=timeout)
            except LookupError:
                break
            found.append(make_client(port, reply.data))
        return found

    def await_peer(self, remote: str, timeout: float) -> None:
        """Give discovery up to ``timeout`` to see ``remote`` (a just-opened session may not have met it yet)."""
        if remote in self._seen:
            return
        address = parse_address(remote)
        transport = self.node.transport
        if address.robot is not None and address.robot != transport.robot:
            return  # discovery lists this node's own robot: another robot's node answers or times out
        if address.robot is not None:  # this robot's node, named with its robot: discovery lists its segment
            remote = address.segment
            if remote in self._seen:
                return
        deadline = WALL_CLOCK.now() + timeout
        while remote not in transport.peers():
            if WALL_CLOCK.now() >= deadline:
                return  # the request itself will time out and say so
            WALL_CLOCK.sleep(DISCOVERY_POLL)
        self._seen.add(remote)

    def peer_changed(self, name: str, alive: bool) -> None:
        """Discovery saw ``name`` come or go: a peer that left fails every call in flight to it."""
        if not alive:
            self._seen.discard(name)
            port = self._ports.get(name)
            if port is not None:
                port.fail_all(f"node {name!r} left")

    def close(self, reason: str) -> None:
        with self._lock:
            ports = list(self._ports.values())
        for port in ports:
            port.fail_all(reason)
