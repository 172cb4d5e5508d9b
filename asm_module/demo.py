"""A runnable tour of the core: a chain of modules crawling with one phase automaton each.

Every module has a joint-goal attribute and a periodic automaton started with its own phase delay φ = n/N; one
timer trigger fires one tick event that all automata share, exactly as a gait runs on PolyBot-like modules. Half way
through, the direction attribute of every automaton is flipped and the wave runs backward.

    python -m asm_module.demo --modules 6 --seconds 10
"""

from __future__ import annotations

import argparse
import sys
import time

from asm_py import Attribute, Event, PeriodicAutomaton, PhaseState, TimerTrigger
from asm_py.cli import bounded, rate, summary

# One period of a caterpillar joint, as eight states with linear interpolation: a sine sampled at 45° steps.
CATERPILLAR = [PhaseState(round(60.0 * s, 1), 0.125, "linear") for s in (0.71, 1, 0.71, 0, -0.71, -1, -0.71, 0)]


def bar(angle: float, width: int = 9) -> str:
    """The angle (-90…90°) as a marker on a small scale."""
    cells = [" "] * width
    cells[round((angle + 90) / 180 * (width - 1))] = "●"
    return "".join(cells)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="asm-demo", description=summary(__doc__))
    parser.add_argument("--modules", type=bounded(int, 1, 254, what="a module count"), default=6,
                        help="modules in the chain (default 6)")  # fmt: skip
    parser.add_argument("--seconds", type=bounded(float, 0, 86_400, what="a run time"), default=0.0,
                        help="run time; 0 runs until Ctrl-C")  # fmt: skip
    parser.add_argument("--rate", type=rate, default=50.0, help="control ticks per second (default 50)")
    args = parser.parse_args(argv)

    tick = Event("tick", codec="float64")
    timer = TimerTrigger(1.0 / args.rate, name="control-timer")
    tick.add_trigger(timer)
    goals = [Attribute(f"m{n}.joint.goal", 0.0, codec="float32") for n in range(args.modules)]
    gaits = [PeriodicAutomaton(f"m{n}.gait", tick, CATERPILLAR, output=goals[n]) for n in range(args.modules)]

    print(f"ASM demo: {args.modules} modules, phase delays φ = n/{args.modules}, {args.rate:g} Hz ticks")
    print("every module runs the same automaton; only the phase differs. Ctrl-C stops.", flush=True)
    for n, gait in enumerate(gaits):
        gait.start(n / args.modules)
    timer.start()
    started = time.monotonic()
    flipped = False
    try:
        while args.seconds <= 0 or time.monotonic() - started < args.seconds:
            elapsed = time.monotonic() - started
            if args.seconds > 0 and not flipped and elapsed >= args.seconds / 2:
                for gait in gaits:
                    gait.direction.set(-1)
                flipped = True
                print("-- direction set to -1 on every module: the wave runs backward --")
            row = " ".join(f"{g.peek():+6.1f}{bar(g.peek())}" for g in goals)
            print(f"t={elapsed:5.2f}s {row}", flush=True)
            time.sleep(0.1)
    except KeyboardInterrupt:
        pass
    finally:
        timer.stop(timeout=5)
        for gait in gaits:
            gait.stop(timeout=5)
    failed = [g.name for g in gaits if g.last_error is not None]
    if failed:
        print(f"failed: {failed}", file=sys.stderr)
        return 1
    print("stopped cleanly")
    return 0


if __name__ == "__main__":
    sys.exit(main())
