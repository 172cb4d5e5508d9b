"""The robot a gait runs on: its configuration (shape, modules, axes) and what its modules are — module types, each
described once (size, mass, inertia, joint range, servo), and which module IDs are of which type.

In the gait file's ``[robot]``, or in a robot file it names (``[robot] file = "my_robot.toml"``, relative to the
gait file's folder and inside it), whose own ``[robot]`` table holds the description: ``module`` (one unnamed type),
``type`` (the name of the default type) and ``types`` (named types, each with the ``ids`` of its modules). The
configuration — shape, module count, axes — stays the gait's: one set of modules makes a chain for one gait and a
loop for another. Every module no named type lists is of the default type: ``type``'s, else ``[robot.module]``'s,
else today's module (:class:`ModuleType`'s defaults), so a file that describes nothing simulates as it always did.

A module reports its type's name (``module.type``, docs/protocol.md §9): gaits/compatible.py compares the two
before a deploy. An unnamed type makes no claim about the name.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from .errors import GaitError
from .validate import SCHEMA, Checker, Validator, brief, decode, parse, read


@dataclass
class ModuleType:
    """A module type: its body and its servo. Every default is the module the simulator has always modelled
    (SIMULATION.md: 5 cm, 0.2 kg, kp 10, kv 0.1, ±1.5 N·m, ±90°), so a file without a description simulates exactly
    as before; a field given in the file overrides only itself. The gait is then judged against the servo it will
    meet, not an ideal one."""

    length: float | None = None
    """Metres along the chain; None: ``robot.module_size`` (which the default type's length sets)."""
    width: float | None = None
    """Metres across the chain (the hinge axis of a pitch module); None: the length, a cube."""
    height: float | None = None
    """Metres, bottom to top; None: the length."""
    mass: float = 0.2
    """kg per module."""
    stall_torque: float = 1.5
    """N·m: the most the servo exerts, at standstill (the actuator's force limit)."""
    no_load_speed: float | None = None
    """Degrees per second at which the torque the servo can give in its direction of motion has fallen (linearly)
    to zero, as on a DC motor's torque-speed line; None: no such limit (the ideal servo of the past)."""
    kp: float = 10.0
    """Position gain, N·m per radian of error (MuJoCo's unit, as SIMULATION.md gives it)."""
    damping: float = 0.1
    """Velocity gain, N·m·s per radian."""
    deadband: float = 0.0
    """Degrees: while |goal − angle| is below it the servo exerts no torque (no correction), as a hobby servo's
    deadband or a gearbox's backlash lets the joint sit off its goal."""
    range: float = 90.0
    """The hinge's mechanical range, ± degrees: the actuator cannot be commanded beyond it."""
    inertia: tuple[float, float, float] | None = None
    """kg·m², the principal moments about the module's centre (along the chain, across it, up), where a solid box
    would be wrong (a heavy motor at the hinge, a battery at an end); None: a solid box's of its mass and size."""
    ids: tuple[int, ...] = ()
    """The module IDs of a named type (the default type is every module no named type lists)."""

    @property
    def ideal(self) -> bool:
        """MuJoCo's position actuator alone models this servo: no torque-speed line, no deadband."""
        return self.no_load_speed is None and self.deadband == 0.0


FIELDS: tuple[str, ...] = tuple(f.name for f in fields(ModuleType) if f.name != "ids")
"""A module type's fields as a file spells them (``ids`` only a named type's)."""
DESCRIPTION = ("module", "type", "types")
"""The keys of ``[robot]`` that describe its modules: what a robot file's ``[robot]`` holds."""


@dataclass
class Robot:
    shape: str = "chain"
    modules: int = 8
    axes: str = "pitch"
    module_size: float = 0.05
    legs: int = 0
    """Legged robots: number of legs around the body (the modules are split evenly among them)."""
    module: ModuleType = field(default_factory=ModuleType)
    """The default module type: every module no named type lists (``[robot.module]``, or ``types[type]``)."""
    types: dict[str, ModuleType] = field(default_factory=dict)
    """Named module types (``[robot.types.NAME]``), each with the IDs of its modules."""
    type: str = ""
    """The default type's name (one of ``types``); "": an unnamed type (``[robot.module]``, or today's module)."""
    file: str | None = None
    """The robot file the module description was read from, as the gait names it (a save names it again)."""

    @property
    def size(self) -> tuple[float, float, float]:
        """The default type's (length, width, height), metres: the description's, else a cube of ``module_size``."""
        return self._size(self.module)

    def _size(self, m: ModuleType) -> tuple[float, float, float]:
        length = self.module_size if m.length is None else m.length
        return length, length if m.width is None else m.width, length if m.height is None else m.height

    def type_name(self, module_id: int) -> str:
        """The name of module ``module_id``'s type ("": unnamed)."""
        return next((name for name, t in self.types.items() if module_id in t.ids), self.type)

    def module_type(self, module_id: int) -> ModuleType:
        """What module ``module_id`` (1-based) is."""
        return next((t for t in self.types.values() if module_id in t.ids), self.module)

    def size_of(self, module_id: int) -> tuple[float, float, float]:
        """Module ``module_id``'s (length, width, height), metres."""
        return self._size(self.module_type(module_id))

    def every_module(self) -> list[ModuleType]:
        """Each module's type, in module order (index 0 is module 1)."""
        return [self.module_type(k) for k in range(1, self.modules + 1)]

    @property
    def ideal_servo(self) -> bool:
        """Every module's servo is MuJoCo's position actuator alone (gaits/servo.py is then not needed)."""
        return all(t.ideal for t in self.every_module())

    @property
    def length(self) -> float:
        """Metres from end to end of the modules laid in a line: modules × module size when they share one."""
        lengths = [self.size_of(k)[0] for k in range(1, self.modules + 1)]
        return self.modules * lengths[0] if len(set(lengths)) == 1 else math.fsum(lengths)

    def axis(self, index: int) -> str:
        """The axis of module ``index`` (0-based): pitch or yaw."""
        if self.axes == "alternating":
            return "pitch" if index % 2 == 0 else "yaw"
        return self.axes


# -- reading --------------------------------------------------------------------------------------------------------

_ROBOT = SCHEMA["properties"]["robot"]
_FILE_VALIDATOR = Validator({
    "$schema": SCHEMA["$schema"], "$defs": SCHEMA["$defs"], "type": "object", "additionalProperties": False,
    "required": ["robot"],
    "properties": {"description": SCHEMA["properties"]["description"],
                   "robot": {"type": "object", "additionalProperties": False,
                             "properties": {key: _ROBOT["properties"][key] for key in DESCRIPTION}}},
})  # fmt: skip
"""A robot file: an optional description and a ``[robot]`` of the gait schema's description fields, no others."""


def robot_of(data: dict[str, Any], gait: Checker, limits: tuple[float, float], path: Path | None) -> Robot:
    """The robot of a gait's ``[robot]`` (its structure checked), its module description read from the robot file it
    names if it names one (``path``: the gait file's, whose folder holds it). Problems of the gait go to ``gait``; a
    robot file's are a GaitError of their own, naming that file."""
    data = dict(data)
    name = data.pop("file", None)
    described = {key: data.pop(key) for key in DESCRIPTION if key in data}
    robot = Robot(**data)
    check = gait
    if name is not None:
        for key in described:
            gait.bad(f"robot.{key}", f"the modules are described in the robot file {brief(name)} (robot.file): "
                                     "describe them there only")  # fmt: skip
        loaded = _robot_file(name, gait, path)
        if loaded is None:
            return robot
        described, check = loaded
        robot.file = name
    _describe(robot, described, check, gait, limits, "module_size" in data)
    if check is not gait:
        check.raise_if()
    return robot


def _why(name: str, exc: Exception) -> str:
    """Why a robot file cannot be read, for a person (an exception's class name said nothing: a review)."""
    if "\0" in name:
        return "a file name cannot hold a NUL character"
    if isinstance(exc, OSError):
        return exc.strerror or type(exc).__name__
    return str(exc) or type(exc).__name__


def _robot_file(name: str, gait: Checker, path: Path | None) -> tuple[dict[str, Any], Checker] | None:
    """The description in robot file ``name`` and a Checker for its problems; None when it cannot be read (said at
    robot.file). Its structure problems are raised at once, as its own file's."""
    if path is None:
        gait.bad("robot.file", f"this gait has no folder to find {brief(name)} in (an upload, an edited copy): "
                               "describe the modules in its [robot] instead")  # fmt: skip
        return None
    shown = str(path.parent / name)  # as a person finds it: beside the gait file, as that was named
    try:
        folder = path.resolve().parent
        if Path(name).is_absolute():
            raise _Refused("must be a path relative to the gait file's folder, not an absolute one")
        raw = os.path.join(folder, name)  # as the system reads the name: pathlib drops the "/" of "robot.toml/"
        found = Path(raw).resolve()
        if not found.is_relative_to(folder):
            raise _Refused("lies outside the gait file's folder: a gait may only name files beside or below it")
        if not found.exists():
            raise _Refused("no such file beside the gait file")
        if name.endswith("/") or (os.path.exists(raw) and not os.path.isfile(raw)):
            raise _Refused("is not a regular file")
        if not os.path.exists(raw):  # resolve() took "sub/.." away: the system, reading the name, does not
            raise _Refused("cannot be reached: a folder on its path does not exist")
        if found == path.resolve() or (path.exists() and os.path.samefile(found, path)):
            raise _Refused("names the gait file itself: a robot file holds the [robot] description only")
        text = decode(read(found), shown, "robot")
        data = parse(text, shown)
    except _Refused as refused:
        gait.bad("robot.file", f"{brief(name)} {refused}")
        return None
    except GaitError as exc:  # not UTF-8, larger than a gait file, not TOML: said with the robot file's own name
        raise GaitError(shown, [replace(p, file=shown) for p in exc.problems], more=exc.more) from None
    except RuntimeError:  # Path.resolve (before Python 3.13) on symbolic links that name each other
        gait.bad("robot.file", f"{brief(name)} cannot be read: its symbolic links form a loop")
        return None
    except (OSError, ValueError) as exc:  # unreadable, a name the system refuses (a NUL byte, too long), a loop
        gait.bad("robot.file", f"{brief(name)} cannot be read: {_why(name, exc)}")
        return None
    check = Checker(shown, text, file=shown)
    robot = data.get("robot")
    if isinstance(robot, dict) and "file" in robot:
        check.bad("robot.file", "a robot file cannot name another robot file")
        check.raise_if()
    check.check_structure(data, _FILE_VALIDATOR)
    return data["robot"], check


class _Refused(Exception):
    """A robot file named that is not read (why, for robot.file's problem)."""


def _module_type(data: dict[str, Any]) -> ModuleType:
    values = dict(data)
    ids, inertia = tuple(values.pop("ids", ())), values.pop("inertia", None)
    return ModuleType(**values, ids=ids, inertia=None if inertia is None else (inertia[0], inertia[1], inertia[2]))


def _describe(robot: Robot, described: dict[str, Any], check: Checker, gait: Checker, limits: tuple[float, float],
              sized: bool) -> None:  # fmt: skip
    """Set ``robot``'s module types from ``described`` (a checked structure), ``check`` collecting its problems,
    ``gait`` the gait's own (its limits); ``sized``: the gait gives ``module_size``."""
    types = described.get("types", {})
    robot.types = {name: _module_type(t) for name, t in types.items()}
    default, where = described.get("module", {}), "robot.module"
    robot.module = _module_type(default)
    if "type" in described:
        name = described["type"]
        if "module" in described:
            check.bad("robot.type", "give robot.type (the named type of every module no type lists) or robot.module "
                                    "(one unnamed type), not both")  # fmt: skip
        if name not in types:
            check.bad("robot.type", f"unknown module type {brief(name)} (described: {', '.join(types) or 'none'})")
        else:
            robot.type, robot.module, default, where = name, robot.types[name], types[name], f"robot.types.{name}"
            if "ids" in default:
                check.bad(f"{where}.ids", "the default type (robot.type) is every module no other type lists: it "
                                          "has no ids of its own")  # fmt: skip
    if "length" in default:
        if not sized:
            robot.module_size = default["length"]  # what measures the default module reads module_size
        elif robot.module_size != default["length"]:
            check.bad(f"{where}.length", f"{default['length']} m differs from robot.module_size {robot.module_size} m:"
                                         " give one of them")  # fmt: skip
    _check_ids(robot, types, check)
    if ("type" in described or "module" in described) and all(
        any(k in t.ids for t in robot.types.values() if t is not robot.module) for k in range(1, robot.modules + 1)
    ):
        check.bad(where if "module" in described else "robot.type", "no module is of the default type: the named "
                  "types list every module (leave the default type out, or list fewer modules)")  # fmt: skip
    if robot.shape == "loop" and len({robot.size_of(k)[0] for k in range(1, robot.modules + 1)}) > 1:
        check.bad("robot.types", "a loop's modules must share one length (its polygon closes only with equal sides)")
    tables = {"robot.module": described.get("module", {})} | {f"robot.types.{n}": t for n, t in types.items()}
    for path, table in tables.items():
        if "inertia" in table:
            _check_inertia(robot, path, _module_type(table), check)
    _check_range(robot, tables, gait, limits)


def _check_range(robot: Robot, tables: dict[str, Any], gait: Checker, limits: tuple[float, float]) -> None:
    """``[limits]`` within the hinge range of every module's type, said or not (90°): the simulated modules' hardware
    range is their type's (gaits/sim.py), and a module's soft limits lie within it."""
    low, high = limits
    if not low < high:
        return
    kinds = {robot.type_name(k) for k in range(1, robot.modules + 1)}
    for name in sorted(kinds):
        path = f"robot.types.{name}" if name else "robot.module"
        span = (robot.types[name] if name else robot.module).range
        if -span <= low < high <= span:
            continue
        what = f"the joint range of module type {name}" if name else "the module's joint range"
        given = "range" in tables.get(path, {})
        gait.bad("limits", f"{low}..{high}° exceeds {what} ±{span}° ({path}.range"
                           + (")" if given else ", 90 unless given: give your modules' range)"))  # fmt: skip


def _check_ids(robot: Robot, types: dict[str, Any], check: Checker) -> None:
    """Each module is of one named type at most, IDs exist, and every named type is some module's."""
    seen: dict[int, str] = {}
    for name, table in types.items():
        for k, module_id in enumerate(table.get("ids", []) if name != robot.type else []):
            where = f"robot.types.{name}.ids[{k}]"
            if module_id > robot.modules:
                check.bad(where, f"must be a module ID 1..{robot.modules} (the gait's robot.modules), not {module_id}")
            elif module_id in seen:
                check.bad(where, f"module {module_id} is already of a type ({seen[module_id]})")
            else:
                seen[module_id] = where
        if not table.get("ids") and name != robot.type:
            check.bad(f"robot.types.{name}", "no module is of this type: list its module IDs (ids) or make it the "
                                             "default type (robot.type)")  # fmt: skip


def _check_inertia(robot: Robot, path: str, t: ModuleType, check: Checker) -> None:
    """A module's moments must be a body's: each half (mjcf.py splits a module at its hinge, each half's mass at a
    quarter of the length from the centre) keeps positive moments that satisfy the triangle inequality."""
    assert t.inertia is not None
    ixx, iyy, izz = t.inertia
    length = robot.module_size if t.length is None else t.length
    spread = t.mass * length**2 / 16  # m·L²/16: the halves' mass off the centre, in iyy and izz
    if iyy <= spread or izz <= spread:
        check.bad(
            f"{path}.inertia",
            f"across and up must exceed m·L²/16 = {spread:.4g} kg·m² for {t.mass:g} kg "
            f"along {length:g} m (its halves' mass lies off its centre), not {iyy:g}, {izz:g}",
        )
    elif ixx + iyy < izz or ixx + izz < iyy or iyy + izz - ixx < 2 * spread:
        check.bad(f"{path}.inertia", f"({ixx:g}, {iyy:g}, {izz:g}) kg·m² is no body's: each moment must be at most "
                                     f"the sum of the other two (along: at most across + up − m·L²/8 = "
                                     f"{iyy + izz - 2 * spread:.4g})")  # fmt: skip


# -- writing --------------------------------------------------------------------------------------------------------


def _fields(t: ModuleType, *, ids: bool) -> dict[str, Any]:
    """A type's fields that differ from today's module (and, for a named type, its IDs)."""
    out = {key: list(value) if isinstance(value, tuple) else value for key in FIELDS
           if (value := getattr(t, key)) is not None and value != getattr(ModuleType, key, None)}  # fmt: skip
    return out | ({"ids": list(t.ids)} if ids and t.ids else {})


def description(robot: Robot, *, inline: bool = False) -> dict[str, Any]:
    """The ``[robot]`` keys that describe ``robot``'s modules: its robot file's name, or (``inline``, or without a
    file) the description itself."""
    if robot.file is not None and not inline:
        return {"file": robot.file}
    out: dict[str, Any] = {}
    if robot.type:
        out["type"] = robot.type
    elif module := _fields(robot.module, ids=False):
        out["module"] = module
    if robot.types:
        out["types"] = {name: _fields(t, ids=True) for name, t in robot.types.items()}
    return out
