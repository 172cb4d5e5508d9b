"""Gait control tables (module × time → commanded angle), as PolyBot used them, from and to phase automata.

:func:`expand` samples what every module's PeriodicAutomaton will command — the same reference function the
modules run (asm_py.automaton.reference_at), started at phase φ and running in its direction. :func:`compress`
goes back: a periodic table whose columns are time shifts (or time-reversed shifts) of one another becomes one
automaton plus a phase delay and a direction per module.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from asm_py.automaton import PhaseState, interpolation_of, scalar_reference_at, state_starts

from .model import Assignment, Automaton, Gait, State


def phase_states(automaton: Automaton) -> list[PhaseState]:
    """The automaton's states as the module runtime runs them (degrees, seconds)."""
    if automaton.period is None:
        raise ValueError(f"automaton {automaton.name!r} waits for events: it has no fixed timing to expand")
    return [PhaseState(s.angle, s.duration or 0.0, interpolation_of(s.interpolation)) for s in automaton.states]


def angle_at(gait: Gait, module_id: int, t: float) -> float:
    """The angle (degrees) module ``module_id`` commands ``t`` seconds after the gait starts."""
    assignment = gait.assignment(module_id)
    states = phase_states(gait.automata[assignment.automaton])
    period = math.fsum(s.duration for s in states)
    return scalar_reference_at(
        states, state_starts(states), period, assignment.phase * period + assignment.direction * t
    )


def expand(gait: Gait, *, samples: int = 16, periods: float = 1.0) -> tuple[list[float], list[list[float]]]:
    """Times and the table: ``table[i][k]`` is module i+1's angle at ``times[k]`` (``samples`` per period)."""
    period = gait.period
    count = max(1, round(samples * periods))
    times = [k * period / samples for k in range(count)]
    rows = []
    for assignment in gait.modules:
        states = phase_states(gait.automata[assignment.automaton])
        starts = state_starts(states)
        rows.append([scalar_reference_at(states, starts, period, assignment.phase * period + assignment.direction * t)
                     for t in times])  # fmt: skip
    return times, rows


def format_table(gait: Gait, *, samples: int = 16) -> str:
    """The expanded table as text: one row per module, one column per sample, degrees."""
    times, rows = expand(gait, samples=samples)
    head = "module " + " ".join(f"{t:6.3f}" for t in times)
    lines = [f"# {gait.name}: commanded angle (degrees), module x time (s), period {gait.period:g} s", head]
    lines += [f"{m.id:6d} " + " ".join(f"{v:6.1f}" for v in row) for m, row in zip(gait.modules, rows, strict=True)]
    return "\n".join(lines)


def _shift(base: Sequence[float], row: Sequence[float], tolerance: float) -> tuple[int, int] | None:
    n = len(base)
    for direction in (1, -1):
        for s in range(n):
            if all(abs(row[k] - base[(s + direction * k) % n]) <= tolerance for k in range(n)):
                return s, direction
    return None


def compress(
    table: Sequence[Sequence[float]], period: float, *, name: str = "compressed", tolerance: float = 1e-6
) -> tuple[Automaton, list[Assignment]]:
    """One automaton and per-module (phase, direction) reproducing ``table`` (one period, equal time steps).

    ValueError if a row is not a time shift of the first one: such a table needs several automata.
    """
    if not table or not table[0]:
        raise ValueError("an empty table cannot be compressed")
    base = list(table[0])
    n = len(base)
    if any(len(row) != n for row in table):
        raise ValueError("every row of the table needs the same number of samples")
    dt = period / n
    # Linear states: state k ramps to base[k + 1] over dt, so the reference at k·dt is base[k].
    automaton = Automaton(name, [State(base[(k + 1) % n], dt, None, "linear") for k in range(n)])
    assignments = []
    for i, row in enumerate(table):
        found = _shift(base, row, tolerance)
        if found is None:
            raise ValueError(f"row {i} is not a time shift of row 0: the table needs more than one automaton")
        s, direction = found
        assignments.append(Assignment(i + 1, name, s / n, direction))
    return automaton, assignments
