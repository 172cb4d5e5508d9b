"""What a tool must read before it resets or moves a robot's modules: which have their e-stop latched and which run a
gait — asked of the modules themselves, as a robot on a real bus keeps no other record of either.

A firmware update, a node ID given or erased (each a board reset, which releases a latch) and a wiggle (a joint
moved) are refused while any module of the bus is latched or walks: asm_module.flasher, the robot's commissioning
service (server/commission_service.py) and ``asm-commission`` all read them here, so all three refuse alike.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass, field

from asm_py.node import Node
from asm_py.remote import RemoteAttribute, RemoteService

log = logging.getLogger("asm_module.halts")

SHOWN = 8
"""Modules a refusal names before "and N more"."""


@dataclass
class Halts:
    """The modules (node names) whose e-stop is latched and those whose gait runs, as read."""

    latched: list[str] = field(default_factory=list)
    walking: list[str] = field(default_factory=list)

    def refusal(self, why: str) -> str | None:
        """Why an operation that ``why`` (what it would do: "an ID given resets the board") is refused, or None:
        a latch first (it forbids the operation outright), then a gait (stop it first)."""
        if self.latched:
            return (f"refused: the robot's e-stop is latched ({_listed(self.latched)}); {why}, which the e-stop "
                    "forbids: release it first")  # fmt: skip
        if self.walking:
            return f"refused: a gait runs on {_listed(self.walking)}; {why}, mid-step: stop the gait first"
        return None


def read_halts(node: Node, modules: Iterable[str], timeout: float) -> Halts:
    """Read each module's ``estop`` and ``gait.service``; one without them (not a module) or silent is not counted:
    what the operation then does to it is its own report."""
    halts = Halts()
    for name in modules:
        try:
            estop = node.lookup(name, "estop", timeout=timeout)
            if isinstance(estop, RemoteAttribute) and estop.peek(timeout=timeout):
                halts.latched.append(name)
            service = node.lookup(name, "gait.service", timeout=timeout)
            if isinstance(service, RemoteService) and service.running:
                halts.walking.append(name)
        except Exception:  # not a module with an e-stop or a gait, silent, or gone meanwhile: nothing to keep
            log.debug("%s: no e-stop or gait read", name, exc_info=True)
    return halts


def _listed(names: list[str]) -> str:
    return ", ".join(names[:SHOWN]) + (f" and {len(names) - SHOWN} more" if len(names) > SHOWN else "")
