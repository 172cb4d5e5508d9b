"""A calibration shifts the simulated joint as stated (issue 28 part 3): in MuJoCo, a module calibrated with a zero
offset of 15° that is told to go to 0° drives its hinge to 15° and reads its hinge less 15° — a Python module and
the C runtime alike — while an uncalibrated neighbour told 0° is sent 0°."""

from __future__ import annotations

import math
import shutil
import struct

import mujoco
import pytest

from asm_module.c_module import CModule
from asm_module.runtime import ModuleRuntime
from asm_py.protocol import Method
from gaits.model import LIBRARY, load
from gaits.sim import Simulation

pytestmark = pytest.mark.timeout(300)
ZERO = 15.0


@pytest.mark.skipif(shutil.which("gcc") is None, reason="the C module needs gcc")
def test_a_zero_offset_moves_the_simulated_joint_by_the_offset() -> None:
    gait = load(LIBRARY / "caterpillar.toml")
    lo, hi = gait.limits
    calibration = {"zero": ZERO, "direction": 1, "min": lo - ZERO, "max": hi - ZERO}
    with Simulation(gait, c_modules=[5]) as sim:
        sim.advance(1.0)
        python, c = sim.modules[3], sim.modules[5]
        assert isinstance(python, ModuleRuntime) and isinstance(c, CModule)
        raw = {k: sim.modules[k].driver.read().angle for k in (3, 4, 5)}  # type: ignore[union-attr]
        assert all(abs(angle) < 2.0 for angle in raw.values()), raw
        python.calibration.set(calibration)
        c.local(Method.SET, "joint.calibration", struct.pack("<fbff", ZERO, 1, lo - ZERO, hi - ZERO))
        sim.advance(0.5)
        for module in (python, c):
            assert abs(module.goal_now() + ZERO) < 2.0, "the new zero keeps the joint where it was: goal -15"
        python.goal.set(0.0)
        c.local(Method.SET, "joint.goal", struct.pack("<f", 0.0))
        sim.advance(2.0)
        for k in (3, 5):
            actuator = mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"m{k}")
            assert math.degrees(sim.data.ctrl[actuator]) == pytest.approx(ZERO, abs=1e-3), "sent: zero + goal"
            hinge = sim.modules[k].driver.read().angle  # type: ignore[union-attr]
            # the servo carries part of the chain's weight (gaits/servo.py): it reaches most of the way
            assert hinge - raw[k] > ZERO * 0.6, f"m{k}'s hinge moved towards the offset: {raw[k]:.2f} -> {hinge:.2f}"
            assert sim.angle(k) == pytest.approx(hinge - ZERO, abs=0.3), f"m{k} reads its hinge less the zero"
        uncalibrated = mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_ACTUATOR, "m4")
        assert sim.data.ctrl[uncalibrated] == 0.0, "m4, not calibrated, is sent its goal as it is"
