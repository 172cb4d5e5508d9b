"""An in-process transport for tests and simulation: real asynchronous delivery, no sockets.

Every node has its own delivery thread, as a real network stack would, so a handler never runs on the sender's
thread (a node can call itself without deadlock) and messages between two nodes arrive in order.
"""

from __future__ import annotations

import logging
import threading
from collections import defaultdict, deque
from collections.abc import Callable

from .base import BROADCAST, PublicationHandler, Transport

log = logging.getLogger("asm_py.transport.memory")


class MemoryNetwork:
    """The medium shared by the MemoryTransports of one process."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.nodes: dict[str, MemoryTransport] = {}
        self.subscriptions: dict[tuple[str, str], list[tuple[MemoryTransport, PublicationHandler]]] = defaultdict(list)

    def members(self, group: str) -> list[MemoryTransport]:
        with self.lock:
            return [t for t in self.nodes.values() if group == BROADCAST or group in t.groups]


class MemoryTransport(Transport):
    """A node's port on a :class:`MemoryNetwork`."""

    def __init__(self, network: MemoryNetwork) -> None:
        super().__init__()
        self.network = network
        self._queue: deque[Callable[[], None]] = deque()
        self._wake = threading.Condition()
        self._closed = False
        self._thread: threading.Thread | None = None

    def _open(self, name: str) -> None:
        with self.network.lock:
            if name in self.network.nodes:
                raise ValueError(f"a node named {name!r} is already on this network")
            self.network.nodes[name] = self
            others = [t for t in self.network.nodes.values() if t is not self]
        self._thread = threading.Thread(target=self._pump, name=f"asm-mem:{name}", daemon=True)
        self._thread.start()
        for other in others:
            other._post(lambda o=other, n=name: o._peer_changed(n, True))

    def _join(self, group: str) -> None:
        pass  # membership is read from self.groups at send time

    def _post(self, work: Callable[[], None], *, urgent: bool = False) -> None:
        """Queue ``work`` for this node's thread; ``urgent`` work (an e-stop) goes before everything queued."""
        with self._wake:
            if self._closed:
                return
            if urgent:
                self._queue.appendleft(work)
            else:
                self._queue.append(work)
            self._wake.notify()

    def _pump(self) -> None:
        while True:
            with self._wake:
                while not self._queue and not self._closed:
                    self._wake.wait()
                if self._closed and not self._queue:
                    return
                work = self._queue.popleft()
            try:
                work()
            except Exception:  # a subscriber's failure (a refused publication) must not end this node's delivery
                log.exception("delivery to %s failed", self.name)

    def send(self, dest: str, data: bytes) -> None:
        source = self.name
        target = self.network.nodes.get(dest)
        if target is not None:
            target._post(lambda: target._deliver(source, data))

    def _send_estop(self, reason: str, lab: bool) -> None:
        source = self.name
        with self.network.lock:
            others = [t for t in self.network.nodes.values() if t is not self]
        for target in others:
            target._post(lambda t=target: t._estop_received(source, reason), urgent=True)

    def send_group(self, group: str, data: bytes) -> None:
        source = self.name
        for target in self.network.members(group):
            if target is not self:
                target._post(lambda t=target: t._deliver(source, data))

    def publish(self, object_name: str, data: bytes, json_text: Callable[[], str] | None = None) -> None:
        with self.network.lock:
            subscribers = list(self.network.subscriptions.get((self.name, object_name), ()))
        for transport, callback in subscribers:
            transport._post(lambda c=callback: c(data))

    def subscribe(
        self, node: str, object_name: str, callback: PublicationHandler, *, object_id: int | None = None
    ) -> Callable[[], None]:
        entry = (self, callback)
        with self.network.lock:
            self.network.subscriptions[(node, object_name)].append(entry)

        def remove() -> None:
            with self.network.lock:
                entries = self.network.subscriptions.get((node, object_name), [])
                if entry in entries:
                    entries.remove(entry)

        return remove

    def peers(self) -> list[str]:
        with self.network.lock:
            return sorted(self.network.nodes)

    def _close(self) -> None:
        with self.network.lock:
            if self.network.nodes.get(self._name or "") is self:
                del self.network.nodes[self._name or ""]
            for entries in self.network.subscriptions.values():
                entries[:] = [e for e in entries if e[0] is not self]
            others = list(self.network.nodes.values())
        name = self._name
        for other in others:
            other._post(lambda o=other: o._peer_changed(name or "", False))
        with self._wake:
            self._closed = True
            self._wake.notify()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5)
