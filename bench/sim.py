"""Simulation speed with the modules' automata in the loop, against raw MuJoCo stepping of the same model in the same
run, and the speed of every library gait.

    .venv/bin/python bench/sim.py

Each chain (8, 32, 128 pitch modules, a caterpillar wave) runs twice after the same 1 s warm-up: once as
gaits.sim.Simulation (one ModuleRuntime per module, ticked on the SimClock at 50 Hz), once as a bare loop that sets
``ctrl`` from numpy at the same rate and calls mj_step — the cheapest way to move the same model the same way.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from gaits.mjcf import build_mjcf
from gaits.model import LIBRARY, Robot, load
from gaits.serpenoid import sine, wave_gait
from gaits.sim import Simulation

TARGETS = {"caterpillar": 3, "sidewinding": 3, "rolling_loop": 3, "inchworm": 2, "legged_walk": 2,
           "lateral_undulation": 3}  # fmt: skip


def chain(n: int):
    return wave_gait("chain", "", Robot("chain", n, "pitch"), {"wave": (sine(30.0), 0.0)}, role_of=lambda i: "wave",
                     offset_of=lambda i: -i / 8)  # fmt: skip


def with_runtime(n: int, seconds: float) -> tuple[float, float]:
    """Steps per second and real-time factor with every module's runtime in the loop."""
    with Simulation(chain(n)) as sim:
        sim.start()
        sim.advance(1.0)
        steps0, t0 = sim.data.time, time.perf_counter()
        sim.advance(seconds)
        wall = time.perf_counter() - t0
        steps = (sim.data.time - steps0) / sim.model.opt.timestep
        print(f"#   runtimes: {sim.data.ncon} contacts at the end, com {np.round(sim.data.subtree_com[0], 3)}")
    return steps / wall, seconds / wall


def raw(n: int, seconds: float) -> float:
    """Steps per second of bare mj_step on the same model, moved the same way from numpy."""
    model = mujoco.MjModel.from_xml_string(build_mjcf(chain(n).robot))
    data = mujoco.MjData(model)
    phases = (np.arange(n) * -1 / 8) % 1.0
    every = max(1, round(1 / (50 * model.opt.timestep)))

    def run(ticks: int) -> None:
        for _ in range(ticks):
            ramp = min(1.0, data.time)
            data.ctrl[:] = np.radians(30.0 * ramp * np.sin(2 * math.pi * (phases + data.time)))
            mujoco.mj_step(model, data, every)

    run(round(1.0 / (every * model.opt.timestep)))
    ticks = round(seconds / (every * model.opt.timestep))
    t0 = time.perf_counter()
    run(ticks)
    print(f"#   raw: {data.ncon} contacts at the end, com {np.round(data.subtree_com[0], 3)}")
    return ticks * every / (time.perf_counter() - t0)


def main() -> None:
    for n, seconds in ((8, 4.0), (32, 3.0), (128, 2.0)):
        rate, rtf = with_runtime(n, seconds)
        base = raw(n, seconds)
        print(f"# chain of {n}: {rate:,.0f} steps/s with runtimes, {base:,.0f} raw")
        print(f"ratio sim_steps_{n}_vs_raw_mujoco {rate / base:.2f} (target >= 0.5)")
        print(f"ratio sim_real_time_factor_{n} {rtf:.1f} (target >= {2 if n == 128 else 1})")
    for name, target in TARGETS.items():
        with Simulation(load(LIBRARY / f"{name}.toml")) as sim:
            m = sim.run(10.0, warmup=2.0)
        print(f"# {name}: {m.summary()}")
        print(f"ratio gait_{name}_body_lengths_per_10s {m.body_lengths:.2f} (target >= {target})")


if __name__ == "__main__":
    main()
