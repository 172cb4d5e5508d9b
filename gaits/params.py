"""The free parameters of a gait file that gaits/tune.py searches: names, ranges, and how a value changes the file.

A name says where in the file the number lives, in the paths GaitError uses (0-based indexes)::

    automata.wave.states[3].angle        one state's target angle, degrees
    automata.wave.states[3].duration     one state's duration, seconds (the period changes with it)
    modules[2].phase                     one module's phase delay, cycles (taken mod 1)

and, because a gait file does not record the generator that made it (gaits/generate.py and gaits/serpenoid.py write
plain states), the generator's own parameters are applied to what the file holds, the way the generator would:

    amplitude / automata.wave.amplitude  every angle (of that automaton) scaled so the largest |angle| is this
    period                               every duration scaled so each periodic automaton's period is this
    wavelength                           modules per wave: the phase steps by 1 / wavelength per module ID among
                                         the modules running one automaton, the first's phase and the direction
                                         the wave travels kept (a negative wavelength reverses it)

Whole-gait parameters apply first (the period, then ``amplitude`` before an automaton's own, which rescales that
automaton alone; an automaton amplitude for every automaton beside ``amplitude`` is refused: it would undo it), then
single states and phases, whatever order they were given in. A value is rounded (angles to 0.001°, durations
to 0.1 ms, phases to 1e-6) before the gait is built, so the file written is exactly the gait that was simulated.
"""

from __future__ import annotations

import argparse
import copy
import math
import re
from dataclasses import dataclass
from typing import Any

from .model import Gait

_STATE = re.compile(r"^automata\.([^.\[\]]+)\.states\[(\d+)\]\.(angle|duration)$")
_PHASE = re.compile(r"^modules\[(\d+)\]\.phase$")
_AMPLITUDE = re.compile(r"^(?:automata\.([^.\[\]]+)\.)?amplitude$")
_DIGITS = {"angle": 3, "duration": 4, "phase": 6, "amplitude": 3, "period": 4, "wavelength": 4}
_ORDER = {"period": 0, "amplitude": 1, "wavelength": 2, "angle": 3, "duration": 3, "phase": 3}


@dataclass(frozen=True)
class Free:
    """One free parameter: its name (see the module docstring) and the range the search keeps it in."""

    name: str
    low: float
    high: float

    @property
    def kind(self) -> str:
        """angle, duration, phase, amplitude, period or wavelength."""
        if m := _STATE.match(self.name):
            return m.group(3)
        if _PHASE.match(self.name):
            return "phase"
        if _AMPLITUDE.match(self.name):
            return "amplitude"
        return self.name

    def rounded(self, value: float) -> float:
        return round(value, _DIGITS[self.kind])

    def __str__(self) -> str:
        return f"{self.name}={self.low:g}:{self.high:g}"


def parse_free(text: str) -> Free:
    """``NAME=LOW:HIGH``; ValueError naming what is wrong."""
    name, equals, bounds = text.partition("=")
    low_text, colon, high_text = bounds.partition(":")
    if not equals or not colon:
        raise ValueError(f"free parameter {text!r}: write NAME=LOW:HIGH, e.g. amplitude=20:80")
    try:
        low, high = float(low_text), float(high_text)
    except ValueError:
        raise ValueError(f"free parameter {text!r}: LOW and HIGH must be numbers") from None
    if not (math.isfinite(low) and math.isfinite(high) and low < high and math.isfinite(high - low)):
        raise ValueError(f"free parameter {text!r}: needs finite LOW < HIGH (and HIGH - LOW finite)")
    free = Free(name.strip(), low, high)
    known = _STATE.match(free.name) or _PHASE.match(free.name) or _AMPLITUDE.match(free.name)
    if not known and free.name not in ("period", "wavelength"):
        raise ValueError(f"free parameter {free.name!r}: not one of automata.NAME.states[K].angle|duration, "
                         "modules[I].phase, [automata.NAME.]amplitude, period, wavelength")  # fmt: skip
    if free.kind in ("duration", "period") and low <= 0:
        raise ValueError(f"free parameter {text!r}: a {free.kind} must stay above 0 s")
    if free.kind == "wavelength" and low <= 0 < high:
        raise ValueError(f"free parameter {text!r}: a wavelength range may not include 0 (its sign is the way the "
                         "wave runs: -HIGH:-LOW for a gait whose wavelength is negative; speed is measured the way "
                         "the start goes)")  # fmt: skip
    return free


def argument(text: str) -> Free:
    """argparse's view of :func:`parse_free`: a bad parameter is a usage error (exit 2)."""
    try:
        return parse_free(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def check(gait: Gait, frees: list[Free]) -> None:
    """Every free parameter names something this gait has; ValueError otherwise."""
    names = [f.name for f in frees]
    if len(set(names)) != len(names):
        raise ValueError("a free parameter is given twice")
    scaled = {m.group(1) for n in names if (m := _AMPLITUDE.match(n)) and m.group(1)}
    if "amplitude" in names and scaled and scaled >= set(gait.automata):  # every automaton rescaled after it
        raise ValueError(f"amplitude scales every automaton's angles, and {', '.join(sorted(scaled))} rescale each "
                         "of them after it: the first would do nothing (give one or the other)")  # fmt: skip
    for free in frees:
        if m := _STATE.match(free.name):
            automaton = gait.automata.get(m.group(1))
            if automaton is None:
                raise ValueError(f"{free.name}: no automaton {m.group(1)!r} (the gait has {', '.join(gait.automata)})")
            if int(m.group(2)) >= len(automaton.states):
                raise ValueError(f"{free.name}: automaton {automaton.name!r} has {len(automaton.states)} states "
                                 "(0-based indexes)")  # fmt: skip
            if free.kind == "duration" and automaton.states[int(m.group(2))].duration is None:
                raise ValueError(f"{free.name}: that state has no duration (it waits for its event)")
        elif m := _PHASE.match(free.name):
            if int(m.group(1)) >= len(gait.modules):
                raise ValueError(f"{free.name}: the gait assigns {len(gait.modules)} modules (0-based indexes)")
        elif (m := _AMPLITUDE.match(free.name)) and m.group(1) and m.group(1) not in gait.automata:
            raise ValueError(f"{free.name}: no automaton {m.group(1)!r} (the gait has {', '.join(gait.automata)})")
        elif free.kind == "period" and not any(a.period for a in gait.automata.values()):
            raise ValueError("period: the gait has no periodic time-driven automaton")


def current(gait: Gait, free: Free) -> float:
    """The value a free parameter has in ``gait`` (where the search starts)."""
    if m := _STATE.match(free.name):
        state = gait.automata[m.group(1)].states[int(m.group(2))]
        return float(state.angle if m.group(3) == "angle" else state.duration or 0.0)
    if m := _PHASE.match(free.name):
        return gait.modules[int(m.group(1))].phase
    if m := _AMPLITUDE.match(free.name):
        automata = [gait.automata[m.group(1)]] if m.group(1) else list(gait.automata.values())
        return max((abs(s.angle) for a in automata for s in a.states), default=0.0)
    if free.kind == "period":
        return next(p for a in gait.automata.values() if (p := a.period))
    return _wavelength(gait)


def _wavelength(gait: Gait) -> float:
    """Modules per wave now, positive (the direction the wave travels is kept by :func:`apply`): from the first two
    modules running the first module's automaton; inf when they are in phase."""
    group = [m for m in gait.modules if m.automaton == gait.modules[0].automaton]
    if len(group) < 2:
        return math.inf
    step = (group[1].phase - group[0].phase + 0.5) % 1.0 - 0.5
    return abs((group[1].id - group[0].id) / step) if step else math.inf


def _rank(free: Free) -> tuple[int, int]:
    """The order free parameters are applied in: the period, then the whole gait's amplitude before one
    automaton's (which then rescales that automaton alone), then the rest — whatever order they were given in."""
    named = bool((m := _AMPLITUDE.match(free.name)) and m.group(1))
    return _ORDER[free.kind], int(named)


def apply(document: dict[str, Any], frees: list[Free], values: list[float]) -> dict[str, Any]:
    """A copy of a gait document (gaits.model.to_dict) with the free parameters set to ``values`` (rounded)."""
    doc = copy.deepcopy(document)
    automata: dict[str, Any] = doc["automata"]
    for free, raw in sorted(zip(frees, values, strict=True), key=lambda fv: _rank(fv[0])):
        value = free.rounded(raw)
        if m := _STATE.match(free.name):
            automata[m.group(1)]["states"][int(m.group(2))][m.group(3)] = value
        elif m := _PHASE.match(free.name):
            doc["modules"][int(m.group(1))]["phase"] = round(value % 1.0, 6) % 1.0
        elif m := _AMPLITUDE.match(free.name):
            for name in [m.group(1)] if m.group(1) else list(automata):
                states = automata[name]["states"]
                peak = max(abs(s["angle"]) for s in states)
                for s in states:
                    s["angle"] = round(s["angle"] * value / peak, 3) if peak else s["angle"]
        elif free.kind == "period":
            for auto in automata.values():
                durations = [s.get("duration") for s in auto["states"]]
                if (
                    auto.get("one_shot")
                    or any(d is None for d in durations)
                    or any("until" in s for s in auto["states"])
                ):
                    continue  # not periodic: no period to set
                scale = value / math.fsum(d for d in durations if d is not None)
                for s in auto["states"]:
                    s["duration"] = s["duration"] * scale
        else:
            _set_wavelength(doc["modules"], value)
    return doc


def _set_wavelength(modules: list[dict[str, Any]], wavelength: float) -> None:
    """Phase = first phase + sign · (ID − first ID) / wavelength, per group of modules running one automaton; the
    sign is the direction the wave travels now (the generator's waves step the phase down); a negative wavelength
    reverses it."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for m in sorted(modules, key=lambda m: m["id"]):
        groups.setdefault(m["automaton"], []).append(m)
    for group in groups.values():
        if len(group) < 2:
            continue
        first = group[0]
        step = (group[1]["phase"] - first["phase"] + 0.5) % 1.0 - 0.5
        sign = 1.0 if step > 0 else -1.0
        for m in group[1:]:
            m["phase"] = round((first["phase"] + sign * (m["id"] - first["id"]) / wavelength) % 1.0, 6) % 1.0
