"""Gait files: a TOML document (comments welcome) describing a robot and the phase automata its modules run.

    name = "caterpillar"
    [robot]
    shape = "chain"          # chain | loop | legged
    modules = 8
    axes = "pitch"           # pitch | yaw | alternating (pitch, yaw, pitch, …)
    module_size = 0.05       # metres
    [robot.module]           # optional: the module's description (gaits/README.md); every field defaults to today's
    mass = 0.2               # kg
    stall_torque = 1.5       # N·m
    [robot.types.heavy]      # optional: named module types, each with its module IDs (gaits/robot.py); or
    mass = 0.6               # [robot] file = "my_robot.toml", a robot file holding the description
    ids = [4, 5]
    [limits]                 # joint limits, degrees; every module enforces them whatever it is sent
    min = -90.0
    max = 90.0
    [automata.wave]          # a phase automaton: its states run in order, period = the sum of their durations
    states = [ { angle = 0.0, duration = 0.125, interpolation = "linear" }, … ]
    [[modules]]              # one per module: which automaton, phase delay φ in [0, 1), direction ±1
    id = 1
    automaton = "wave"
    phase = 0.0
    direction = 1

A state has a target ``angle`` (degrees) and a ``duration`` (seconds), or ``until`` the event that ends it
("contact"); ``interpolation`` is ``step`` (jump to the angle) or ``linear`` (ramp from the previous state's angle),
exactly as asm_py.PeriodicAutomaton runs it on the modules. The JSON Schema is gaits/schema.json.

:func:`load` validates everything before returning, so a bad file is never half applied: :class:`GaitError` lists
every problem with its field path and, where it can be found, its line.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w

from .errors import GaitError as GaitError  # re-exported: callers have always found it here
from .errors import Problem as Problem
from .robot import FIELDS as FIELDS  # re-exported: the fields of a module type
from .robot import ModuleType as ModuleType
from .robot import Robot as Robot
from .robot import description, robot_of
from .validate import SCHEMA, Checker, brief, decode, parse, read

_FIELDS = SCHEMA["properties"]
SHAPES: tuple[str, ...] = tuple(_FIELDS["robot"]["properties"]["shape"]["enum"])
AXES: tuple[str, ...] = tuple(_FIELDS["robot"]["properties"]["axes"]["enum"])
_STATE_FIELDS = _FIELDS["automata"]["additionalProperties"]["properties"]["states"]["items"]["properties"]
INTERPOLATIONS: tuple[str, ...] = tuple(_STATE_FIELDS["interpolation"]["enum"])
EVENTS: tuple[str, ...] = tuple(_STATE_FIELDS["until"]["enum"])
MAX_MODULES: int = _FIELDS["robot"]["properties"]["modules"]["maximum"]
FORWARD = "forward"
"""The name of the gait ``modules`` assigns: the first of the program."""
LIBRARY = Path(__file__).resolve().parent / "library"
"""The library gaits shipped with the package (gaits.serpenoid writes them)."""


@dataclass
class State:
    angle: float
    """Target joint angle, degrees."""
    duration: float | None = None
    """Seconds in this state per period (None: the state lasts until its event)."""
    until: str | None = None
    """Event that ends the state early (or alone, without a duration)."""
    interpolation: str = "linear"
    name: str = ""
    tolerance: float | None = None
    """at_goal: degrees that count as reached."""
    threshold: float | None = None
    """torque: N·m that end the state."""
    neighbour: int | None = None
    """neighbour: the watched module's ID relative to this one."""
    state: str | int | None = None
    """neighbour: the watched module's state, by name or 1-based number."""
    on_timeout: str | None = None
    """With an event and a duration: "next" (default) or "stop"."""
    signal: int | None = None
    """signal: the broadcast signal (1..255) that ends the state."""
    emit: int | None = None
    """A broadcast signal (1..255) sent to every module on entering the state."""


@dataclass
class Automaton:
    name: str
    states: list[State]
    one_shot: bool = False
    """Non-periodic: the gait ends after the last state."""

    @property
    def period(self) -> float | None:
        """Seconds per cycle, or None when a state waits for an event or the automaton is one-shot."""
        if self.one_shot or any(s.duration is None or s.until is not None for s in self.states):
            return None
        return math.fsum(s.duration for s in self.states if s.duration is not None)


@dataclass
class Assignment:
    id: int
    automaton: str
    phase: float = 0.0
    direction: int = 1


@dataclass
class Ground:
    """The surface the robot is simulated on (a real robot meets whatever floor it is on)."""

    friction: float = 1.0
    """Coulomb friction μ between modules and the ground."""
    anisotropic: tuple[float, float] | None = None
    """(μ along each module, μ across it): snake skin or passive wheels, which lateral undulation needs."""


@dataclass
class Gait:
    name: str
    robot: Robot
    automata: dict[str, Automaton]
    modules: list[Assignment]
    limits: tuple[float, float] = (-90.0, 90.0)
    description: str = ""
    ground: Ground = field(default_factory=Ground)
    extra: dict[str, Any] = field(default_factory=dict)
    gaits: dict[str, list[Assignment]] = field(default_factory=dict)
    """More gaits of the program, by name (``modules`` is the one called FORWARD)."""
    sequence: list[tuple[str, int]] = field(default_factory=list)
    """The program's own order: (gait, cycles); cycles 0: until the gait ends by itself (one-shot), or for the
    last step until the robot is told otherwise."""

    @property
    def period(self) -> float:
        """Seconds per cycle of its periodic time-driven automata (ValueError when it has none)."""
        periods = {p for a in self.automata.values() if (p := a.period) is not None}
        if len(periods) != 1:
            raise ValueError("the gait has no periodic time-driven automaton, so no fixed period")
        return periods.pop()

    @property
    def timed(self) -> bool:
        """Every automaton is periodic and time-driven: the gait has a control table."""
        return all(a.period is not None for a in self.automata.values())

    def assignment(self, module_id: int, gait: str = FORWARD) -> Assignment:
        assignments = self.modules if gait == FORWARD else self.gaits[gait]
        return next(m for m in assignments if m.id == module_id)

    def program_gaits(self) -> list[str]:
        """The gaits of the program in mode order: FORWARD, then the file's ``[gaits]``."""
        return [FORWARD, *self.gaits]


# -- loading and validation -----------------------------------------------------------------------------------------


def load(path: str | Path) -> Gait:
    """Read, parse and validate a gait file; GaitError (never anything else) for any bytes it holds (and for a robot
    file it names, beside it)."""
    return loads(read(path), source=str(path), path=Path(path))


def loads(text: str | bytes, *, source: str = "<gait>", path: Path | None = None) -> Gait:
    """Parse and validate a gait document; GaitError lists every problem. ``path``: the file it was read from,
    whose folder holds a robot file it names (without one it cannot name any)."""
    text = decode(text, source)
    return from_dict(parse(text, source), source=source, text=text, path=path)


def from_dict(data: Any, *, source: str = "<gait>", text: str | None = None, path: Path | None = None) -> Gait:
    """Validate a parsed document (structure by gaits/schema.json, then what a schema cannot say) and build it.
    ``path``: the gait file's, beside which a robot file it names is read."""
    check = Checker(source, text)
    check.check_structure(data)  # the checks below rely on the structure being right
    bad = check.bad
    limits = data.get("limits", {})
    low, high = limits.get("min", -90.0), limits.get("max", 90.0)
    if not low < high:
        bad("limits", f"min must be below max, not {low}..{high}")
    robot = robot_of(data["robot"], check, (low, high), path)
    if robot.shape == "legged" and (robot.legs < 2 or robot.modules % robot.legs):
        bad("robot.legs", f"a legged robot needs 2 or more legs sharing its {robot.modules} modules evenly")
    if robot.shape == "loop" and robot.modules < 4:
        bad("robot.modules", "a closed loop needs at least 4 modules")
    ground_data = data.get("ground", {})
    anisotropic = ground_data.get("anisotropic")
    ground = Ground(
        friction=ground_data.get("friction", Ground.friction),
        anisotropic=None if anisotropic is None else (anisotropic[0], anisotropic[1]),  # the schema: two numbers
    )

    automata: dict[str, Automaton] = {}
    for name, auto in data["automata"].items():
        states = []
        for k, st in enumerate(auto["states"]):
            angle = st["angle"]
            if low < high and not low <= angle <= high:
                bad(f"automata.{name}.states[{k}].angle", f"{angle}° is outside the joint limits {low}..{high}°")
            states.append(State(angle, st.get("duration"), st.get("until"), st.get("interpolation", "linear"),
                                st.get("name", ""), st.get("tolerance"), st.get("threshold"), st.get("neighbour"),
                                st.get("state"), st.get("on_timeout"), st.get("signal"), st.get("emit")))  # fmt: skip
            _check_event(st, f"automata.{name}.states[{k}]", bad)
        automata[name] = Automaton(name, states, bool(auto.get("one_shot", False)))
    periods = {a.period for a in automata.values() if a.period is not None}
    if len(periods) > 1:
        bad("automata", f"all automata must share one period, not {sorted(periods)} seconds")

    lists = {FORWARD: ("modules", data["modules"])}
    lists |= {name: (f"gaits.{name}.modules", g["modules"]) for name, g in data.get("gaits", {}).items()}
    for where, listed in lists.values():
        _check_assignments(where, listed, robot, automata, bad)
    sequence = [(step["gait"], step.get("cycles", 0)) for step in data.get("program", {}).get("sequence", [])]
    for k, (name, cycles) in enumerate(sequence):
        if name not in lists:
            bad(f"program.sequence[{k}].gait", f"unknown gait {brief(name)} (the program has: {', '.join(lists)})")
        elif not cycles and k + 1 < len(sequence) and not _ends(automata, lists[name][1]):
            bad(f"program.sequence[{k}]", f"gait {name!r} never ends by itself: give it a number of cycles")
    check.raise_if()
    assigned = {name: sorted((Assignment(m["id"], m["automaton"], m.get("phase", 0.0), m.get("direction", 1))
                              for m in listed), key=lambda m: m.id) for name, (_, listed) in lists.items()}  # fmt: skip
    for name, (where, _) in lists.items():
        _check_neighbours(where, assigned[name], robot, automata, bad)
    check.raise_if()
    modules = assigned.pop(FORWARD)
    return Gait(data["name"], robot, automata, modules, (float(low), float(high)), data.get("description", ""),
                ground, gaits=assigned, sequence=sequence)  # fmt: skip


def _check_event(st: dict[str, Any], path: str, bad: Callable[[str, str], None]) -> None:
    """The fields of an event go with their event."""
    until = st.get("until")
    uses = {"tolerance": "at_goal", "threshold": "torque", "neighbour": "neighbour", "state": "neighbour",
            "signal": "signal"}  # fmt: skip
    for key, event in uses.items():
        if key in st and until != event:
            bad(f"{path}.{key}", f"only a state ending on {event!r} has a {key}")
    if until == "neighbour" and "state" not in st:
        bad(f"{path}.state", "a neighbour event needs the neighbour's state that ends it")
    if until == "signal" and "signal" not in st:
        bad(f"{path}.signal", "a signal event needs the number of the signal that ends it")
    if "on_timeout" in st and (until is None or "duration" not in st):
        bad(f"{path}.on_timeout", "only a state with both an event and a duration (its timeout) can time out")


Bad = Callable[[str, str], None]


def _ends(automata: dict[str, Automaton], listed: list[dict[str, Any]]) -> bool:
    """Every module of this gait runs a one-shot automaton: the gait ends by itself."""
    return all(isinstance(m, dict) and m.get("automaton") in automata and automata[m["automaton"]].one_shot
               for m in listed)  # fmt: skip


def _check_assignments(
    path: str, listed: list[dict[str, Any]], robot: Robot, automata: dict[str, Automaton], bad: Bad
) -> None:
    seen: dict[int, int] = {}
    for i, md in enumerate(listed):
        mid, auto = md["id"], md["automaton"]
        if mid > robot.modules:
            bad(f"{path}[{i}].id", f"must be a module ID 1..{robot.modules} (robot.modules), not {mid}")
        elif mid in seen:
            bad(f"{path}[{i}].id", f"module {mid} is already assigned in {path}[{seen[mid]}]")
        else:
            seen[mid] = i
        if auto not in automata:
            bad(f"{path}[{i}].automaton", f"unknown automaton {brief(auto)} (defined: {', '.join(automata)})")
    missing = [m for m in range(1, robot.modules + 1) if m not in seen]  # robot.modules <= 254: the schema said so
    if missing:
        bad(path, f"no assignment for module(s) {', '.join(map(str, missing))}")


def _check_neighbours(
    path: str, assigned: list[Assignment], robot: Robot, automata: dict[str, Automaton], bad: Bad
) -> None:
    """A neighbour event names a module that exists and a state its automaton has (in the same gait)."""
    by_id = {a.id: a for a in assigned}
    for i, a in enumerate(assigned):
        for k, st in enumerate(automata[a.automaton].states):
            if st.until != "neighbour":
                continue
            where = f"automata.{a.automaton}.states[{k}]"
            other = by_id.get(a.id + (st.neighbour or -1))
            if other is None:
                bad(f"{where}.neighbour", f"module {a.id} ({path}[{i}]) has no module {st.neighbour or -1:+d} away")
            elif state_index(automata[other.automaton], st.state) is None:
                bad(f"{where}.state", f"automaton {other.automaton!r} (module {other.id}) has no state {st.state!r}")


def state_index(automaton: Automaton, state: str | int | None) -> int | None:
    """The 0-based index of a state named or numbered (1-based) as a file does, or None."""
    if isinstance(state, int):
        return state - 1 if 1 <= state <= len(automaton.states) else None
    names = [s.name for s in automaton.states]
    return names.index(state) if state in names else None


# -- dumping --------------------------------------------------------------------------------------------------------


def to_dict(gait: Gait, *, inline: bool = False) -> dict[str, Any]:
    """The gait as a document. A robot file it names is named again, unless ``inline``: then its description is
    written into ``[robot]``, a document that stands alone (what a tuner's worker or a robot process is sent)."""

    def state(s: State) -> dict[str, Any]:
        out: dict[str, Any] = {"angle": s.angle}
        if s.name:
            out = {"name": s.name, **out}
        if s.duration is not None:
            out["duration"] = s.duration
        if s.until is not None:
            out["until"] = s.until
        for key in ("tolerance", "threshold", "neighbour", "state", "on_timeout", "signal", "emit"):
            if getattr(s, key) is not None:
                out[key] = getattr(s, key)
        out["interpolation"] = s.interpolation
        return out

    def automaton(a: Automaton) -> dict[str, Any]:
        return {"states": [state(s) for s in a.states], **({"one_shot": True} if a.one_shot else {})}

    def assignments(listed: list[Assignment]) -> list[dict[str, Any]]:
        return [{"id": m.id, "automaton": m.automaton, "phase": m.phase, "direction": m.direction} for m in listed]

    robot = {"shape": gait.robot.shape, "modules": gait.robot.modules, "axes": gait.robot.axes,
             "module_size": gait.robot.module_size}  # fmt: skip
    if gait.robot.shape == "legged":
        robot["legs"] = gait.robot.legs
    robot |= description(gait.robot, inline=inline)
    out: dict[str, Any] = {"name": gait.name}
    if gait.description:
        out["description"] = gait.description
    out |= {
        "robot": robot,
        "limits": {"min": gait.limits[0], "max": gait.limits[1]},
    }
    if gait.ground != Ground():
        ground: dict[str, Any] = {"friction": gait.ground.friction}
        if gait.ground.anisotropic is not None:
            ground["anisotropic"] = list(gait.ground.anisotropic)
        out["ground"] = ground
    out |= {
        "automata": {a.name: automaton(a) for a in gait.automata.values()},
        "modules": assignments(gait.modules),
    }
    if gait.gaits:
        out["gaits"] = {name: {"modules": assignments(listed)} for name, listed in gait.gaits.items()}
    if gait.sequence:
        out["program"] = {"sequence": [{"gait": name, **({"cycles": cycles} if cycles else {})}
                                       for name, cycles in gait.sequence]}  # fmt: skip
    return out


def dumps(gait: Gait, *, inline: bool = False) -> str:
    """The gait as TOML; ``loads(dumps(g)) == g`` (``inline``: its robot file's description written in, see
    :func:`to_dict`)."""
    return tomli_w.dumps(to_dict(gait, inline=inline))
