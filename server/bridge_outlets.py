"""A bridged node's publications on Zenoh: each object's publishers declared once, its JSON view formatted only while
someone watches it.

The bridge forwarded every publication frame of a running 128-module robot (about 5,000 a second) with two
``session.put`` calls — each resolving its key expression again — and a ``json.dumps`` of a view nobody may read
(issue 31). An :class:`Outlet` is what the node's own Zenoh transport does for itself (asm_py.transport.zenoh):
declared publishers, and for the view a :class:`~asm_py.transport.zenoh_watch.WatchedPublisher` that follows whether
it has a subscriber: the same piece.
"""

from __future__ import annotations

import json
import time

import zenoh

from asm_py.codec import to_json
from asm_py.protocol import txn_of
from asm_py.remote import RemoteAttribute, RemoteObject
from asm_py.transport.zenoh_watch import WatchedPublisher, direct

__all__ = ["Outlet", "direct"]


class Outlet:
    """One mirrored object's publications; ``close`` undeclares them."""

    __slots__ = ("_binary", "_prefix", "_view", "obj")

    def __init__(self, session: zenoh.Session, binary_key: str, view_key: str, node: str, obj: RemoteObject) -> None:
        self.obj = obj
        drop = zenoh.CongestionControl.DROP  # a publication is refreshed: never hold the bridge for a slow viewer
        self._binary = session.declare_publisher(binary_key, congestion_control=drop, express=False)
        self._view: WatchedPublisher | None = None
        if isinstance(obj, RemoteAttribute):  # only attributes and events publish values: a view needs a codec
            self._view = WatchedPublisher(session.declare_publisher(view_key, congestion_control=drop, express=False))
        names = {"node": node, "object": obj.name, "class": obj.info.class_name}
        self._prefix = json.dumps(names, separators=(",", ":"))[:-1] + ","

    @property
    def watched(self) -> bool:
        """Whether a subscriber matches the JSON view now."""
        return self._view is not None and self._view.watched

    def forward(self, data: bytes) -> bool:
        """Put one publication message; True if its JSON view went out too. A node unmirrored meanwhile (its
        publishers undeclared by the bridge's other thread) loses the message, as a node gone would."""
        try:
            self._binary.put(data)
        except zenoh.ZError:
            return False
        view, obj = self._view, self.obj
        if view is None or not view.watched or not isinstance(obj, RemoteAttribute):
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
        if self._view is not None:
            self._view.close()
        self._binary.undeclare()
