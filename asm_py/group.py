"""One-to-many ports: one message to every member of a group (paper section 3, "ports are one-to-one or
one-to-many"; MDCN's group and broadcast destinations).

A group message addresses *the object of a class* on each member (object ID 0 in the header), so the class must
mean the same thing on every node: one of the well-known classes (``asm_py.classes.well_known()``: "joint.goal",
"gait.service", …) or an explicit class ID. Group requests never ask for a reply — with many receivers there is no
single answer to wait for, and on CAN one frame reaches every member at once. To read values back, use each
member's one-to-one port (``node.lookup``) or subscribe to its publications.

    legs = node.group("legs")
    legs.service("gait.service").start()          # every member's gait starts on one message
    node.group().attribute("joint.goal", "float32").set(0.0)   # "all": the broadcast
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

from .classes import well_known
from .codec import Codec
from .codec_parse import parse_codec
from .protocol import Kind, Message, Method, check_size, encode
from .transport.base import BROADCAST, check_name

if TYPE_CHECKING:
    from .node import Node


def class_id_of(cls: str | int) -> int:
    """The class ID a group message carries: a well-known class name, or an ID given as a number."""
    if isinstance(cls, int) and not isinstance(cls, bool):
        if not 1 <= cls <= 0xFF:
            raise ValueError(f"class ID {cls} must be 1..255")
        return cls
    known = well_known()
    if isinstance(cls, str) and cls in known:
        return known[cls]
    raise LookupError(
        f"class {cls!r} has no network-wide ID; group messages need a well-known class "
        f"({', '.join(sorted(known))}) or an explicit class ID"
    )


class GroupPort:
    """The one-to-many port from a node to a group (``"all"``: every node)."""

    def __init__(self, node: Node, group: str = BROADCAST) -> None:
        self.node = node
        self.group = check_name(group, "group name")
        self.sent = 0

    def send(self, method: Method, cls: str | int, data: bytes = b"") -> None:
        """Send one request (no reply) for the object of class ``cls`` on every member."""
        raw = check_size(encode(Message(Kind.REQUEST, method, 0, class_id_of(cls), 0, data=data)), self)
        self.node.transport.send_group(self.group, raw)
        self.sent += 1

    def attribute(self, cls: str | int, codec: Codec | str) -> GroupAttribute:
        """The attribute of class ``cls`` on every member, written with ``codec``."""
        return GroupAttribute(self, class_id_of(cls), codec if isinstance(codec, Codec) else parse_codec(codec))

    def service(self, cls: str | int) -> GroupService:
        """The service of class ``cls`` on every member."""
        return GroupService(self, class_id_of(cls))

    def __repr__(self) -> str:
        return f"<GroupPort {self.node.name} -> {self.group}>"


class GroupAttribute:
    """Writes one attribute class on every group member; each member applies its own checks (limits, types)."""

    def __init__(self, port: GroupPort, class_id: int, codec: Codec) -> None:
        self.port = port
        self.class_id = class_id
        self.codec = codec

    def set(self, value: Any) -> None:
        """Send the value to every member (encoded here: a bad value fails before anything is sent)."""
        self.port.send(Method.SET, self.class_id, self.codec.encode(value))

    def reset(self) -> None:
        self.port.send(Method.RESET, self.class_id)


class GroupService:
    """Controls one service class on every group member at once."""

    def __init__(self, port: GroupPort, class_id: int) -> None:
        self.port = port
        self.class_id = class_id

    def start(self, *params: Any) -> None:
        self.port.send(Method.START, self.class_id, json.dumps(list(params)).encode("utf-8") if params else b"")

    def stop(self) -> None:
        self.port.send(Method.STOP, self.class_id)

    def suspend(self) -> None:
        self.port.send(Method.SUSPEND, self.class_id)

    def resume(self) -> None:
        self.port.send(Method.RESUME, self.class_id)

    def reset(self) -> None:
        self.port.send(Method.RESET, self.class_id)
