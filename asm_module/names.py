"""The names a robot's modules go by on a bus and on Zenoh: module ``n`` is node ``m<n>`` (its CAN node ID is ``n``).

One place builds and parses them, so a tool, the simulation, the robot process and ``asm-module`` agree.
"""

from __future__ import annotations

MODULE_IDS = range(1, 200)
"""Node IDs modules may take: 200-253 are the bridge's aliases for Zenoh clients, 254 the bridge."""


def module_name(module_id: int) -> str:
    """The node name of module ``module_id``: m1, m2, …"""
    return f"m{module_id}"


def module_id(name: str) -> int | None:
    """The module ID a node name stands for (``m3`` → 3), or None for a name that is not a module's."""
    if name.startswith("m") and name[1:].isdigit() and not name[1:].startswith("0"):
        return int(name[1:])
    return None


def is_module(name: str) -> bool:
    return module_id(name) is not None
