"""Gait files: a TOML document (comments welcome) describing a robot and the phase automata its modules run.

    name = "caterpillar"
    [robot]
    shape = "chain"          # chain | loop | legged
    modules = 8
    axes = "pitch"           # pitch | yaw | alternating (pitch, yaw, pitch, …)
    module_size = 0.05       # metres
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
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w

from asm_py.errors import AsmError

SHAPES = ("chain", "loop", "legged")
AXES = ("pitch", "yaw", "alternating")
INTERPOLATIONS = ("step", "linear")
EVENTS = ("contact",)
MAX_MODULES = 254
LIBRARY = Path(__file__).resolve().parent / "library"
"""The library gaits shipped with the package (gaits.serpenoid writes them)."""


@dataclass(frozen=True)
class Problem:
    path: str
    """Where: a dotted field path such as ``modules[3].phase``."""
    message: str
    line: int | None = None
    """1-based line in the file, when it can be located."""

    def __str__(self) -> str:
        where = f"line {self.line}: " if self.line else ""
        return f"{where}{self.path}: {self.message}"


class GaitError(AsmError, ValueError):
    """A gait file that cannot be used; ``problems`` says every reason."""

    def __init__(self, source: str, problems: list[Problem]) -> None:
        self.source = source
        self.problems = problems
        super().__init__(f"{source}: " + "; ".join(str(p) for p in problems))


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


@dataclass
class Automaton:
    name: str
    states: list[State]

    @property
    def period(self) -> float | None:
        """Seconds per cycle, or None when a state waits for an event."""
        if any(s.duration is None for s in self.states):
            return None
        return math.fsum(s.duration for s in self.states)  # type: ignore[misc]


@dataclass
class Assignment:
    id: int
    automaton: str
    phase: float = 0.0
    direction: int = 1


@dataclass
class Robot:
    shape: str = "chain"
    modules: int = 8
    axes: str = "pitch"
    module_size: float = 0.05
    legs: int = 0
    """Legged robots: number of legs around the body (the modules are split evenly among them)."""

    def axis(self, index: int) -> str:
        """The axis of module ``index`` (0-based): pitch or yaw."""
        if self.axes == "alternating":
            return "pitch" if index % 2 == 0 else "yaw"
        return self.axes


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

    @property
    def period(self) -> float:
        periods = {a.period for a in self.automata.values()}
        if len(periods) != 1 or None in periods:
            raise ValueError("the gait has no single fixed period")
        return periods.pop()  # type: ignore[return-value]

    def assignment(self, module_id: int) -> Assignment:
        return next(m for m in self.modules if m.id == module_id)


# -- loading and validation -----------------------------------------------------------------------------------------

_TOP = {"name", "description", "robot", "limits", "ground", "automata", "modules"}
_ROBOT = {"shape", "modules", "axes", "module_size", "legs"}
_STATE = {"name", "angle", "duration", "until", "interpolation"}
_MODULE = {"id", "automaton", "phase", "direction"}


def load(path: str | Path) -> Gait:
    path = Path(path)
    return loads(path.read_text(encoding="utf-8"), source=str(path))


def loads(text: str, *, source: str = "<gait>") -> Gait:
    """Parse and validate a gait document; GaitError lists every problem."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        line = re.search(r"line (\d+)", str(exc))
        raise GaitError(source, [Problem("(file)", f"not valid TOML: {exc}", int(line[1]) if line else None)]) from None
    return from_dict(data, source=source, text=text)


def _finite(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def from_dict(data: dict[str, Any], *, source: str = "<gait>", text: str = "") -> Gait:
    problems: list[Problem] = []

    def bad(path: str, message: str) -> None:
        problems.append(Problem(path, message, locate(text, path)))

    def unknown_fields(table: dict[str, Any], allowed: set[str], prefix: str = "") -> None:
        for key in sorted(set(table) - allowed):
            bad(f"{prefix}{key}", "unknown field")

    def section(key: str, default: dict[str, Any] | None = None) -> dict[str, Any]:
        table = data.get(key, default if default is not None else {})
        if not isinstance(table, dict):
            bad(key, "must be a table")
            return {}
        return table

    unknown_fields(data, _TOP)
    name = data.get("name")
    if not isinstance(name, str) or not name:
        bad("name", "missing: a gait needs a name")
    robot_data = section("robot")
    unknown_fields(robot_data, _ROBOT, "robot.")
    robot = Robot(**{k: v for k, v in robot_data.items() if k in _ROBOT})
    if robot.shape not in SHAPES:
        bad("robot.shape", f"must be one of {', '.join(SHAPES)}, not {robot.shape!r}")
    if robot.axes not in AXES:
        bad("robot.axes", f"must be one of {', '.join(AXES)}, not {robot.axes!r}")
    if not isinstance(robot.modules, int) or isinstance(robot.modules, bool) or not 1 <= robot.modules <= MAX_MODULES:
        bad("robot.modules", f"must be an integer 1..{MAX_MODULES}, not {robot.modules!r}")
    if not _finite(robot.module_size) or robot.module_size <= 0:
        bad("robot.module_size", f"must be a positive number of metres, not {robot.module_size!r}")
    uneven = isinstance(robot.modules, int) and isinstance(robot.legs, int) and robot.modules % max(robot.legs, 1)
    if robot.shape == "legged" and (not isinstance(robot.legs, int) or robot.legs < 2 or uneven):
        bad("robot.legs", "a legged robot needs 2 or more legs sharing its modules evenly")
    if robot.shape == "loop" and isinstance(robot.modules, int) and robot.modules < 4:
        bad("robot.modules", "a closed loop needs at least 4 modules")

    limits_data = section("limits", {"min": -90.0, "max": 90.0})
    low, high = limits_data.get("min", -90.0), limits_data.get("max", 90.0)
    unknown_fields(limits_data, {"min", "max"}, "limits.")
    if not (_finite(low) and _finite(high) and -180 <= low < high <= 180):
        bad("limits", f"min < max, both finite degrees within ±180, not {low!r}..{high!r}")
        low, high = -90.0, 90.0

    ground_data = section("ground")
    unknown_fields(ground_data, {"friction", "anisotropic"}, "ground.")
    ground = Ground()
    friction = ground_data.get("friction", 1.0)
    if not _finite(friction) or not 0 < friction <= 10:
        bad("ground.friction", f"must be a number in (0, 10], not {friction!r}")
    else:
        ground.friction = float(friction)
    aniso = ground_data.get("anisotropic")
    if aniso is not None:
        if not (isinstance(aniso, list) and len(aniso) == 2 and all(_finite(v) and 0 < v <= 10 for v in aniso)):
            bad("ground.anisotropic", f"must be [μ along, μ across], two numbers in (0, 10], not {aniso!r}")
        else:
            ground.anisotropic = (float(aniso[0]), float(aniso[1]))

    automata: dict[str, Automaton] = {}
    automata_data = data.get("automata", {})
    if not isinstance(automata_data, dict) or not automata_data:
        bad("automata", "missing: at least one automaton")
        automata_data = {}
    for auto_name, auto in automata_data.items():
        base = f"automata.{auto_name}"
        states_data = auto.get("states") if isinstance(auto, dict) else None
        if isinstance(auto, dict):
            unknown_fields(auto, {"states"}, f"{base}.")
        if not isinstance(states_data, list) or not states_data:
            bad(f"{base}.states", "missing: at least one state")
            continue
        states = []
        for k, st in enumerate(states_data):
            path = f"{base}.states[{k}]"
            if not isinstance(st, dict):
                bad(path, "must be a table")
                continue
            unknown_fields(st, _STATE, f"{path}.")
            angle, duration, until = st.get("angle"), st.get("duration"), st.get("until")
            interpolation = st.get("interpolation", "linear")
            if not _finite(angle):
                bad(f"{path}.angle", f"must be a finite number of degrees, not {angle!r}")
            elif not low <= angle <= high:
                bad(f"{path}.angle", f"{angle}° is outside the joint limits {low}..{high}°")
            if duration is None and until is None:
                bad(path, "needs a duration or the event it waits for (until)")
            if duration is not None and (not _finite(duration) or duration <= 0):
                bad(f"{path}.duration", f"must be a positive number of seconds, not {duration!r}")
            if until is not None and until not in EVENTS:
                bad(f"{path}.until", f"unknown event {until!r} (known: {', '.join(EVENTS)})")
            if interpolation not in INTERPOLATIONS:
                bad(f"{path}.interpolation", f"must be one of {', '.join(INTERPOLATIONS)}, not {interpolation!r}")
            states.append(State(angle if _finite(angle) else 0.0, duration, until, interpolation, st.get("name", "")))
        automata[auto_name] = Automaton(auto_name, states)
    periods = {a.period for a in automata.values() if a.period is not None}
    if len(periods) > 1:
        bad("automata", f"all automata must share one period, not {sorted(periods)} seconds")

    assignments: list[Assignment] = []
    modules_data = data.get("modules", [])
    if not isinstance(modules_data, list):
        bad("modules", "must be an array of tables ([[modules]])")
        modules_data = []
    seen: dict[int, int] = {}
    for i, md in enumerate(modules_data):
        path = f"modules[{i}]"
        if not isinstance(md, dict):
            bad(path, "must be a table")
            continue
        unknown_fields(md, _MODULE, f"{path}.")
        mid, auto, phase, direction = md.get("id"), md.get("automaton"), md.get("phase", 0.0), md.get("direction", 1)
        if not isinstance(mid, int) or isinstance(mid, bool) or not 1 <= mid <= robot.modules:
            bad(f"{path}.id", f"must be a module ID 1..{robot.modules}, not {mid!r}")
        elif mid in seen:
            bad(f"{path}.id", f"module {mid} is already assigned in modules[{seen[mid]}]")
        else:
            seen[mid] = i
        if auto not in automata:
            bad(f"{path}.automaton", f"unknown automaton {auto!r} (defined: {', '.join(automata) or 'none'})")
        if not _finite(phase) or not 0 <= phase < 1:
            bad(f"{path}.phase", f"must be in [0, 1), not {phase!r}")
        if direction not in (1, -1) or isinstance(direction, bool):
            bad(f"{path}.direction", f"must be 1 or -1, not {direction!r}")
        assignments.append(Assignment(mid if isinstance(mid, int) else 0, auto, phase if _finite(phase) else 0.0,
                                      direction if direction in (1, -1) else 1))  # fmt: skip
    if isinstance(robot.modules, int):
        missing = sorted(set(range(1, robot.modules + 1)) - set(seen))
        if missing:
            bad("modules", f"no assignment for module(s) {', '.join(map(str, missing))}")
    if problems:
        raise GaitError(source, problems)
    return Gait(name, robot, automata, sorted(assignments, key=lambda m: m.id), (float(low), float(high)),
                data.get("description", ""), ground)  # fmt: skip


def locate(text: str, path: str) -> int | None:
    """Best-effort 1-based line of ``path`` in the TOML ``text`` (None if it cannot be told)."""
    if not text:
        return None
    lines = text.splitlines()
    parts = re.findall(r"[^.\[\]]+|\[\d+\]", path)
    section_line = 0
    if parts and parts[0] == "modules" and len(parts) > 1 and parts[1].startswith("["):
        index = int(parts[1][1:-1])
        headers = [n for n, line in enumerate(lines) if re.match(r"\s*\[\[modules\]\]", line)]
        if not headers:  # the inline form: modules = [ { id = 1, … }, … ]
            start = next((n for n, line in enumerate(lines) if re.match(r"\s*modules\s*=\s*\[", line)), None)
            rows = [n for n in range(start + 1, len(lines)) if "{" in lines[n]] if start is not None else []
            return rows[index] + 1 if index < len(rows) else None
        if index >= len(headers):
            return None
        section_line = headers[index]
        return _field_line(lines, section_line, parts[2] if len(parts) > 2 else None)
    if parts and parts[0] == "automata" and len(parts) > 1:
        header = next((n for n, line in enumerate(lines) if re.match(rf"\s*\[automata\.{re.escape(parts[1])}\]", line)),
                      None)  # fmt: skip
        if header is None:
            return None
        if len(parts) > 3 and parts[3].startswith("["):
            index = int(parts[3][1:-1])
            braces = [n for n in range(header + 1, len(lines)) if "{" in lines[n]]
            return braces[index] + 1 if index < len(braces) else header + 1
        return header + 1
    if parts and parts[0] in ("robot", "limits", "ground"):
        header = next((n for n, line in enumerate(lines) if re.match(rf"\s*\[{parts[0]}\]", line)), None)
        if header is None:
            return None
        return _field_line(lines, header, parts[1] if len(parts) > 1 else None)
    return _field_line(lines, -1, parts[0] if parts else None)


def _field_line(lines: list[str], start: int, name: str | None) -> int | None:
    if name is None:
        return start + 1 if start >= 0 else None
    for n in range(start + 1, len(lines)):
        if n > start + 1 and re.match(r"\s*\[", lines[n]):
            break
        if re.match(rf"\s*{re.escape(name)}\s*=", lines[n]):
            return n + 1
    return start + 1 if start >= 0 else None


# -- dumping --------------------------------------------------------------------------------------------------------


def to_dict(gait: Gait) -> dict[str, Any]:
    def state(s: State) -> dict[str, Any]:
        out: dict[str, Any] = {"angle": s.angle}
        if s.name:
            out = {"name": s.name, **out}
        if s.duration is not None:
            out["duration"] = s.duration
        if s.until is not None:
            out["until"] = s.until
        out["interpolation"] = s.interpolation
        return out

    robot = {"shape": gait.robot.shape, "modules": gait.robot.modules, "axes": gait.robot.axes,
             "module_size": gait.robot.module_size}  # fmt: skip
    if gait.robot.shape == "legged":
        robot["legs"] = gait.robot.legs
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
        "automata": {a.name: {"states": [state(s) for s in a.states]} for a in gait.automata.values()},
        "modules": [
            {"id": m.id, "automaton": m.automaton, "phase": m.phase, "direction": m.direction} for m in gait.modules
        ],
    }
    return out


def dumps(gait: Gait) -> str:
    """The gait as TOML; ``loads(dumps(g)) == g``."""
    return tomli_w.dumps(to_dict(gait))
