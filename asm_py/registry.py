"""The lookup table of a node's own objects: who they are on the wire, and who publishes them.

``register`` gives an attribute, event or service an object ID (1, 2, … in order) and a class ID (a well-known
class from the profiles, asm_py.classes, or a local one from LOCAL_CLASS_BASE up), so a request names it with two
bytes. Each published attribute gets a publisher, made by the node, and a new one whenever its policy changes.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from .attribute import Attribute, PublishPolicy
from .classes import well_known
from .codec import JSON, Codec
from .event import Event
from .protocol import LOCAL_CLASS_BASE, ObjectKind
from .service import Service
from .transport.base import check_name

Registrable = Attribute | Service
Guard = Callable[[int], None]
"""Called with the method of each request that would change an object, before it runs; raises to refuse it."""
MAX_OBJECTS = 0xFF
"""Object IDs are one byte, and 0 means "the object of this class" (group addressing)."""


class Closeable(Protocol):
    def close(self) -> None: ...


PublisherFactory = Callable[["Entry", PublishPolicy], Closeable]


@dataclass
class Entry:
    """One row of the lookup table."""

    obj: Registrable
    name: str
    class_name: str
    class_id: int
    object_id: int
    kind: ObjectKind
    codec: Codec
    """Codec of the value (attributes, events) or of the start parameters (services: JSON)."""
    publisher: Closeable | None = None
    read_only: bool = False
    """Remote SET and RESET are refused (READ_ONLY): only the node itself writes the value."""
    guard: Guard | None = None
    """Called before every remote request that would change the object; may refuse it by raising."""


class Registry:
    """One node's objects by name and by ID; see the module docstring."""

    def __init__(self, node_name: str, make_publisher: PublisherFactory) -> None:
        self.node_name = node_name
        self._make_publisher = make_publisher
        self._lock = threading.Lock()
        self._by_id: dict[int, Entry] = {}
        self._by_name: dict[str, Entry] = {}
        self._local_classes: dict[str, int] = {}
        self._closed = False

    def register(
        self,
        obj: Registrable,
        *,
        name: str | None = None,
        class_name: str | None = None,
        read_only: bool = False,
        guard: Guard | None = None,
    ) -> Entry:
        """Enter ``obj`` in the table (see Node.register)."""
        if isinstance(obj, Event):
            kind, codec = ObjectKind.EVENT, obj.codec or JSON
        elif isinstance(obj, Attribute):
            kind, codec = ObjectKind.ATTRIBUTE, obj.codec or JSON
        elif isinstance(obj, Service):
            kind, codec = ObjectKind.SERVICE, JSON
        else:
            raise TypeError(f"only attributes, events and services can be registered, not {type(obj).__name__}")
        name = check_name(name or obj.name, "object name")
        class_name = check_name(class_name or name, "class name")
        with self._lock:
            if name in self._by_name:
                raise ValueError(f"node {self.node_name!r} already has an object named {name!r}")
            object_id = len(self._by_id) + 1
            if object_id > MAX_OBJECTS:
                raise ValueError(f"node {self.node_name!r} is full: at most {MAX_OBJECTS} objects")
            class_id = self._class_id(class_name)
            entry = Entry(obj, name, class_name, class_id, object_id, kind, codec, read_only=read_only, guard=guard)
            self._by_id[object_id] = entry
            self._by_name[name] = entry
        if isinstance(obj, Attribute):
            obj._add_policy_hook(lambda policy: self._set_policy(entry, policy))
            if obj.publish_policy is not None:
                self._set_policy(entry, obj.publish_policy)
            elif kind == ObjectKind.EVENT:
                self._set_policy(entry, PublishPolicy())  # every firing is published: remote waiters need them
        return entry

    def _class_id(self, class_name: str) -> int:
        known = well_known()
        if class_name in known:
            return known[class_name]
        if class_name not in self._local_classes:
            class_id = LOCAL_CLASS_BASE + len(self._local_classes)
            if class_id > 0xFF:
                raise ValueError(f"node {self.node_name!r} has too many classes")
            self._local_classes[class_name] = class_id
        return self._local_classes[class_name]

    def by_name(self, name: str) -> Entry:
        try:
            return self._by_name[name]
        except KeyError:
            raise LookupError(f"node {self.node_name!r} has no object {name!r}") from None

    def by_id(self, object_id: int) -> Entry:
        try:
            return self._by_id[object_id]
        except KeyError:
            raise LookupError(f"node {self.node_name!r} has no object {object_id!r}") from None

    def by_class(self, class_id: int) -> Entry:
        """The first object of a class (group addressing: "the joint.goal of whichever node receives this")."""
        for entry in self.entries():
            if entry.class_id == class_id:
                return entry
        raise LookupError(f"node {self.node_name!r} has no object of class {class_id:#04x}")

    def entries(self) -> list[Entry]:
        with self._lock:
            return list(self._by_id.values())

    def __len__(self) -> int:
        return len(self._by_id)

    def _set_policy(self, entry: Entry, policy: PublishPolicy | None) -> None:
        old, entry.publisher = entry.publisher, None
        if old is not None:
            old.close()
        if policy is not None and not self._closed:
            entry.publisher = self._make_publisher(entry, policy)

    def close(self) -> None:
        """Stop every publisher; a policy set afterwards publishes nothing."""
        with self._lock:
            self._closed = True
            entries = list(self._by_id.values())
        for entry in entries:
            if entry.publisher is not None:
                entry.publisher.close()
