"""The LOOKUP reply, both ways: what a node says about one of its objects (docs/protocol.md, "Lookup").

The server encodes a registry row with ``describe_entry``; the client decodes it with ``parse_description`` into
the ObjectInfo its client object is built from. One module, so the two sides cannot drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from .codec import Codec
from .codec_parse import codec_from_descriptor
from .protocol import LookupFlag, ObjectKind, ProtocolError

if TYPE_CHECKING:
    from .registry import Entry


@dataclass(frozen=True)
class ObjectInfo:
    """What a lookup reply tells about an object."""

    class_id: int
    object_id: int
    kind: ObjectKind
    sync_get: bool
    sync_set: bool
    published: bool
    codec: Codec
    name: str
    class_name: str
    read_only: bool = False
    """Only the node writes it: a remote set or reset is answered READ_ONLY."""


def describe_entry(entry: Entry) -> bytes:
    """The data of a LOOKUP reply for one registered object."""
    obj = entry.obj
    published = getattr(obj, "publish_policy", None) is not None or entry.kind == ObjectKind.EVENT
    flags = (
        (LookupFlag.SYNC_GET if getattr(obj, "sync_get", False) else 0)
        | (LookupFlag.SYNC_SET if getattr(obj, "sync_set", False) else 0)
        | (LookupFlag.PUBLISHED if published else 0)
        | (LookupFlag.READ_ONLY if entry.read_only else 0)
    )
    descriptor = entry.codec.descriptor()
    name = entry.name.encode("utf-8")
    head = bytes([entry.class_id, entry.object_id, entry.kind, flags, len(descriptor)])
    return head + descriptor + bytes([len(name)]) + name + entry.class_name.encode("utf-8")


def describe_node(name: str, objects: int) -> bytes:
    """The data of a LOOKUP reply to an empty name: how many objects the node has, and its name."""
    return bytes([objects]) + name.encode("utf-8")


def parse_description(data: bytes) -> ObjectInfo:
    """The ObjectInfo in a LOOKUP reply's data; ProtocolError if it is malformed."""
    try:
        class_id, object_id, kind, flags, length = data[:5]
        descriptor = data[5 : 5 + length]
        offset = 5 + length
        name_length = data[offset]
        name = data[offset + 1 : offset + 1 + name_length].decode("utf-8")
        class_name = data[offset + 1 + name_length :].decode("utf-8")
        return ObjectInfo(
            class_id,
            object_id,
            ObjectKind(kind),
            bool(flags & LookupFlag.SYNC_GET),
            bool(flags & LookupFlag.SYNC_SET),
            bool(flags & LookupFlag.PUBLISHED),
            codec_from_descriptor(descriptor),
            name,
            class_name,
            bool(flags & LookupFlag.READ_ONLY),
        )
    except (ValueError, IndexError) as exc:
        raise ProtocolError(f"malformed lookup reply: {exc}") from None
