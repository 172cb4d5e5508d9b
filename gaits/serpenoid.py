"""Gaits from the serpenoid family (Tesch, Choset et al. 2009) and friends, as phase automata: one automaton per
joint role, sampled into linear states, each module started at its phase delay φ_n = n·Δ/2π (mod 1).

This is how the library files in gaits/library/ were made (``python -m gaits.serpenoid`` rewrites them); the files
are the source of truth afterwards, and a user edits them, not this code.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

from .model import LIBRARY, Assignment, Automaton, Gait, Ground, Robot, State, dumps

SAMPLES = 16


def sampled(name: str, wave: Callable[[float], float], period: float, samples: int = SAMPLES) -> Automaton:
    """An automaton whose linear states follow ``wave(phase in [0, 1))`` (degrees)."""
    dt = period / samples
    return Automaton(name, [State(round(wave((k + 1) / samples), 3), dt, None, "linear") for k in range(samples)])


def sine(amplitude: float, offset: float = 0.0) -> Callable[[float], float]:
    return lambda p: offset + amplitude * math.sin(2 * math.pi * p)


def _phase(x: float) -> float:
    return round(x % 1.0, 6) % 1.0


Wave = Callable[[float], float]


def wave_gait(
    name: str,
    description: str,
    robot: Robot,
    roles: dict[str, tuple[Wave, float]],
    *,
    period: float = 1.0,
    role_of: Callable[[int], str],
    offset_of: Callable[[int], float],
    samples: int = SAMPLES,
) -> Gait:
    """A gait where module n (0-based) runs automaton ``role_of(n)`` with phase ``offset_of(n)`` (cycles)."""
    automata = {role: sampled(role, wave, period, samples) for role, (wave, _) in roles.items()}
    modules = [Assignment(n + 1, role_of(n), _phase(offset_of(n) + roles[role_of(n)][1]), 1)
               for n in range(robot.modules)]  # fmt: skip
    return Gait(name, robot, automata, modules, (-90.0, 90.0), description)


def library() -> dict[str, Gait]:
    chain8 = Robot("chain", 8, "pitch")
    chain12 = Robot("chain", 12, "alternating")
    gaits: dict[str, Gait] = {
        "caterpillar": wave_gait(
            "caterpillar",
            "A vertical travelling wave along a chain of pitch joints (A 50°, wavelength 7 modules).",
            chain8,
            {"wave": (sine(50.0), 0.0)},
            role_of=lambda n: "wave",
            offset_of=lambda n: -n / 7,
        ),
        "lateral_undulation": wave_gait(
            "lateral_undulation",
            "Snake-like lateral undulation: yaw joints swing (A 45°, wavelength 6 modules), "
            "pitch joints stay flat. Needs anisotropic friction to be efficient.",
            chain12,
            {"pitch": (sine(0.0), 0.0), "yaw": (sine(45.0), 0.0)},
            role_of=lambda n: "pitch" if n % 2 == 0 else "yaw",
            offset_of=lambda n: -(n // 2) / 6,
        ),
        "sidewinding": wave_gait(
            "sidewinding",
            "Sidewinding: yaw 60°, pitch 10°, one wave along the body, yaw leads pitch by a quarter period. "
            "It moves at an angle to its body; direction -1 moves it back the other way.",
            chain12,
            {"pitch": (sine(10.0), 0.0), "yaw": (sine(60.0), 0.25)},
            role_of=lambda n: "pitch" if n % 2 == 0 else "yaw",
            offset_of=lambda n: -n / 12,
        ),
        "rolling_loop": wave_gait(
            "rolling_loop",
            "A closed loop of 12 rolling like a tank tread: a two-lobe wave (A 45°) travels around it.",
            Robot("loop", 12, "pitch"),
            {"wave": (sine(45.0), 0.0)},
            role_of=lambda n: "wave",
            offset_of=lambda n: -2 * n / 12,
        ),
        "inchworm": wave_gait(
            "inchworm",
            "An inchworm: a single hump 6 joints wide (A 75°) travels along a chain of pitch joints.",
            chain8,
            {"hump": (lambda p: 75.0 * max(0.0, math.sin(2 * math.pi * p)) ** 2 - 0.0, 0.0)},
            role_of=lambda n: "hump",
            offset_of=lambda n: -n / 12,
        ),
        "legged_walk": wave_gait(
            "legged_walk",
            "A trot: a body with four legs of two modules (hip yaw 40°, knee pitch 30°); diagonal legs together. "
            "Legs are numbered counter-clockwise from the front left; a left hip swings back while a right one "
            "swings forward, and each knee lowers its foot while its hip pushes backwards.",
            Robot("legged", 8, "alternating", legs=4),
            {"hip": (sine(40.0), 0.0), "knee": (sine(30.0), 0.0)},
            role_of=lambda n: "hip" if n % 2 == 0 else "knee",
            # per leg (FL, BL, BR, FR): hip phase, knee phase; see the description
            offset_of=lambda n: ((0.25, 0.0), (0.75, 0.5), (0.75, 0.0), (0.25, 0.5))[n // 2][n % 2],
        ),
    }
    # Snake skin: slides along the body ten times more easily than across it (SIMULATION.md).
    gaits["lateral_undulation"].ground = Ground(1.0, (0.1, 1.0))
    return gaits


def write_library(directory: Path = LIBRARY) -> list[Path]:
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    from .coordinated import library as coordinated

    for name, gait in (library() | coordinated()).items():
        path = directory / f"{name}.toml"
        header = (
            f"# {gait.description}\n# Generated by `python -m gaits.serpenoid`; edit freely (see gaits/model.py).\n"
        )
        path.write_text(header + dumps(gait), encoding="utf-8")
        written.append(path)
    return written


if __name__ == "__main__":
    for written in write_library():
        print(written)
