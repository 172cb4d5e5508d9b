"""The board image in the loop (issue 28): what the STM32F4 port's ELF costs, run instruction by instruction in
the emulator (asm_module/emulated.py) as modules of the simulated robot.

    .venv/bin/python bench/emulated.py

- ``emulated_tick_cycles_vs_budget``: the most instructions one control tick (asm_module_tick) took on any
  emulated module while the caterpillar walked with modules 1, 3, 5, 7 as emulated boards, over the budget of 10%
  of a 20 ms period at 168 MHz (336,000 cycles). Instructions stand in for cycles (one each: a lower bound — loads,
  taken branches and divisions take more, flash wait states are hidden by the ART accelerator mostly). Target <= 1.
- ``emulated_module_distance_vs_python``: the distance that robot walks from 2 s to 12 s of simulated time over
  the all-Python robot's (the mean of its body positions), both stepped as fast as they run — simulated time, not
  wall time, so this machine's load does not enter. Target 0.95-1.05.

Also printed: what the boards report themselves over the bus (``module.info``: the worst control tick timed with
their DWT cycle counter, the stack's high-water mark from their own paint) against the emulator's figures —
``board_reported_tick_vs_emulator``, target 0.95-1.05 (the board times the call from inside, the emulator from the
call's first instruction to its return) — the worst instructions executed in one control period (tick, frames,
interrupts), the stack's high-water mark, how many seconds of emulated board one second of this machine runs,
and — for context, as it depends on this machine's load — the live distance of a real-time
``asm-robot --sim --emulated-modules 1,3`` in 10 s of wall time over the all-Python robot's (bench/robot.py's live
distance).
"""

from __future__ import annotations

import shutil
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np

from asm_py.node import Node
from asm_py.remote import RemoteAttribute
from asm_py.transport.can import CanTransport
from gaits.model import LIBRARY, load
from gaits.sim import Simulation

BUDGET = 336_000
SECONDS = 12.0


def read_info(sim: Simulation, tool: Node, ids: list[int]) -> list[dict]:
    """Each board's module.info over the bus. The boards run only as the simulation steps: it steps (after the
    measurement) while a thread asks."""
    got: list[dict] = []

    def ask() -> None:
        for i in ids:
            info = tool.lookup(f"m{i}", "module.info", timeout=5)
            assert isinstance(info, RemoteAttribute)
            got.append(info.get(timeout=5))

    asking = threading.Thread(target=ask, name="bench-read-info")
    asking.start()
    while asking.is_alive():
        sim.advance(0.1)
    asking.join()
    if len(got) != len(ids):
        raise RuntimeError(f"module.info read from {len(got)} of {len(ids)} boards")
    return got


def walk(emulated: bool) -> tuple[float, dict[str, float]]:
    """Metres walked from 2 s to 12 s of simulated time; with ``emulated``, the boards' figures."""
    gait = load(LIBRARY / "caterpillar.toml")
    channel = f"bench-emulated-{time.monotonic_ns()}"
    nodes: list[Node] = []

    def node_of(module_id: int) -> Node:
        transport = CanTransport(module_id, interface="virtual", channel=channel, heartbeat_period=0.5,
                                 watch_bus=False)  # fmt: skip
        nodes.append(Node(f"m{module_id}", transport))
        return nodes[-1]

    odd = [a.id for a in gait.modules if a.id % 2] if emulated else []
    bus = {"interface": "virtual", "channel": channel}
    figures: dict[str, float] = {}
    # a tool that hears the heartbeats (the modules' own nodes do not watch the bus): it reads module.info
    tool = Node("bench-tool", CanTransport(250, interface="virtual", channel=channel, heartbeat_period=0.5))
    nodes.append(tool)
    try:
        with Simulation(gait, node_of=node_of, emulated_modules=odd, bus_options=bus) as sim:
            sim.start()
            sim.advance(2.0)
            start = sim.data.xpos[1:].mean(axis=0).copy()
            began = time.perf_counter()
            sim.advance(SECONDS - 2.0)
            host = time.perf_counter() - began
            end = sim.data.xpos[1:].mean(axis=0)
            boards = [sim.modules[i] for i in odd]
            reported = read_info(sim, tool, odd)
            if boards:
                figures = {
                    "worst_tick": max(b.tick_cycles().worst for b in boards),  # type: ignore[attr-defined]
                    "mean_tick": sum(b.tick_cycles().total for b in boards)  # type: ignore[attr-defined]
                    / sum(b.tick_cycles().ticks for b in boards),  # type: ignore[attr-defined]
                    "worst_period": max(b.worst_period_cycles() for b in boards),  # type: ignore[attr-defined]
                    "stack": max(b.stack_used() for b in boards),  # type: ignore[attr-defined]
                    "speed": (SECONDS - 2.0) * len(boards) / host,
                    "faults": sum(b.fault is not None for b in boards),  # type: ignore[attr-defined]
                    "reported_tick": max(r["tick_cycles"] for r in reported),
                    "reported_stack": max(r["stack_bytes"] for r in reported),
                }
    finally:
        for node in nodes:
            node.close()
    return float(np.hypot(*(end - start)[:2])), figures


def main() -> None:
    if shutil.which("arm-none-eabi-gcc") is None:
        print("# the board image needs arm-none-eabi-gcc (make test installs it)")
        return
    python, _ = walk(False)
    mixed, figures = walk(True)
    print(f"# caterpillar, {SECONDS - 2.0:.0f} s of simulated time: {python:.3f} m all Python, {mixed:.3f} m with "
          f"modules 1, 3, 5, 7 as emulated boards ({figures['faults']:.0f} faulted)")  # fmt: skip
    print(f"# control tick: worst {figures['worst_tick']:.0f} instructions, mean {figures['mean_tick']:.0f}; worst "
          f"control period (tick, frames, interrupts) {figures['worst_period']:.0f}; stack high-water "
          f"{figures['stack']:.0f} bytes")  # fmt: skip
    print(f"# emulation: {figures['speed']:.2f} board-seconds per second of this machine (all four boards)")
    print(f"# reported by the boards (module.info over the bus): worst tick {figures['reported_tick']:.0f} cycles "
          f"(DWT_CYCCNT), stack high-water {figures['reported_stack']:.0f} bytes")  # fmt: skip
    print(f"ratio emulated_tick_cycles_vs_budget {figures['worst_tick'] / BUDGET:.4f} (target <= 1)")
    agreement = figures["reported_tick"] / figures["worst_tick"] if figures["worst_tick"] else 0.0
    print(f"ratio board_reported_tick_vs_emulator {agreement:.3f} (target >= 0.95)")
    print(f"ratio board_reported_tick_vs_emulator {agreement:.3f} (target <= 1.05)")
    from bench.robot import live_distance

    path = LIBRARY / "caterpillar.toml"
    live_python, live_mixed = live_distance(path), live_distance(path, "--emulated-modules", "1,3")
    print(f"# live, 10 s of wall time: {live_python:.3f} m all Python, {live_mixed:.3f} m with modules 1 and 3 "
          f"emulated: {live_mixed / live_python if live_python > 0 else 0.0:.2f}")  # fmt: skip
    ratio = mixed / python if python > 0 else 0.0
    print(f"ratio emulated_module_distance_vs_python {ratio:.3f} (target >= 0.95)")
    print(f"ratio emulated_module_distance_vs_python {ratio:.3f} (target <= 1.05)")


if __name__ == "__main__":
    main()
