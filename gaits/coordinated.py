"""How the library's programs and coordinated gaits were made: steering, a tour, a neighbour-coordinated wave, a
contact-driven inchworm and a one-shot curl (``python -m gaits.serpenoid`` writes them with the others).

Each is a phase automaton of the kinds the paper lists beyond the periodic time-driven one, run on the modules
(asm_module/program.py): several gaits of one program, sensor-driven states, neighbour events, one-shot modes.
"""

from __future__ import annotations

import math

from .model import Assignment, Automaton, Gait, Robot, State
from .serpenoid import sampled, sine

TURN_BIAS = 20.0
"""Degrees every yaw joint bends to turn the steerable caterpillar (≈ 85° of heading in 5 s on 12 modules)."""


def _steerable(name: str, description: str) -> Gait:
    robot = Robot("chain", 12, "alternating")
    automata = {
        "wave": sampled("wave", sine(50.0), 1.0),
        "straight": Automaton("straight", [State(0.0, 1.0, None, "step", "straight")]),
        "left": Automaton("left", [State(TURN_BIAS, 1.0, None, "step", "left")]),
        "right": Automaton("right", [State(-TURN_BIAS, 1.0, None, "step", "right")]),
    }

    def assign(yaw: str) -> list[Assignment]:
        # pitch joints carry the caterpillar wave (7 pitch joints per wavelength); yaw joints steer
        return [Assignment(n + 1, "wave", round((-(n // 2) * 2 / 7) % 1.0, 6) % 1.0, 1) if n % 2 == 0
                else Assignment(n + 1, yaw, 0.0, 1) for n in range(robot.modules)]  # fmt: skip

    gaits = {"left": assign("left"), "right": assign("right")}
    return Gait(name, robot, automata, assign("straight"), (-90.0, 90.0), description, gaits=gaits)


def _wave_states(amplitude: float, seconds: float) -> list[State]:
    """The caterpillar's wave as linear states named w1, w2, … over ``seconds``."""
    wave = sampled("wave", sine(amplitude), seconds)
    return [State(s.angle, s.duration, None, "linear", f"w{k + 1}") for k, s in enumerate(wave.states)]


def _neighbour_caterpillar() -> Gait:
    """No phase offsets: module 1 leads on its own clock, and every other module starts its stroke when the
    module before it enters w3 (two states into its stroke, plus the tick the news takes: ≈ 1/7 period)."""
    rest = 0.05
    wave = _wave_states(50.0, 1.0 - rest)
    lead = Automaton("lead", [State(0.0, rest, None, "step", "rest"), *wave])
    follow = Automaton("follow", [State(0.0, 2.0, "neighbour", "step", "rest", neighbour=-1, state="w3"), *wave])
    robot = Robot("chain", 8, "pitch")
    modules = [Assignment(n, "lead" if n == 1 else "follow", 0.0, 1) for n in range(1, 9)]
    return Gait("neighbour_caterpillar", robot, {"lead": lead, "follow": follow}, modules, (-90.0, 90.0),
                "A caterpillar without phase offsets: module 1 keeps time, and each module starts its stroke when "
                "the one before it enters state w3 (a neighbour event over the bus).")  # fmt: skip


def _contact_inchworm() -> Gait:
    """The inchworm's hump, advanced by its feet: after its hump each module reaches 10° down until it touches the
    ground (a contact state: contact made, 0.6 s at most); module 1 then rests, the others wait for the module
    before them to be in h2 (a neighbour event), so a late landing delays the wave instead of breaking it."""
    hump = [State(round(75.0 * max(0.0, math.sin(2 * math.pi * (k + 1) / 16)) ** 2, 3), 0.0625, None, "linear",
                  f"h{k + 1}") for k in range(7)]  # fmt: skip
    land = State(-10.0, 0.6, "contact", "step", "land")
    lead = Automaton("lead", [*hump, land, State(0.0, 0.5, None, "step", "rest")])
    follow = Automaton("follow", [State(0.0, 3.0, "neighbour", "step", "rest", neighbour=-1, state="h2"), *hump,
                                  land])  # fmt: skip
    modules = [Assignment(n, "lead" if n == 1 else "follow", 0.0, 1) for n in range(1, 9)]
    description = ("An inchworm whose states advance on foot contact: after its hump each module reaches down until "
                   "it touches the ground, and the next module's hump starts from its neighbour's.")  # fmt: skip
    automata = {"lead": lead, "follow": follow}
    return Gait("contact_inchworm", Robot("chain", 8, "pitch"), automata, modules, (-90.0, 90.0), description)


def _curl() -> Gait:
    """Eight pitch joints at 45° each make a closed octagon: a one-shot sequence that ends when it is there."""
    curl = Automaton("curl", [State(0.0, 0.5, None, "step", "flat"), State(20.0, 1.5, None, "linear", "bend"),
                              State(45.0, 2.5, None, "linear", "close"), State(45.0, 1.0, None, "step", "hold")],
                     one_shot=True)  # fmt: skip
    modules = [Assignment(n, "curl", 0.0, 1) for n in range(1, 9)]
    return Gait("curl_into_loop", Robot("chain", 8, "pitch"), {"curl": curl}, modules, (-90.0, 90.0),
                "A one-shot sequence: a chain of 8 pitch joints curls into a loop (45° each) and stops there; each "
                "module's gait ends by itself and says so (gait.done).")  # fmt: skip


def library() -> dict[str, Gait]:
    steerable = _steerable(
        "steerable_caterpillar",
        "A caterpillar of pitch and yaw joints you can steer: pitch joints crawl (A 50°), yaw joints bend "
        f"{TURN_BIAS:g}° to turn. Gaits forward, left and right of one program; drive it with the arrow keys.",
    )
    tour = _steerable(
        "caterpillar_tour",
        "A program of gaits: the steerable caterpillar crawls forward 5 cycles, turns left 5, then goes forward.",
    )
    tour.sequence = [("forward", 5), ("left", 5), ("forward", 0)]
    return {"steerable_caterpillar": steerable, "caterpillar_tour": tour,
            "neighbour_caterpillar": _neighbour_caterpillar(), "curl_into_loop": _curl(),
            "contact_inchworm": _contact_inchworm()}  # fmt: skip
