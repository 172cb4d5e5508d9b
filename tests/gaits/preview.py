"""What tests of several layers check a preview against: a gait whose modules wait on a broadcast signal, and
"this module's goals lie on the preview's trajectory"."""

from __future__ import annotations

import bisect

SIGNALLED = """
name = "signalled"
modules = [ { id = 1, automaton = "lead" }, { id = 2, automaton = "follow" }, { id = 3, automaton = "follow" },
            { id = 4, automaton = "follow" }, { id = 5, automaton = "follow" }, { id = 6, automaton = "follow" } ]
[robot]
shape = "chain"
modules = 6
axes = "pitch"
[automata.lead]
states = [ { angle = 0.0, duration = 0.5, interpolation = "step" },
           { name = "go", angle = 30.0, duration = 0.5, interpolation = "linear", emit = 7 } ]
[automata.follow]
states = [ { name = "wait", angle = 0.0, until = "signal", signal = 7, interpolation = "step" },
           { angle = 40.0, duration = 0.3, interpolation = "linear" },
           { angle = -20.0, duration = 0.3, interpolation = "linear" } ]
"""


def assert_follows_preview(
    sim_times: list[float], sim_goals: list[list[float]], column: int, record: list[tuple[float, float]],
    started: float, tick: float = 1 / 50,
) -> None:  # fmt: skip
    """Every goal of ``record`` ((time, goal), time on the clock ``started`` is on) in its first 2 s lies on the
    preview's trajectory of module ``column + 1`` within one control tick either side."""
    samples = [(t - started, v) for t, v in record if 0 <= t - started <= 2.0]
    assert len(samples) > 50, f"module {column + 1} produced {len(samples)} goals in 2 s"
    for t, value in samples:
        # the simulated trajectory over [t - tick, t + tick]: its ticks inside, and its values at both ends
        lo = bisect.bisect_left(sim_times, t - tick)
        hi = bisect.bisect_right(sim_times, t + tick)
        window = [row[column] for row in sim_goals[lo:hi]]
        window += [interpolate(sim_times, sim_goals, column, t - tick), interpolate(sim_times, sim_goals, column,
                                                                                   t + tick)]  # fmt: skip
        # between its samples the trajectory may bulge past them (a peak): by at most one tick's change
        step = max(
            abs(rows[column] - prev[column])
            for prev, rows in zip(sim_goals[max(lo, 1) - 1 : hi], sim_goals[max(lo, 1) : hi + 1], strict=False)
        )
        assert min(window) - step - 1e-3 <= value <= max(window) + step + 1e-3, (column + 1, t, value, window)


def interpolate(times: list[float], rows: list[list[float]], column: int, t: float) -> float:
    k = min(max(bisect.bisect_right(times, t) - 1, 0), len(times) - 2)
    frac = (t - times[k]) / (times[k + 1] - times[k])
    return rows[k][column] + max(0.0, min(1.0, frac)) * (rows[k + 1][column] - rows[k][column])
