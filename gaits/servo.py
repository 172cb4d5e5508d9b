"""The servo a module's joint really has, where MuJoCo's position actuator alone would be ideal.

MuJoCo computes each actuator's force as ``kp·(goal − q) − kv·ω`` and clamps it to a *constant* force range; a
real servo's motor gives less torque the faster it turns — the torque-speed line, stall torque at standstill
falling linearly to 0 at the no-load speed — and a hobby servo does not correct an error inside its deadband. Both
are a force range that depends on the joint's state, so :class:`Servo` sets every actuator's range before each
physics step (one step at a time, so the range follows the motion):

* in the direction the joint is turning, at most ``stall · (1 − |ω| / no_load_speed)``: the stall torque at
  standstill, 0 at the no-load speed, and beyond it negative — a joint dragged faster than the motor turns is
  braked by its back-EMF, as a DC motor's is; against the motion (braking) the full stall torque. The force never
  exceeds the stall torque either way (a servo's current limit);
* inside the deadband (``|goal − q| < deadband``), no torque at all: the servo leaves the joint alone.

Each actuator follows its own module's type (a robot of several module types has several servos); a module without a
speed limit or deadband keeps its constant range. A robot whose servos are all ideal (no speed limit, no deadband —
every gait file without those fields) needs none of this, and the simulation then steps exactly as it always has
(gaits.sim does not create a Servo).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from .robot import Robot


class Servo:
    """The torque-speed line and deadband of every actuator of ``model`` (actuator i − 1 drives module i), each by
    its own module's type in ``robot``."""

    def __init__(self, model: mujoco.MjModel, robot: Robot) -> None:
        joints = model.actuator_trnid[:, 0]
        self._qpos = model.jnt_qposadr[joints]
        self._dof = model.jnt_dofadr[joints]
        types = robot.every_module()
        self._stall = np.array([t.stall_torque for t in types])
        speeds = [t.no_load_speed for t in types]
        self._speed = None if all(v is None for v in speeds) else np.radians([math.inf if v is None else v
                                                                              for v in speeds])  # fmt: skip
        """rad/s, MuJoCo's unit (the file's is degrees per second); inf: a module without the line."""
        band = np.radians([t.deadband for t in types])
        self._band = band if (band > 0).any() else None

    def limit(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Set each actuator's force range for the joint's present velocity and error."""
        stall = self._stall
        omega = data.qvel[self._dof]
        high = stall.copy()
        low = -high
        if self._speed is not None:
            along = stall * np.clip(1.0 - np.abs(omega) / self._speed, -1.0, 1.0)
            high = np.where(omega > 0, along, high)
            low = np.where(omega < 0, -along, low)
        if self._band is not None:
            inside = np.abs(data.ctrl - data.qpos[self._qpos]) < self._band
            high = np.where(inside, 0.0, high)
            low = np.where(inside, 0.0, low)
        model.actuator_forcerange[:, 0] = low
        model.actuator_forcerange[:, 1] = high

    def step(self, model: mujoco.MjModel, data: mujoco.MjData, steps: int) -> None:
        """``steps`` physics steps, the force ranges updated before each."""
        for _ in range(steps):
            self.limit(model, data)
            mujoco.mj_step(model, data)
