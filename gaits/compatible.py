"""Are a connected robot's modules the ones a gait describes? Checked before a deploy, so a mismatch is said first.

A gait is previewed and tuned for its ``[robot]``: so many modules, each of its module type (gaits/robot.py), whose
hinge turns ±``range`` degrees. A module reports whether it answers, its ``joint.limits`` — settable only within its
calibration's soft limits (``joint.calibration``, themselves within its hardware's range), and every goal sent is
clamped to them — its ``module.info``: firmware version, language and how many states it holds, and its
``module.type``: the name of its type (a module older than the object, or one not told its type, says none). From
those, :func:`mismatches` finds:

* modules the gait assigns that do not answer, and modules that answer but the gait does not name (the robot has
  another count of modules than the one simulated);
* a module whose limits cut off angles the gait commands (it refuses such a table: gaits.deploy says so too);
* a module whose type is not the one the gait describes for it (``m3 is module type X, the gait describes Y``),
  where the module says its type and the gait names it;
* where the types cannot be compared so, a module whose limits reach beyond the hinge range of its type in the gait:
  its joint turns further than the module the gait was made for, so it is another type of module;
* a module that holds fewer states than the gait gives it (its module.info's ``max_states``: a C module keeps 64).

:func:`read_limits` and :func:`read_objects` ask each module; the Deploy tab (web/deploy_panel.py) shows the lines
before it asks to deploy to a real robot, and :func:`module_lines` (each module's firmware, type and calibration) in its
log.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from asm_module.names import module_name

from .model import FORWARD, Gait


def commanded(gait: Gait) -> dict[int, tuple[float, float]]:
    """Per module ID, the lowest and highest angle any of its automata commands, in any gait of the program."""
    spans: dict[int, tuple[float, float]] = {}
    for name in gait.program_gaits():
        listed = gait.modules if name == FORWARD else gait.gaits[name]
        for a in listed:
            angles = [s.angle for s in gait.automata[a.automaton].states]
            if not angles:
                continue
            low, high = spans.get(a.id, (min(angles), max(angles)))
            spans[a.id] = (min(low, *angles), max(high, *angles))
    return spans


def states_needed(gait: Gait) -> dict[int, int]:
    """Per module ID, the states its program holds: those of its automaton in every gait of the program."""
    needed: dict[int, int] = {}
    for name in gait.program_gaits():
        for a in gait.modules if name == FORWARD else gait.gaits[name]:
            needed[a.id] = needed.get(a.id, 0) + len(gait.automata[a.automaton].states)
    return needed


def mismatches(gait: Gait, present: Iterable[str], limits: Mapping[str, tuple[float, float]],
               infos: Mapping[str, Mapping[str, Any]] | None = None,
               types: Mapping[str, str] | None = None) -> list[str]:  # fmt: skip
    """What differs between the gait's robot and the modules that answered (``present``, with the ``limits``, the
    ``module.info`` and the ``module.type`` each reported); empty when nothing does."""
    present = set(present)
    wanted = {module_name(a.id): a.id for a in gait.modules}
    lines = []
    missing = sorted((n for n in wanted if n not in present), key=wanted.__getitem__)
    if missing:
        lines.append(f"{', '.join(missing)} of the gait's {len(wanted)} modules did not answer")
    extra = sorted((n for n in present if n.startswith("m") and n[1:].isdigit() and n not in wanted),
                   key=lambda n: int(n[1:]))  # fmt: skip
    if extra:
        lines.append(f"{', '.join(extra)} answered but the gait has {len(wanted)} modules: the robot is not the "
                     f"{gait.robot.modules}-module {gait.robot.shape} it was made for")  # fmt: skip
    spans = commanded(gait)
    robot = gait.robot
    for name, module_id in sorted(wanted.items(), key=lambda item: item[1]):
        described, reported = robot.type_name(module_id), (types or {}).get(name, "")
        compared = bool(described and reported)  # both name a type: the names say it, not the range
        other = type_mismatch(gait, module_id, name, reported)
        if other is not None:
            lines.append(other)
        if name not in limits:
            continue
        low, high = limits[name]
        want_low, want_high = spans.get(module_id, (0.0, 0.0))
        if low > want_low + 1e-3 or high < want_high - 1e-3:
            lines.append(f"{name} allows {low:g}..{high:g}°, the gait commands {want_low:g}..{want_high:g}°: it "
                         "would refuse the table")  # fmt: skip
        hinge = robot.module_type(module_id).range
        if not compared and (low < -hinge - 1e-3 or high > hinge + 1e-3):
            where = f"robot.types.{described}.range" if described else "robot.module.range"
            lines.append(f"{name} turns {low:g}..{high:g}°, beyond the ±{hinge:g}° hinge of the gait's module "
                         f"({where}): another type of module than the one simulated")  # fmt: skip
    needed = states_needed(gait)
    for name, module_id in sorted(wanted.items(), key=lambda item: item[1]):
        info = (infos or {}).get(name)
        if info is not None and needed.get(module_id, 0) > int(info["max_states"]):
            lines.append(f"{name} holds {info['max_states']} states, the gait gives it {needed[module_id]}: it "
                         "would refuse the table")  # fmt: skip
    return lines


def type_mismatch(gait: Gait, module_id: int, name: str, reported: str) -> str | None:
    """The line that says module ``module_id`` (node ``name``) is another type than the gait describes for it, where
    both name a type (``reported`` its module.type, "": it says none); None when they agree or cannot be compared.
    The same words wherever a deploy is checked (the Deploy tab's question, gaits.deploy's own check), so a line a
    user accepted is recognised."""
    described = gait.robot.type_name(module_id)
    if not (described and reported) or reported == described:
        return None
    return (f"{name} is module type {reported}, the gait describes {described} (robot.types.{described}): another "
            "type of module than the one simulated")  # fmt: skip


def read_objects(lookup: Any, names: Iterable[str], object_name: str, timeout: float = 2.0) -> dict[str, Any]:
    """Each module's ``object_name`` (``module.info``, ``joint.calibration``) by ``lookup``; a module that does not
    answer or has no such object (one older than the object) is left out."""
    found = {}
    for name in names:
        try:
            found[name] = lookup(name, object_name, timeout=timeout).get(timeout=timeout)
        except Exception:  # no reply, no such object: nothing to say about it
            continue
    return found


def module_lines(infos: Mapping[str, Mapping[str, Any]], calibrations: Mapping[str, Mapping[str, Any]],
                 types: Mapping[str, str] | None = None) -> list[str]:  # fmt: skip
    """One line per module: its firmware (language, version, build), type and calibration, for a deploy's log."""
    types = types or {}
    lines = []
    for name in sorted(set(infos) | set(calibrations) | set(types), key=lambda n: (len(n), n)):
        parts = [name + ":"]
        info = infos.get(name)
        if info is not None:
            v = int(info["version"])
            language = {0: "Python", 1: "C"}.get(int(info["language"]), f"language {info['language']}")
            parts.append(f"{language} {v >> 16 & 0xFF}.{v >> 8 & 0xFF}.{v & 0xFF} build {int(info['build']):08x}")
        if types.get(name):
            parts.append(f"type {types[name]}")
        c = calibrations.get(name)
        if c is not None:
            parts.append(f"zero {c['zero']:g}°, direction {int(c['direction']):+d}, soft limits "
                         f"{c['min']:g}..{c['max']:g}°")  # fmt: skip
        lines.append(" ".join(parts))
    return lines


def read_limits(lookup: Any, names: Iterable[str], timeout: float = 2.0) -> dict[str, tuple[float, float]]:
    """Each module's ``joint.limits`` by ``lookup(name, "joint.limits", timeout)`` (a Node's lookup); a module that
    does not answer is left out (:func:`mismatches` reports it as missing)."""
    found = {}
    for name in names:
        try:
            low, high = lookup(name, "joint.limits", timeout=timeout).get(timeout=timeout)
        except Exception:  # no reply, no such object: not this module's to judge here
            continue
        found[name] = (float(low), float(high))
    return found
