"""The Module calls of a module whose firmware answers its own local requests: the C runtime built for the host
(c_module.CModule) and the board image in the emulator (emulated.EmulatedModule).

Each call is the request a deployment would send over the bus, made in-process to the firmware, so both run the
firmware's own checks; the two differ only in how a local request reaches the firmware and how its joint is read.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Literal

from asm_py.codec import FLOAT32, INT8, UINT8
from asm_py.protocol import Method

from .gait_service import SWITCH


class FirmwareCalls(ABC):
    """``asm_module.module.Module``'s calls in terms of ``local`` requests to the firmware."""

    language: Literal["python", "c"] = "c"
    node_id: int

    @abstractmethod
    def local(self, method: int, name: str, data: bytes = b"") -> None:
        """Make request ``method`` to this module's object ``name`` in-process (ValueError/TypeError as refused)."""

    @abstractmethod
    def gait_running(self) -> bool:
        """gait.service runs."""

    @property
    @abstractmethod
    def goal(self) -> float:
        """What the firmware commands the joint to (degrees)."""

    @property
    @abstractmethod
    def angle(self) -> float:
        """joint.angle as the firmware last read it (degrees)."""

    @property
    def module_id(self) -> int:
        return self.node_id

    def load_gait(self, table: bytes, phase: float, direction: int) -> None:
        self.local(Method.SET, "gait.table", table)
        self.local(Method.SET, "gait.phase", FLOAT32.encode(phase))
        self.local(Method.SET, "gait.direction", INT8.encode(direction))

    def start_gait(self) -> None:
        if not self.gait_running():
            self.local(Method.START, "gait.service")

    def switch_mode(self, mode: int, direction: int, after: float) -> None:
        self.local(Method.SET, "gait.switch", SWITCH.encode({"mode": mode, "direction": direction, "after": after}))

    def hear_signal(self, number: int) -> None:
        self.local(Method.SET, "gait.signal", UINT8.encode(number))

    def stop_gait(self) -> None:
        self.local(Method.STOP, "gait.service")

    def goal_now(self) -> float:
        return self.goal

    def angle_now(self) -> float:
        return self.angle
