"""A robot at rest costs nothing: when no gait runs and nothing moves, the simulated robot stops stepping physics.

A 128-module robot lying still spent a third of a core stepping MuJoCo and ticking every module 50 times a second
to compute what it already knew (issue 31: under 0.1 of a core at rest). At rest the robot process steps no
physics: its time passes along the tick grid, and every ``REST_TICK`` seconds of wall time the modules tick (they
read the joints as they stand) and a pose frame goes out, so the clock, the publications and the real-time factor
carry on as before. It wakes within ``CHECK`` seconds of anything that can move the robot: a gait
started, a joint commanded, powered or relaxed, an e-stop's hold, a push.

A robot of Python and C modules rests: each ticks only when the simulation's tick fires, on the simulation's clock.
A C module's own timed work — heartbeats, publication refreshes, the deadlines of waits — runs at its ticks, so at
rest it comes up to REST_TICK late (a Python module's runs on the wall clock's timers). An emulated board keeps its
own time: a robot with one does not rest.
"""

from __future__ import annotations

import numpy as np

from asm_module import ModuleRuntime
from asm_module.c_module import CModule
from gaits.sim import Simulation

REST_SPEED = 1e-3
"""Largest joint or body speed (rad/s, m/s) of a robot that counts as standing still."""
REST_TICK = 0.5
"""Wall seconds between the control periods a resting robot still steps."""
CHECK = 0.05
"""Wall seconds between looks for what wakes a resting robot (the longest a command waits for the physics)."""


class Rest:
    """Whether ``sim`` may rest, and whether what it rests on has changed; see the module docstring."""

    def __init__(self, sim: Simulation) -> None:
        self.sim = sim
        self._modules = list(sim.modules.values())
        self._can_rest = all(isinstance(m, ModuleRuntime | CModule) for m in self._modules)
        self._inputs: np.ndarray | None = None
        self.rests = 0
        """Times the robot came to rest (tests, benches)."""

    def still(self) -> bool:
        """No gait runs, no push, every joint and body still."""
        sim = self.sim
        if not self._can_rest or sim.pushing:
            return False
        if any(module.gait_running() for module in self._modules):
            return False
        return float(np.abs(sim.data.qvel).max(initial=0.0)) < REST_SPEED

    def begin(self) -> None:
        self._inputs = self._read_inputs()
        self.rests += 1

    def disturbed(self) -> bool:
        """Something that can move the robot changed since ``begin``."""
        if self.sim.pushing or any(module.gait_running() for module in self._modules):
            return True
        return self._inputs is None or not np.array_equal(self._inputs, self._read_inputs())

    def _read_inputs(self) -> np.ndarray:
        """What moves the robot: the servos' set points and gains (on, relaxed), forces applied to bodies."""
        sim = self.sim
        return np.concatenate((sim.data.ctrl, sim.model.actuator_gainprm[:, 0], sim.data.xfrc_applied.ravel()))
