"""The one interface of a module, whichever language runs it.

A simulation, a robot process and the tests hold Python modules (asm_module.runtime.ModuleRuntime) and C modules
(asm_module.c_module.CModule, the firmware's own runtime) side by side and drive both through these calls — the
ones a deployment makes over the bus, made in-process without a round trip and with the same checks — so none of
them branches on the language.
"""

from __future__ import annotations

from typing import Literal, Protocol, runtime_checkable


@runtime_checkable
class Module(Protocol):
    """One module, in-process."""

    language: Literal["python", "c"]

    @property
    def module_id(self) -> int:
        """Its CAN node ID: the ``m<id>`` it answers as."""
        ...

    @property
    def latched(self) -> bool:
        """Its emergency stop is latched."""
        ...

    def load_gait(self, table: bytes, phase: float, direction: int) -> None:
        """Set ``gait.table``, ``gait.phase`` and ``gait.direction`` as a deployment would (refused while latched,
        a table that does not fit the module refused whole)."""
        ...

    def start_gait(self) -> None:
        """Start ``gait.service`` unless it runs."""
        ...

    def switch_mode(self, mode: int, direction: int, after: float) -> None:
        """Set ``gait.switch``: program mode ``mode`` in ``direction`` from the first cycle boundary after ``after``."""
        ...

    def hear_signal(self, number: int) -> None:
        """Receive signal ``number`` as a group SET of ``gait.signal`` delivers it."""
        ...

    def stop_gait(self) -> None:
        """Stop ``gait.service``: the joint holds its last goal."""
        ...

    def gait_running(self) -> bool:
        """``gait.service`` runs (a one-shot program that ended, or a stopped gait, does not)."""
        ...

    def goal_now(self) -> float:
        """What it commands its joint to now (degrees)."""
        ...

    def angle_now(self) -> float:
        """Its joint angle as it last read it (degrees)."""
        ...

    def close(self) -> None:
        """Stop everything it started (not the node or bus it was given)."""
        ...
