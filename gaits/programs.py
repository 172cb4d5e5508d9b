"""From a gait file to what each module runs: its program (asm_module/program.py).

Mode k of every module's program is gait k of the file (``modules`` first, then ``[gaits]`` in order), so a switch
names the same gait on every module. A neighbour's state, named in the file by name or 1-based number, becomes the
0-based index in the automaton that neighbour runs in the same gait.
"""

from __future__ import annotations

from typing import Literal

from asm_module.program import EVENTS, Mode, ModeState, Program, Until
from asm_py.automaton import interpolation_of

from .model import FORWARD, Automaton, Gait, State, state_index

DEFAULT_TOLERANCE = 2.0
"""Degrees: an at_goal state without a tolerance ends within 2° of its angle."""
DEFAULT_THRESHOLD = 1.0
"""N·m: a torque state without a threshold ends at 1 N·m."""


def _until(gait: Gait, gait_name: str, module_id: int, state: State) -> Until | None:
    if state.until is None:
        return None
    outcome: Literal["next", "stop"] = "stop" if state.on_timeout == "stop" else "next"
    if state.until == "at_goal":
        return Until("at_goal", DEFAULT_TOLERANCE if state.tolerance is None else state.tolerance, on_timeout=outcome)
    if state.until == "torque":
        return Until("torque", DEFAULT_THRESHOLD if state.threshold is None else state.threshold, on_timeout=outcome)
    if state.until == "neighbour":
        offset = -1 if state.neighbour is None else state.neighbour
        other = gait.automata[gait.assignment(module_id + offset, gait_name).automaton]
        index = state_index(other, state.state)
        assert index is not None  # the loader checked it
        return Until("neighbour", neighbour=offset, state=index, on_timeout=outcome)
    if state.until == "signal":
        return Until("signal", state=state.signal or 0, on_timeout=outcome)
    for event in EVENTS:  # the loader checked the name against the same list
        if event == state.until:
            return Until(event, on_timeout=outcome)
    raise ValueError(f"unknown event {state.until!r}")


def _mode(gait: Gait, gait_name: str, module_id: int) -> Mode:
    assignment = gait.assignment(module_id, gait_name)
    automaton: Automaton = gait.automata[assignment.automaton]
    states = tuple(ModeState(s.angle, s.duration, interpolation_of(s.interpolation),
                             _until(gait, gait_name, module_id, s), s.emit or 0) for s in automaton.states)  # fmt: skip
    return Mode(states, assignment.phase, assignment.direction, automaton.one_shot)


def module_program(gait: Gait, module_id: int) -> Program:
    """Module ``module_id``'s program: one mode per gait of the file, and the file's sequence."""
    names = gait.program_gaits()
    modes = tuple(_mode(gait, name, module_id) for name in names)
    return Program(modes, tuple((names.index(name), cycles) for name, cycles in gait.sequence))


def mode_index(gait: Gait, name: str) -> int:
    """The mode number of gait ``name`` on every module (ValueError if the program has no such gait)."""
    names = gait.program_gaits()
    if name not in names:
        raise ValueError(f"the program has no gait {name!r} (it has: {', '.join(names)})")
    return names.index(name)


__all__ = ["FORWARD", "mode_index", "module_program"]
