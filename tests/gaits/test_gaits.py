"""Gait files: the library, round trips, the JSON Schema, precise validation errors, and control tables."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tomllib
from pathlib import Path

import jsonschema
import pytest

from asm_py import Event, PeriodicAutomaton, SimClock, TimerTrigger
from gaits.model import GaitError, dumps, load, loads, to_dict
from gaits.table import angle_at, compress, expand, phase_states

from ..helpers import ROOT

GAITS = ROOT / "gaits"
LIBRARY = sorted((GAITS / "library").glob("*.toml"))
LIBRARY_DIR = GAITS / "library"
SCHEMA = json.loads((GAITS / "schema.json").read_text())

GOOD = """\
# a tiny gait
name = "tiny"
[robot]
shape = "chain"
modules = 2
axes = "pitch"
[limits]
min = -60.0
max = 60.0
[automata.swing]
states = [
    { angle = 30.0, duration = 0.5 },
    { angle = -30.0, duration = 0.5, interpolation = "step" },
]
[[modules]]
id = 1
automaton = "swing"
phase = 0.0
direction = 1
[[modules]]
id = 2
automaton = "swing"
phase = 0.5
direction = -1
"""


def test_the_library_has_the_six_classic_gaits() -> None:
    names = {path.stem for path in LIBRARY}
    assert {"caterpillar", "lateral_undulation", "sidewinding", "rolling_loop", "inchworm", "legged_walk"} <= names
    shapes = {load(path).robot.shape for path in LIBRARY}
    assert shapes == {"chain", "loop", "legged"}


@pytest.mark.parametrize("path", LIBRARY, ids=[p.stem for p in LIBRARY])
def test_library_files_validate_match_the_schema_and_round_trip(path: Path) -> None:
    gait = load(path)
    jsonschema.validate(tomllib.loads(path.read_text()), SCHEMA)
    again = loads(dumps(gait))
    assert again == gait and to_dict(again) == to_dict(gait)
    if not gait.timed:  # sensor-driven, neighbour-driven or one-shot: no control table to expand
        with pytest.raises(ValueError):
            expand(gait)
        return
    assert gait.period == pytest.approx(1.0)
    times, table = expand(gait)
    assert len(table) == gait.robot.modules and all(len(row) == len(times) for row in table)
    low, high = gait.limits
    assert all(low <= v <= high for row in table for v in row)


def test_a_small_file_loads_into_typed_objects() -> None:
    gait = loads(GOOD)
    assert gait.name == "tiny" and gait.robot.modules == 2 and gait.limits == (-60.0, 60.0)
    assert gait.automata["swing"].period == 1.0 and gait.automata["swing"].states[1].interpolation == "step"
    assert [m.direction for m in gait.modules] == [1, -1]
    jsonschema.validate(tomllib.loads(GOOD), SCHEMA)


@pytest.mark.parametrize(
    ("change", "path", "marker"),
    [
        (("modules = 2", "modules = 2\ncolour = 'red'"), "robot.colour", "colour"),
        (("phase = 0.5", "phase = 1.0"), "modules[1].phase", "phase = 1.0"),
        (("phase = 0.5", "phase = nan"), "modules[1].phase", "phase = nan"),
        (("direction = -1", "direction = 0"), "modules[1].direction", "direction = 0"),
        (("angle = 30.0, duration = 0.5", "angle = 95.0, duration = 0.5"), "automata.swing.states[0].angle", "95"),
        (("angle = 30.0, duration = 0.5", "angle = inf, duration = 0.5"), "automata.swing.states[0].angle", "inf"),
        (
            ("angle = 30.0, duration = 0.5", "angle = 30.0, duration = 0"),
            "automata.swing.states[0].duration",
            "duration = 0 ",
        ),
        (("angle = 30.0, duration = 0.5", "angle = 30.0, until = 'beer'"), "automata.swing.states[0].until", "beer"),
        (('automaton = "swing"\nphase = 0.5', 'automaton = "walk"\nphase = 0.5'), "modules[1].automaton", "walk"),
        (("id = 2", "id = 1"), "modules[1].id", "id = 1"),
        (("id = 2", "id = 9"), "modules[1].id", "id = 9"),
    ],
)
def test_validation_errors_name_the_field_and_line(change: tuple[str, str], path: str, marker: str) -> None:
    text = GOOD.replace(*change, 1)
    with pytest.raises(GaitError) as caught:
        loads(text, source="tiny.toml")
    problems = {p.path: p for p in caught.value.problems}
    assert path in problems, caught.value.problems
    line = problems[path].line
    assert line is not None and marker in text.splitlines()[line - 1], (problems[path], text)
    assert "tiny.toml" in str(caught.value)


def test_missing_modules_and_every_problem_at_once() -> None:
    text = GOOD.replace("modules = 2", "modules = 3").replace("min = -60.0", "min = -10.0")
    with pytest.raises(GaitError) as caught:
        loads(text)
    paths = [p.path for p in caught.value.problems]
    assert paths == ["automata.swing.states[1].angle", "modules"]  # -30° below -10°, and module 3 unassigned
    with pytest.raises(GaitError, match="not valid TOML"):
        loads("name = ")


def test_expansion_is_what_the_modules_periodic_automaton_commands(services) -> None:
    """Run module 2's automaton (phase 0.5, direction -1) on the simulation clock: it commands the expanded table."""
    gait = loads(GOOD)
    assignment = gait.assignment(2)
    clock = SimClock()
    event = Event("tick", clock=clock)
    timer = TimerTrigger(0.01, clock=clock)
    event.add_trigger(timer)
    states = phase_states(gait.automata[assignment.automaton])
    automaton = PeriodicAutomaton("gait", event, states, direction=assignment.direction, clock=clock)
    seen: list[tuple[float, float]] = []
    automaton.output.on_change(lambda v: seen.append((clock.now(), v)))
    services.extend([automaton, timer])
    automaton.start(assignment.phase)
    timer.start()
    clock.advance(2.0)
    assert len(seen) > 150
    off = [(t, v) for t, v in seen if abs(v - angle_at(gait, 2, t)) > 1e-9]
    assert len(off) <= 4, off[:5]  # at most the samples that fall exactly on a step's boundary


def test_compression_recovers_one_automaton_with_phases_and_directions() -> None:
    n = 16
    # asymmetric in time, so a reversed column is not also a forward shift (as it would be for a pure sine)
    base = [40 * math.sin(2 * math.pi * k / n) + 15 * math.sin(4 * math.pi * k / n + 1) for k in range(n)]
    shifts = [(0, 1), (3, 1), (6, 1), (5, -1)]
    table = [[base[(s + d * k) % n] for k in range(n)] for s, d in shifts]
    automaton, assignments = compress(table, 1.0)
    assert [(a.phase * n, a.direction) for a in assignments] == [(s, d) for s, d in shifts]
    gait = loads(GOOD)
    gait.automata = {automaton.name: automaton}
    gait.modules = assignments
    gait.robot.modules = len(assignments)
    gait.limits = (-90.0, 90.0)
    _, again = expand(gait, samples=n)
    assert all(math.isclose(a, b, abs_tol=1e-9) for ra, rb in zip(again, table, strict=True)
               for a, b in zip(ra, rb, strict=True))  # fmt: skip
    with pytest.raises(ValueError, match="more than one automaton"):
        compress([base, [0.0] * n], 1.0)


def test_library_tables_compress_back() -> None:
    gait = load(GAITS / "library" / "caterpillar.toml")
    _, table = expand(gait, samples=112)  # phases are sevenths: sample on a grid that has them
    automaton, assignments = compress(table, gait.period, tolerance=0.01)
    assert len(automaton.states) == 112
    assert [a.phase for a in assignments] == pytest.approx([m.phase for m in gait.modules], abs=1e-5)


def test_gaits_cli(tmp_path: Path) -> None:
    ok = subprocess.run([sys.executable, "-m", "gaits.cli", "validate", *map(str, LIBRARY)], capture_output=True,
                        text=True, timeout=60)  # fmt: skip
    assert ok.returncode == 0 and ok.stdout.count(": ok") == len(LIBRARY)
    bad = tmp_path / "bad.toml"
    bad.write_text(GOOD.replace("phase = 0.5", "phase = 1.5"))
    out = subprocess.run([sys.executable, "-m", "gaits.cli", "validate", str(bad)], capture_output=True, text=True,
                         timeout=60)  # fmt: skip
    assert out.returncode == 1 and "line 23: modules[1].phase" in out.stderr
    table = subprocess.run([sys.executable, "-m", "gaits.cli", "expand", str(LIBRARY[0]), "--samples", "8"],
                           capture_output=True, text=True, timeout=60)  # fmt: skip
    assert table.returncode == 0 and len(table.stdout.splitlines()) == 2 + load(LIBRARY[0]).robot.modules


def test_program_files_check_what_a_schema_cannot() -> None:
    """Sequence steps name gaits of the file; only a gait that ends by itself may go without cycles before the
    last step; event fields go with their event; a neighbour exists and has the named state."""
    base = (LIBRARY_DIR / "steerable_caterpillar.toml").read_text(encoding="utf-8")
    cases = {
        '\n[program]\nsequence = [{ gait = "forward" }, { gait = "left", cycles = 2 }]\n':
            ("program.sequence[0]", "never ends by itself"),
        '\n[program]\nsequence = [{ gait = "sideways", cycles = 2 }]\n': ("program.sequence[0].gait", "unknown gait"),
    }  # fmt: skip
    for extra, (path, words) in cases.items():
        _refused(base + extra, path, words)
    inch = (LIBRARY_DIR / "contact_inchworm.toml").read_text(encoding="utf-8")
    for old, new, path, words in [
        ('until = "contact"', 'until = "contact", tolerance = 2.0', ".tolerance", "only a state ending on 'at_goal'"),
        ("neighbour = -1", "neighbour = 9", ".neighbour", "no module +9 away"),
        ('state = "h2"', 'state = "h99"', ".state", "has no state 'h99'"),
        ('until = "contact"', 'until = "contact", on_timeout = "bogus"', "on_timeout", '"next", "stop"'),
    ]:
        _refused(inch.replace(old, new, 1), path, words)


def _refused(text: str, path: str, words: str) -> None:
    """The loader refuses ``text`` with a problem at a path ending in (or equal to) ``path`` that says ``words``."""
    with pytest.raises(GaitError) as caught:
        loads(text)
    assert any(path in p.path and words in p.message for p in caught.value.problems), caught.value.lines()


def test_a_signal_state_needs_its_signal_and_a_signal_goes_only_with_it() -> None:
    from tests.gaits.preview import SIGNALLED

    gait = loads(SIGNALLED)
    assert gait.automata["lead"].states[1].emit == 7 and gait.automata["follow"].states[0].signal == 7
    assert loads(dumps(gait)) == gait
    for old, new, path, words in [
        ('until = "signal", signal = 7', 'until = "signal"', ".signal", "needs the number"),
        ('until = "signal", signal = 7', 'until = "contact", signal = 7', ".signal", "only a state ending on 'signal'"),
        ("emit = 7", "emit = 300", ".emit", "300"),
    ]:
        _refused(SIGNALLED.replace(old, new, 1), path, words)
