"""Random programs for the firmware and Python module runtimes to agree on (any program the encoder can write)."""

from __future__ import annotations

import random

from asm_module.program import EVENTS, Mode, ModeState, Program, Until


def random_program(rng: random.Random) -> Program:
    def state() -> ModeState:
        event = rng.choice([None, None, *EVENTS])
        until = None
        if event == "neighbour":
            until = Until("neighbour", neighbour=rng.choice([-2, -1, 1]), state=rng.randrange(4))
        elif event == "signal":
            until = Until("signal", state=rng.randrange(1, 256), on_timeout=rng.choice(["next", "stop"]))
        elif event in ("at_goal", "torque"):
            until = Until(event, round(rng.uniform(0, 5), 2))
        elif event is not None:
            until = Until(event)
        duration = None if until is not None and rng.random() < 0.3 else round(rng.uniform(0.02, 2), 3)
        return ModeState(round(rng.uniform(-90, 90), 2), duration, rng.choice(["step", "linear"]), until,
                         rng.choice([0, 0, 0, rng.randrange(1, 256)]))  # fmt: skip

    modes = tuple(Mode(tuple(state() for _ in range(rng.randrange(1, 6))), round(rng.random() * 0.99, 3),
                       rng.choice([1, -1]), rng.random() < 0.2) for _ in range(rng.randrange(1, 4)))  # fmt: skip
    sequence = tuple((rng.randrange(len(modes)), rng.randrange(0, 9)) for _ in range(rng.randrange(0, 3)))
    return Program(modes, sequence)
