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

An ideal servo (no speed limit, no deadband — every gait file without those fields) needs none of this, and the
simulation then steps exactly as it always has (gaits.sim does not create a Servo).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from .mjcf import Physics


class Servo:
    """The torque-speed line and deadband of every actuator of ``model`` (all are module joints)."""

    def __init__(self, model: mujoco.MjModel, physics: Physics) -> None:
        joints = model.actuator_trnid[:, 0]
        self._qpos = model.jnt_qposadr[joints]
        self._dof = model.jnt_dofadr[joints]
        self._stall = physics.torque
        speed = physics.no_load_speed
        self._speed = None if speed is None else math.radians(speed)
        """rad/s, MuJoCo's unit (the file's is degrees per second)."""
        self._band = math.radians(physics.deadband)

    def limit(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """Set each actuator's force range for the joint's present velocity and error."""
        stall = self._stall
        omega = data.qvel[self._dof]
        high = np.full(omega.shape, stall)
        low = -high
        if self._speed is not None:
            along = stall * np.clip(1.0 - np.abs(omega) / self._speed, -1.0, 1.0)
            high = np.where(omega > 0, along, high)
            low = np.where(omega < 0, -along, low)
        if self._band > 0:
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
