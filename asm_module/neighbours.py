"""How a module hears which state its neighbours are in, and the signals broadcast to all: the global events of
program.py.

A module on a bus hears its neighbours' ``gait.state`` publications (they are published on every change anyway,
so coordination costs the bus nothing more); modules in one process without a bus — a preview — share a
:class:`LocalNeighbours` hub instead. Either way the runtime only ever sees ``watch(module_id, callback)``, and
the gait service counts what it heard from the tick after it arrived, so both make the same decisions.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Callable
from typing import Protocol

from asm_py.codec import UINT8
from asm_py.node import Node
from asm_py.protocol import HEADER_SIZE, Kind, Method, first_byte, has_timeout

StateCallback = Callable[[int], None]
_STATE = struct.Struct("<H")


class Neighbours(Protocol):
    def watch(self, module_id: int, callback: StateCallback) -> Callable[[], None]:
        """Call ``callback(state)`` whenever module ``module_id`` enters a state; returns a remover."""
        ...

    def broadcast(self, signal: int) -> None:
        """Send broadcast signal ``signal`` to every module."""
        ...


class LocalNeighbours:
    """Modules of one process (a preview): each runtime announces its states here."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._watchers: dict[int, tuple[StateCallback, ...]] = {}

    def watch(self, module_id: int, callback: StateCallback) -> Callable[[], None]:
        with self._lock:
            self._watchers[module_id] = (*self._watchers.get(module_id, ()), callback)

        def remove() -> None:
            with self._lock:
                self._watchers[module_id] = tuple(c for c in self._watchers.get(module_id, ()) if c is not callback)

        return remove

    def announce(self, module_id: int, state: int) -> None:
        for callback in self._watchers.get(module_id, ()):
            callback(state)

    def listen(self, callback: StateCallback) -> Callable[[], None]:
        """Call ``callback(signal)`` for every broadcast signal (every module of the process listens)."""
        return self.watch(0, callback)

    def broadcast(self, signal: int) -> None:
        """A module emits ``signal``: every module hears it, the emitter too (as a group message reaches all)."""
        self.announce(0, signal)


class BusNeighbours:
    """A module's neighbours heard through its node: the ``gait.state`` publications of module IDs.

    On CAN the publisher is named by its ID (``can.<id>``) and the object by the ID it has on this module: every
    module registers the same objects in the same order (docs/protocol.md §9). Elsewhere modules are named m<id>.
    """

    def __init__(self, node: Node) -> None:
        self._node = node

    def watch(self, module_id: int, callback: StateCallback) -> Callable[[], None]:
        node = self._node
        object_id = node.entry("gait.state").object_id
        head = first_byte(Kind.PUBLICATION, Method.PUBLISH)

        def on_publication(data: bytes) -> None:
            if len(data) == HEADER_SIZE + _STATE.size and data[0] == head and not has_timeout(data):
                callback(_STATE.unpack_from(data, HEADER_SIZE)[0])

        name = f"can.{module_id}" if hasattr(node.transport, "node_id") else f"m{module_id}"
        return node.transport.subscribe(name, "gait.state", on_publication, object_id=object_id)

    def broadcast(self, signal: int) -> None:
        send_signal(self._node, signal)


def send_signal(node: Node, signal: int) -> None:
    """Broadcast ``signal`` from ``node`` (a module's emitting state, or a tool): one group SET of ``gait.signal`` to
    every node — a classic CAN frame, 42 00 2f 00 and the signal."""
    node.group().attribute("gait.signal", UINT8).set(signal)
