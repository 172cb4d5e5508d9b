"""A bridged node's publications on Zenoh: each object's publishers declared once, its JSON view formatted only while
someone watches it.

The bridge forwarded every publication frame of a running 128-module robot (about 5,000 a second) with two
``session.put`` calls — each resolving its key expression again — and a ``json.dumps`` of a view nobody may read
(issue 31). An :class:`Outlet` is what the node's own Zenoh transport does for itself (asm_py.transport.zenoh):
declared publishers, and a matching listener that says whether the view has a subscriber.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Any

import zenoh

from asm_py.codec import to_json
from asm_py.protocol import txn_of
from asm_py.remote import RemoteAttribute, RemoteObject


def direct(callback: Callable[[Any], None]) -> zenoh.handlers.Callback[Any]:
    """``callback`` run on the Zenoh thread that received the item, not a Python thread of its own (zenoh-python's
    default: one per callback, two per bridged module): only for callbacks that never block."""
    return zenoh.handlers.Callback(callback, indirect=False)


class Outlet:
    """One mirrored object's publications; ``close`` undeclares them."""

    __slots__ = ("_binary", "_listener", "_prefix", "_view", "obj", "watched")

    def __init__(self, session: zenoh.Session, binary_key: str, view_key: str, node: str, obj: RemoteObject) -> None:
        self.obj = obj
        drop = zenoh.CongestionControl.DROP  # a publication is refreshed: never hold the bridge for a slow viewer
        self._binary = session.declare_publisher(binary_key, congestion_control=drop, express=False)
        self._view: zenoh.Publisher | None = None
        self._listener: Any = None
        self.watched = False
        if isinstance(obj, RemoteAttribute):  # only attributes and events publish values: a view needs a codec
            self._view = session.declare_publisher(view_key, congestion_control=drop, express=False)
            self.watched = bool(self._view.matching_status.matching)  # pyright: ignore[reportAttributeAccessIssue]  # zenoh's stub says bool; it is a MatchingStatus
            self._listener = self._view.declare_matching_listener(direct(self._matching))
        names = {"node": node, "object": obj.name, "class": obj.info.class_name}
        self._prefix = json.dumps(names, separators=(",", ":"))[:-1] + ","

    def _matching(self, status: zenoh.MatchingStatus) -> None:
        self.watched = status.matching

    def forward(self, data: bytes) -> bool:
        """Put one publication message; True if its JSON view went out too. A node unmirrored meanwhile (its
        publishers undeclared by the bridge's other thread) loses the message, as a node gone would."""
        try:
            self._binary.put(data)
        except zenoh.ZError:
            return False
        view, obj = self._view, self.obj
        if view is None or not self.watched or not isinstance(obj, RemoteAttribute):
            return False
        try:
            value = obj.codec.decode(data[4:])
        except ValueError:
            return False
        try:
            view.put(f'{self._prefix}"seq":{txn_of(data)},"t":{time.time()!r},"value":{json.dumps(to_json(value))}}}')
        except zenoh.ZError:
            return False
        return True

    def close(self) -> None:
        if self._listener is not None:
            self._listener.undeclare()
        if self._view is not None:
            self._view.undeclare()
        self._binary.undeclare()
