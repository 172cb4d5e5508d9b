"""The transport base: what every medium shares, so that a medium only writes how bytes move.

As python-can's ``BusABC`` does for buses, the base does the common work — attaching the node, shielding the
transport's receive threads from a failing handler, fanning out peer (discovery) events, counting — and a concrete
transport implements ``_open``, ``send``, ``send_group``, ``publish``, ``subscribe``, ``_join``, ``peers`` and
``_close``. Every transport passes the same conformance suite (tests/transport/test_transport_conformance.py).

Addresses are node names (``[A-Za-z0-9_.-]``, at most 64 characters). The group ``"all"`` is every node: a
message sent to it is the broadcast of the paper.
"""

from __future__ import annotations

import functools
import logging
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext

from .._contract import ESTOP_REASON_MAX
from ..keys import check_name
from ..speedups import COMPILED

log = logging.getLogger("asm_py.transport")

Responder = Callable[[bytes], None]
"""Sends the reply to one received request back the way it came (e.g. as a Zenoh query's reply)."""
MessageHandler = Callable[[str, bytes, Responder | None], None]
"""Called with (source node name, message bytes, responder or None) for each message to this node or its groups;
with None, a reply is sent with ``send(source, …)``."""
PeerHandler = Callable[[str, bool], None]
"""Called with (node name, alive) when a node appears or disappears."""
PublicationHandler = Callable[[bytes], None]
PublicationSender = Callable[[bytes, Callable[[], str] | None], None]
"""Sends one publication of one object of this node: ``sender(data, json_text)``, as :meth:`Transport.publish`."""
EstopHandler = Callable[[str, str], None]
"""Called with (source node name, reason) when an emergency stop arrives."""

BROADCAST = "all"
__all__ = ["BROADCAST", "ESTOP_REASON_MAX", "PublicationSender", "Responder", "Transport", "check_name", "short_reason"]


def short_reason(reason: str) -> str:
    """``reason`` cut to at most ESTOP_REASON_MAX bytes of UTF-8, never inside a character."""
    return reason.encode("utf-8")[:ESTOP_REASON_MAX].decode("utf-8", errors="ignore")


class Transport(ABC):
    """Moves ASM messages between named nodes; see the module docstring."""

    direct_requests = False
    """True when :meth:`request` does a round trip in the caller's thread, faster than send + deliver."""
    robot: str | None = None
    """The robot (namespace) the node belongs to on media that carry several robots (Zenoh); None elsewhere: a CAN
    bus or an in-process network is one robot."""

    def __init__(self) -> None:
        self.compiled = COMPILED
        """Whether this transport and its node run the C hot path (asm_py.speedups)."""
        self._name: str | None = None
        self._on_message: MessageHandler | None = None
        self._peer_handlers: tuple[PeerHandler, ...] = ()
        self._estop_handlers: tuple[EstopHandler, ...] = ()
        self._groups: set[str] = set()
        self._lock = threading.Lock()
        self.received = 0
        self.handler_errors = 0
        self.estops = 0

    @property
    def name(self) -> str:
        if self._name is None:
            raise RuntimeError("transport is not attached to a node yet")
        return self._name

    @property
    def address(self) -> str:
        """This node as others address it and as :meth:`peers` lists it: its name (a Zenoh tool's is ``~name``)."""
        return self.name

    def attach(self, name: str, on_message: MessageHandler) -> None:
        """Connect as node ``name``; ``on_message`` is called for every message to it, its groups or everyone."""
        if self._name is not None:
            raise RuntimeError(f"transport already attached as {self._name!r}")
        self._name = check_name(name)
        self._on_message = on_message
        self._open(self._name)
        self.join_group(BROADCAST)

    def join_group(self, group: str) -> None:
        """Receive what is sent to ``group`` from now on."""
        check_name(group, "group name")
        with self._lock:
            if group in self._groups:
                return
            self._groups.add(group)
        self._join(group)

    @property
    def groups(self) -> frozenset[str]:
        return frozenset(self._groups)

    def on_peer(self, callback: PeerHandler) -> Callable[[], None]:
        """Call ``callback(name, alive)`` when a node joins or leaves; returns a function that removes it."""
        return self._add_handler("_peer_handlers", callback)

    def on_estop(self, callback: EstopHandler) -> Callable[[], None]:
        """Call ``callback(source, reason)`` on every emergency stop, this node's own included; returns a remover.

        Handlers run on the transport's receive thread, the moment the stop arrives: keep them short (stop
        actuators, set a flag), never blocking.
        """
        return self._add_handler("_estop_handlers", callback)

    def _add_handler(self, field: str, callback: Callable[..., None]) -> Callable[[], None]:
        """Append to the copy-on-write tuple ``field`` (read without the lock by receive threads); return a remover."""
        with self._lock:
            setattr(self, field, (*getattr(self, field), callback))

        def remove() -> None:
            with self._lock:
                setattr(self, field, tuple(h for h in getattr(self, field) if h is not callback))

        return remove

    def estop(self, reason: str = "", *, lab: bool = False) -> None:
        """Send an emergency stop to every node of this node's robot at the medium's highest priority — with
        ``lab``, to every node of every robot on the medium — and act on it here too.

        Handlers here run first (this node stops at once, even if the medium fails); the reason is cut to
        ESTOP_REASON_MAX bytes of UTF-8 so the stop is one frame everywhere."""
        reason = short_reason(reason)
        self._estop_received(self.name, reason)
        self._send_estop(reason, lab)

    def close(self) -> None:
        """Leave the network; idempotent."""
        if self._name is not None:
            self._close()
        self._on_message = None

    # -- for concrete transports ----------------------------------------------------------------------------------

    def _deliver(self, source: str, data: bytes, respond: Responder | None = None) -> None:
        """Hand a received message to the node; a failing handler is logged, never raised into the medium."""
        handler = self._on_message
        if handler is None:
            return
        self.received += 1
        try:
            handler(source, data, respond)
        except Exception:
            self.handler_errors += 1
            log.exception("node %r failed to handle a message from %r", self._name, source)

    def _estop_received(self, source: str, reason: str) -> None:
        self.estops += 1
        for handler in self._estop_handlers:
            try:
                handler(source, reason)
            except Exception:
                log.exception("e-stop handler failed")

    def _peer_changed(self, name: str, alive: bool) -> None:
        for handler in self._peer_handlers:
            try:
                handler(name, alive)
            except Exception:
                log.exception("peer callback failed for %r", name)

    @abstractmethod
    def _open(self, name: str) -> None:
        """Join the medium as ``name``."""

    @abstractmethod
    def _join(self, group: str) -> None:
        """Start receiving messages sent to ``group``."""

    @abstractmethod
    def send(self, dest: str, data: bytes) -> None:
        """Send a message to node ``dest`` (it arrives with this node's name as source)."""

    @abstractmethod
    def send_group(self, group: str, data: bytes) -> None:
        """Send one message to every member of ``group`` (``"all"``: every node)."""

    @abstractmethod
    def publish(self, object_name: str, data: bytes, json_text: Callable[[], str] | None = None) -> None:
        """Publish a PUBLICATION message of this node's object ``object_name``.

        ``json_text`` makes the JSON view of the publication; a transport with a JSON view calls it only when
        someone watches that view, so an unwatched view costs nothing.
        """

    def publication_sender(self, object_name: str) -> PublicationSender:
        """``publish`` for one object, its route resolved once: a published attribute sends through this on every
        set, so a transport that can (Zenoh: the declared publisher) leaves out the lookup per publication."""
        return functools.partial(self.publish, object_name)

    @abstractmethod
    def subscribe(
        self, node: str, object_name: str, callback: PublicationHandler, *, object_id: int | None = None
    ) -> Callable[[], None]:
        """Receive the publications of ``node``'s ``object_name``, across restarts of that node; returns a remover.

        ``object_id`` (from the lookup) is for media that address objects by ID only, such as CAN.
        """

    @abstractmethod
    def _send_estop(self, reason: str, lab: bool) -> None:
        """Broadcast an emergency stop (every other node calls its e-stop handlers); ``lab``: beyond this robot, on
        media that carry several."""

    @abstractmethod
    def peers(self) -> list[str]:
        """The names of the live nodes, this one included."""

    def request(self, dest: str, data: bytes, wait: float) -> bytes | None:
        """Send a request that wants a reply and return the reply, or None if none came within ``wait`` seconds.

        Only for transports with ``direct_requests``; the others deliver replies as messages.
        """
        raise NotImplementedError(f"{type(self).__name__} delivers replies as messages")

    def wait_reply(self, done: threading.Lock, wait: float | None, source: str, head: bytes) -> bool:
        """Wait until ``done`` is released — the delivery of the reply from ``source`` whose data begin with
        ``head`` completes the call — or ``wait`` seconds pass (None: without limit); whether it was released.

        The base blocks; on CAN the caller reads the bus itself meanwhile (asm_py.transport.can_reader)."""
        return done.acquire(True, -1 if wait is None else max(0.0, wait))

    def waiting(self, done: threading.Lock) -> AbstractContextManager[None]:
        """Around a wait until ``done`` is released that does not go through :meth:`wait_reply` (a service
        thread's, which its service's stop must interrupt): the medium is read for it meanwhile."""
        return nullcontext()

    @abstractmethod
    def _close(self) -> None:
        """Leave the medium and release every resource (threads, sockets)."""
