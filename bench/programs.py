"""Phase automata beyond the periodic time-driven one (issue 16), in MuJoCo on the modules' own runtime: a program
that turns, a switch that does not stop the robot, modules that switch together over a CAN bus, a wave coordinated
by neighbour events instead of phase offsets, and an inchworm advanced by its feet.

    .venv/bin/python bench/programs.py
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from asm_module.names import module_name
from asm_py import Node
from asm_py.transport.can import CanTransport
from gaits.drive import drive
from gaits.model import LIBRARY, load
from gaits.sim import Simulation

TICK = 1 / 50


def _heading(positions: np.ndarray, times: np.ndarray, start: float, end: float) -> float:
    i, j = np.searchsorted(times, start), np.searchsorted(times, end)
    d = positions[j] - positions[i]
    return math.degrees(math.atan2(d[1], d[0]))


def tour() -> None:
    """caterpillar_tour: forward 5 cycles, left 5, forward (1 s cycles), run on its own sequence."""
    gait = load(LIBRARY / "caterpillar_tour.toml")
    with Simulation(gait) as sim:
        sim.start()
        times, positions = [], []
        while sim.data.time < 16.0:
            sim.step_tick()
            times.append(sim.data.time)
            positions.append(sim.center_of_mass()[:2].copy())
        switches = sorted({round(r.gait.switched_at or 0.0, 3) for r in sim.modules.values()})
    t, p = np.array(times), np.array(positions)
    before = _heading(p, t, 1.0, 5.0)  # after the start ramp, before the first switch
    after = _heading(p, t, 11.0, 15.5)  # after the second switch and its blend
    change = abs((after - before + 180) % 360 - 180)
    print(f"# tour: heading {before:.1f}° then {after:.1f}° (last switch at {switches} s)")
    print(f"ratio program_heading_change_vs_60deg {change / 60:.2f} (target >= 1)")
    window = round(1.0 / TICK)  # one period
    speed = np.linalg.norm(p[window:] - p[:-window], axis=1)  # metres per 1 s window, ending at t[window:]
    ends = t[window:]
    mean = float(np.linalg.norm(np.diff(p[np.searchsorted(t, 2.0) :], axis=0), axis=1).sum() / (t[-1] - 2.0))
    lowest = min(float(speed[(ends >= s - 1.0) & (ends <= s + 2.0)].min()) for s in (5.0, 10.0))
    print(f"# tour: mean path speed {mean:.3f} m/s, slowest 1 s window around a switch {lowest:.3f} m/s")
    print(f"ratio program_min_speed_at_switch_vs_mean {lowest / mean:.2f} (target >= 0.3)")


def skew() -> None:
    """The steerable caterpillar on modules that are ASM nodes on a CAN bus, paced to real time like the robot
    process; a tool on the same bus drives it left (one group message, read back), as the Drive panel does."""
    gait = load(LIBRARY / "steerable_caterpillar.toml")
    channel = f"asm-bench-programs-{time.monotonic_ns()}"
    nodes: list[Node] = []

    def node_of(module_id: int) -> Node:
        nodes.append(Node(module_name(module_id), CanTransport(module_id, interface="virtual", channel=channel,
                                                               heartbeat_period=0.05)))  # fmt: skip
        return nodes[-1]

    tool = Node("tool", CanTransport(200, interface="virtual", channel=channel, heartbeat_period=0.05))
    try:
        with Simulation(gait, node_of=node_of) as sim:
            sim.start()
            stop = threading.Event()

            def pace() -> None:
                while not stop.is_set():
                    began = time.monotonic()
                    sim.step_tick()
                    time.sleep(max(0.0, TICK - (time.monotonic() - began)))

            runner = threading.Thread(target=pace, name="bench-pace")
            runner.start()
            try:
                time.sleep(1.5)
                names = [module_name(a.id) for a in gait.modules]
                drive(tool, gait, "left", names, timeout=10.0)
            finally:
                stop.set()
                runner.join()
            times = [r.gait.switched_at for r in sim.modules.values()]
    finally:
        tool.close()
        for node in nodes:
            node.close()
    spread = max(times) - min(times)  # type: ignore[type-var,operator]
    print(f"# skew: {len(times)} modules switched at {sorted(set(round(x, 3) for x in times))} s (their clock)")  # type: ignore[arg-type]
    print(f"ratio switch_skew_vs_tick {spread / TICK:.2f} (target <= 1)")


def neighbour_wave() -> None:
    def distance(name: str) -> float:
        with Simulation(load(LIBRARY / f"{name}.toml")) as sim:
            return sim.run(10.0).distance

    coordinated, phased = distance("neighbour_caterpillar"), distance("caterpillar")
    print(f"# neighbour caterpillar {coordinated:.3f} m, phase-offset caterpillar {phased:.3f} m in 10 s")
    print(f"ratio neighbour_wave_vs_phase_wave {coordinated / phased:.2f} (target >= 0.8)")


def contact_inchworm() -> None:
    gait = load(LIBRARY / "contact_inchworm.toml")
    with Simulation(gait) as sim:
        sim.start()
        sim.advance(2.0)
        start = sim.center_of_mass()
        changed: dict[int, int] = {}  # module → the tick its contact last changed
        last: dict[int, tuple[bool, int]] = {}
        lags: list[int] = []
        for tick in range(round(10.0 / TICK)):
            sim.step_tick()
            for module_id, runtime in sim.modules.items():
                contact, state = bool(runtime.contact.peek()), int(runtime.gait.state.peek())
                before = last.get(module_id)
                if before is not None and before[0] != contact:
                    changed[module_id] = tick
                if before is not None and state != before[1]:
                    automaton = gait.automata[gait.assignment(module_id).automaton]
                    if automaton.states[before[1]].until == "contact":
                        lags.append(tick - changed.get(module_id, -(10**6)))
                last[module_id] = (contact, state)
        metrics = sim.measure(start, 10.0)
        ended: Counter[tuple[str, bool]] = Counter()
        for runtime in sim.modules.values():
            ended.update(runtime.gait.ended)
    within = sum(0 <= lag <= 1 for lag in lags) / max(1, len(lags))
    print(f"# contact inchworm: {metrics.summary()}")
    print(f"# contact states left: {len(lags)}, ticks after the contact changed: {sorted(Counter(lags).items())}; "
          f"ended by event or timeout: {dict(ended)}")  # fmt: skip
    print(f"ratio contact_inchworm_bl_per_10s_vs_2 {metrics.body_lengths / 2:.2f} (target >= 1)")
    print(f"ratio contact_transitions_within_one_tick {within:.2f} (target >= 1)")


if __name__ == "__main__":
    tour()
    skew()
    neighbour_wave()
    contact_inchworm()
