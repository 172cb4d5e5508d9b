"""A module's joint as its runtime sees it: a driver that commands, reads, relaxes and, on an e-stop, holds.

What a simulated or real module plugs into :class:`~asm_module.runtime.ModuleRuntime`: a MuJoCo actuator
(gaits.sim.MujocoJoint), a real servo's registers, or :class:`FakeDriver`, a servo model for tests and for running
without hardware.
"""

from __future__ import annotations

import math
import threading
from abc import ABC, abstractmethod
from typing import NamedTuple

from asm_py.clock import WALL_CLOCK, Clock


class JointReading(NamedTuple):
    """A joint's state at one instant. A named tuple, not a frozen dataclass: every module makes two at every control
    tick (its driver's and the calibrated one), and a frozen dataclass's ``__init__`` sets each field through
    ``object.__setattr__`` (issue 31)."""

    angle: float
    """Measured joint angle, degrees."""
    torque: float = 0.0
    """Measured joint torque, N·m."""
    contact: bool = False
    """The module touches the ground."""


class JointDriver(ABC):
    """The joint of one module in degrees: what a simulated or real module plugs into the runtime."""

    @abstractmethod
    def command(self, degrees: float) -> None:
        """Drive the joint towards ``degrees`` (already within the module's limits)."""

    @abstractmethod
    def read(self) -> JointReading:
        """The joint's measured state now."""

    def relax(self) -> None:
        """Stop driving the joint (servo off)."""

    def hold(self) -> float:
        """Hold the joint where it is now and ignore every command until :meth:`release`; the angle held.

        The e-stop path calls this on the thread the stop arrived on: it must finish at once, taking no lock that a
        control tick or a simulation step holds (a real driver writes its PWM register). This default commands the
        angle read; a driver whose read or command can wait overrides it."""
        angle = self.read().angle
        self.command(angle)
        return angle

    def release(self) -> None:
        """Follow commands again (the e-stop was released)."""


class FakeDriver(JointDriver):
    """A position servo model: the angle follows the command as a first-order lag with time constant ``tau``
    seconds of ``clock``, computed when read (no thread of its own, so it is deterministic on a SimClock)."""

    def __init__(self, *, tau: float = 0.05, stiffness: float = 0.02, clock: Clock | None = None) -> None:
        self.tau = tau
        self.stiffness = stiffness  # N·m per degree of error, for the torque estimate
        self.clock = clock or WALL_CLOCK
        self._lock = threading.Lock()
        self._goal = 0.0
        self._angle = 0.0
        self._powered = True
        self._held = False
        self._time = self.clock.now()

    def _advance(self) -> None:
        now = self.clock.now()
        if self._powered:
            self._angle = self._goal + (self._angle - self._goal) * math.exp(-(now - self._time) / self.tau)
        self._time = now

    def command(self, degrees: float) -> None:
        with self._lock:
            self._advance()
            if self._held:
                return
            self._goal = degrees
            self._powered = True

    def hold(self) -> float:
        with self._lock:  # its own, held for microseconds by its own methods alone
            self._advance()
            self._goal = self._angle
            self._held = True
            return self._angle

    def release(self) -> None:
        with self._lock:
            self._held = False

    @property
    def held(self) -> bool:
        """An e-stop holds the joint: commands are ignored."""
        return self._held

    def read(self) -> JointReading:
        with self._lock:
            self._advance()
            torque = self.stiffness * (self._goal - self._angle) if self._powered else 0.0
            return JointReading(self._angle, max(-1.5, min(1.5, torque)), False)

    def relax(self) -> None:
        with self._lock:
            self._advance()
            self._powered = False
