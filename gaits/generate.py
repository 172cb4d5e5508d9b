"""Gaits made from a few numbers: the classic families of modular-snake locomotion as phase automata.

A gait author rarely wants to type sixteen angles per automaton and a phase per module: a travelling wave is an
amplitude, a wavelength (in modules) and a period. :func:`generate` turns a :class:`WaveSpec` into a complete gait
(robot, automata, phases) in one step, using the same sampling as the library files (gaits.serpenoid), so what it
makes is an ordinary gait file that can then be edited state by state.

- ``travelling_wave``: one sine automaton on every module, module n delayed by n / wavelength of a cycle (the
  caterpillar with pitch joints, lateral undulation with yaw joints).
- ``rolling_loop``: a closed loop with the wave travelling around it (two lobes by default: wavelength = n / 2).
- ``sidewinding``: two waves on alternating pitch/yaw joints, the yaw wave leading the pitch wave by a quarter
  period (Tesch et al. 2009): the body moves sideways.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from asm_module.program import MIN_DURATION, MIN_DURATION_TEXT
from asm_module.wire import MAX_STATES

from .model import MAX_MODULES, Gait, Robot
from .serpenoid import sine, wave_gait

FAMILIES = ("travelling_wave", "rolling_loop", "sidewinding")


@dataclass(frozen=True)
class WaveSpec:
    """What a generated gait is made from; every field is checked by :func:`generate`."""

    family: str = "travelling_wave"
    """One of FAMILIES."""
    modules: int = 12
    """Modules in the chain or loop."""
    amplitude: float = 45.0
    """Degrees, the main wave's amplitude (the yaw wave when sidewinding)."""
    wavelength: float = 6.0
    """Modules per wave; the phase step between neighbours is 1 / wavelength of a cycle (negative: the wave
    travels the other way). A rolling loop needs a whole number of waves around it."""
    period: float = 1.0
    """Seconds per cycle."""
    states: int = 16
    """States per automaton: the wave sampled this many times per period."""
    axes: str = "pitch"
    """Joint axes of a travelling wave: pitch (caterpillar), yaw (lateral undulation) or alternating."""
    offset: float = 0.0
    """Degrees added to every angle (a curved body)."""
    pitch_amplitude: float = 10.0
    """Sidewinding: the pitch wave's amplitude, degrees."""
    limit: float = 90.0
    """The joints' limit, degrees (the gait's [limits] are ±limit)."""


def generate(spec: WaveSpec, *, name: str | None = None) -> Gait:
    """The gait ``spec`` describes; ValueError (saying which number) if it cannot be made."""
    _check(spec)
    step = 1.0 / spec.wavelength
    peak = abs(spec.offset) + max(abs(spec.amplitude), abs(spec.pitch_amplitude) if spec.family == "sidewinding" else 0)
    if peak > spec.limit:
        raise ValueError(f"offset + amplitude reach {peak:g}°, beyond the ±{spec.limit:g}° joint limits")
    if spec.family == "travelling_wave":
        robot = Robot("chain", spec.modules, spec.axes)
        roles = {"wave": (sine(spec.amplitude, spec.offset), 0.0)}
        role_of, offset_of = (lambda n: "wave"), (lambda n: -n * step)
        what = f"A travelling wave on {spec.axes} joints"
    elif spec.family == "rolling_loop":
        waves = spec.modules / spec.wavelength
        if abs(waves - round(waves)) > 1e-6 or round(waves) == 0:
            raise ValueError(f"a loop of {spec.modules} modules needs a whole number of waves around it: "
                             f"wavelength {spec.wavelength:g} gives {waves:g}")  # fmt: skip
        robot = Robot("loop", spec.modules, "pitch")
        roles = {"wave": (sine(spec.amplitude, spec.offset), 0.0)}
        role_of, offset_of = (lambda n: "wave"), (lambda n: -n * step)
        what = f"A loop rolling like a tank tread, {round(waves)} wave(s) around it"
    else:
        robot = Robot("chain", spec.modules, "alternating")
        roles = {
            "pitch": (sine(spec.pitch_amplitude, spec.offset), 0.0),
            "yaw": (sine(spec.amplitude, spec.offset), 0.25),
        }
        role_of, offset_of = (lambda n: "pitch" if n % 2 == 0 else "yaw"), (lambda n: -n * step)
        what = f"Sidewinding: yaw {spec.amplitude:g}°, pitch {spec.pitch_amplitude:g}°, yaw leading by a quarter period"
    description = (f"{what} (A {spec.amplitude:g}°, wavelength {spec.wavelength:g} modules, period {spec.period:g} s, "
                   f"{spec.states} states). Made by the studio's generator.")  # fmt: skip
    gait = wave_gait(name or spec.family, description, robot, roles, period=spec.period, role_of=role_of,
                     offset_of=offset_of, samples=spec.states)  # fmt: skip
    gait.limits = (-spec.limit, spec.limit)
    return gait


def _check(spec: WaveSpec) -> None:
    def number(value: float, what: str, low: float, high: float, *, open_low: bool = False) -> None:
        if (
            not (isinstance(value, int | float) and math.isfinite(value))
            or value > high
            or (value <= low if open_low else value < low)
        ):
            bound = f"({low:g}" if open_low else f"[{low:g}"
            raise ValueError(f"{what} must be in {bound}, {high:g}], not {value!r}")

    if spec.family not in FAMILIES:
        raise ValueError(f"family must be one of {', '.join(FAMILIES)}, not {spec.family!r}")
    low = 4 if spec.family == "rolling_loop" else 2
    if not isinstance(spec.modules, int) or not low <= spec.modules <= MAX_MODULES:
        raise ValueError(f"a {spec.family} needs {low} to {MAX_MODULES} modules, not {spec.modules!r}")
    if not isinstance(spec.states, int) or not 2 <= spec.states <= MAX_STATES:
        raise ValueError(f"states per period must be 2 to {MAX_STATES}, not {spec.states!r}")
    if spec.axes not in ("pitch", "yaw", "alternating"):
        raise ValueError(f"axes must be pitch, yaw or alternating, not {spec.axes!r}")
    number(spec.limit, "the joint limit", 0, 180, open_low=True)
    number(spec.amplitude, "the amplitude", -spec.limit, spec.limit)
    number(spec.pitch_amplitude, "the pitch amplitude", -spec.limit, spec.limit)
    number(spec.offset, "the offset", -spec.limit, spec.limit)
    number(spec.period, "the period", 0, 60, open_low=True)
    if spec.period / spec.states < MIN_DURATION:
        raise ValueError(f"{spec.states} states per period of {spec.period:g} s last {spec.period / spec.states:.4g} s "
                         f"each: a state lasts at least one control tick ({MIN_DURATION_TEXT}); use at most "
                         f"{int(spec.period / MIN_DURATION)} states or a longer period")  # fmt: skip
    number(abs(spec.wavelength), "the wavelength's size", 0.5, 10_000)
