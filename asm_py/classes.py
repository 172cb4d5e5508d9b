"""Well-known classes: the class IDs every node gives the same kind of object, so a group request can address "the
object of this class" on each member.

ASM itself knows only its own (node, heartbeat, estop: asm_py/_contract.py). An application adds a *profile* — as a
CANopen device profile sits on CANopen — by declaring an entry point in the group ``asm.profiles`` whose value is a
mapping of class name to ID (asm_module's module profile is one: ``asm.profiles`` → ``module =
asm_module._profile:CLASSES``). Every installed profile is loaded the first time a class is asked for, so every
process with the same packages installed agrees on every ID, whatever it imported first.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Mapping
from importlib.metadata import entry_points
from types import MappingProxyType

from ._contract import CORE_CLASSES, LOCAL_CLASS_BASE

log = logging.getLogger("asm_py.classes")
PROFILES_GROUP = "asm.profiles"
_lock = threading.Lock()
_known: Mapping[str, int] | None = None

__all__ = ["LOCAL_CLASS_BASE", "PROFILES_GROUP", "merge_profiles", "well_known"]


def merge_profiles(*profiles: tuple[str, Mapping[str, int]]) -> dict[str, int]:
    """The core classes and those of ``profiles`` (name, mapping); ValueError when two give one name or one ID two
    meanings, or a profile takes an ID outside 0x04..0x7F."""
    merged = dict(CORE_CLASSES)
    owner = {name: "asm" for name in merged}
    by_id = {class_id: name for name, class_id in merged.items()}
    for profile, classes in profiles:
        for name, class_id in classes.items():
            if not 0 < class_id < LOCAL_CLASS_BASE:
                raise ValueError(f"profile {profile!r}: class {name!r} has ID {class_id:#04x}, outside 0x01..0x7F")
            if merged.get(name, class_id) != class_id or by_id.get(class_id, name) != name:
                raise ValueError(f"profile {profile!r}: class {name!r} = {class_id:#04x} clashes with "
                                 f"{owner.get(name) or owner[by_id[class_id]]!r}")  # fmt: skip
            merged[name], by_id[class_id], owner[name] = class_id, name, profile
    return merged


def well_known() -> Mapping[str, int]:
    """Every well-known class, by name: the core's and every installed profile's (read-only, loaded once)."""
    global _known
    if _known is None:
        with _lock:
            if _known is None:
                profiles = [(point.name, point.load()) for point in entry_points(group=PROFILES_GROUP)]
                _known = MappingProxyType(merge_profiles(*profiles))
    return _known
