"""A bridged node's publications on Zenoh: each object's publishers declared once, each publication stamped with the
bridge's time, its JSON view formatted only while someone watches it.

The bridge forwarded every publication frame of a running 128-module robot (about 5,000 a second) with two
``session.put`` calls — each resolving its key expression again — and a ``json.dumps`` of a view nobody may read
(issue 31). An :class:`Outlet` is what the node's own Zenoh transport does for itself (asm_py.transport.zenoh):
declared publishers, and for the view a :class:`~asm_py.transport.zenoh_watch.WatchedPublisher` that follows whether
it has a subscriber: the same piece.

While anyone subscribes to it, the binary publication carries a Zenoh timestamp, and the view's ``t`` is that
timestamp: a recorder takes the binary publications (server/record_values.py) and writes the very view a
subscriber of the JSON key would have received, ``t`` included — instead of making the bridge format about 6,000
views a second for it (12-16 µs of the robot's CPU each, the robot's GIL held: 13-17 % of its GIL time with py-spy,
against 1-3 % for the stamped binary publications).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import zenoh

from asm_py.codec import BoolCodec, Codec, FloatCodec, IntCodec, to_json
from asm_py.protocol import txn_of
from asm_py.remote import RemoteAttribute, RemoteObject
from asm_py.transport.zenoh_watch import WatchedPublisher, direct

__all__ = ["Outlet", "direct", "stamp_seconds", "value_json", "view_prefix", "view_text"]


def view_prefix(node: str, object_name: str, class_name: str) -> str:
    """A JSON view up to its ``seq``: the same for every publication of one object, so formatted once."""
    return json.dumps({"node": node, "object": object_name, "class": class_name}, separators=(",", ":"))[:-1] + ","


def view_text(prefix: str, seq: int, t: float, value: str) -> str:
    """The JSON view of one publication (docs/protocol.md §6), ``value`` already JSON (:func:`value_json`), for the
    bridge that puts it and the recorder that writes it from the binary publication: one function, so the two are
    the same bytes."""
    return f'{prefix}"seq":{seq},"t":{t!r},"value":{value}}}'


_NOT_FINITE = {"nan": "NaN", "inf": "Infinity", "-inf": "-Infinity"}


def _float_json(value: float) -> str:
    text = float.__repr__(value)
    return _NOT_FINITE.get(text, text)


def _bool_json(value: bool) -> str:
    return "true" if value else "false"


def _any_json(value: Any) -> str:
    return json.dumps(to_json(value))


def value_json(codec: Codec) -> Callable[[Any], str]:
    """``json.dumps(to_json(value))`` for the values of ``codec``: the same text, the scalars without json's encoder
    (2 µs a value of the recorder's, at thousands a second)."""
    if isinstance(codec, FloatCodec):
        return _float_json
    if isinstance(codec, BoolCodec):
        return _bool_json
    if isinstance(codec, IntCodec):
        return int.__repr__
    return _any_json


def stamp_seconds(stamp: zenoh.Timestamp) -> float:
    """A publication's Zenoh timestamp as its view's ``t``, seconds since the epoch (the same float on both sides)."""
    return stamp.get_time_as_ntp64().as_secs_f64()


class Outlet:
    """One mirrored object's publications; ``close`` undeclares them."""

    __slots__ = ("_binary", "_json", "_prefix", "_session", "_view", "obj")

    def __init__(self, session: zenoh.Session, binary_key: str, view_key: str, node: str, obj: RemoteObject) -> None:
        self.obj = obj
        self._session = session
        drop = zenoh.CongestionControl.DROP  # a publication is refreshed: never hold the bridge for a slow viewer
        self._binary = WatchedPublisher(session.declare_publisher(binary_key, congestion_control=drop, express=False))
        self._view: WatchedPublisher | None = None
        self._json = _any_json
        if isinstance(obj, RemoteAttribute):  # only attributes and events publish values: a view needs a codec
            self._view = WatchedPublisher(session.declare_publisher(view_key, congestion_control=drop, express=False))
            self._json = value_json(obj.codec)
        self._prefix = view_prefix(node, obj.name, obj.info.class_name)

    @property
    def watched(self) -> bool:
        """Whether a subscriber matches the JSON view now."""
        return self._view is not None and self._view.watched

    def forward(self, data: bytes) -> bool:
        """Put one publication message; True if its JSON view went out too. A node unmirrored meanwhile (its
        publishers undeclared by the bridge's other thread) loses the message, as a node gone would."""
        view, obj = self._view, self.obj
        viewed = view is not None and view.watched
        try:
            if viewed or self._binary.watched:  # a stamp costs 1 µs: only for someone who receives it
                stamp = self._session.new_timestamp()
                self._binary.publisher.put(data, timestamp=stamp)
            else:
                self._binary.publisher.put(data)
                return False
        except zenoh.ZError:
            return False
        if view is None or not viewed or not isinstance(obj, RemoteAttribute):
            return False
        try:
            value = obj.codec.decode(data[4:])
        except ValueError:
            return False
        try:
            view.put(view_text(self._prefix, txn_of(data), stamp_seconds(stamp), self._json(value)))
        except zenoh.ZError:
            return False
        return True

    def close(self) -> None:
        if self._view is not None:
            self._view.close()
        self._binary.close()
