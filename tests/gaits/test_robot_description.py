"""The robot description (``[robot.module]``): one module's size, mass and servo, used by the model and the servo.

The default description is the module the simulator always had, so a file without the table simulates exactly as
before; each field then changes what a gait achieves the way the real module would."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from gaits.mjcf import Physics, build_mjcf
from gaits.model import LIBRARY, GaitError, ModuleType, Robot, from_dict, load, loads, to_dict
from gaits.roundtrip import annotated, save
from gaits.sim import Metrics, Simulation

pytestmark = pytest.mark.timeout(120)
CATERPILLAR = (LIBRARY / "caterpillar.toml").read_text(encoding="utf-8")
TODAY = {"length": 0.05, "width": 0.05, "height": 0.05, "mass": 0.2, "stall_torque": 1.5, "kp": 10.0,
         "damping": 0.1, "deadband": 0.0, "range": 90.0}  # fmt: skip
"""SIMULATION.md's module, every field written out."""


def _module_table(fields: dict[str, float]) -> str:
    return "\n[robot.module]\n" + "".join(f"{key} = {value!r}\n" for key, value in fields.items())


def caterpillar(**fields: float) -> str:
    """The library caterpillar with a ``[robot.module]`` table of ``fields``."""
    return CATERPILLAR.replace("module_size = 0.05\n", "module_size = 0.05\n" + _module_table(fields), 1)


def _run(text: str, seconds: float = 6.0, **options: object) -> Metrics:
    with Simulation(loads(text), **options) as sim:  # pyright: ignore[reportArgumentType]
        return sim.run(seconds, warmup=1.0)


def _same(a: Metrics, b: Metrics) -> bool:
    """Every metric equal, bit for bit (the wall-clock real-time factor aside)."""
    return (a.displacement, a.peak_torque, a.fell, a.energy, a.mass, a.turned) == (
        b.displacement, b.peak_torque, b.fell, b.energy, b.mass, b.turned)  # fmt: skip


@pytest.fixture(scope="module")
def default() -> Metrics:
    return _run(CATERPILLAR)


# -- the default is today's module ----------------------------------------------------------------------------------


def test_the_default_description_is_the_module_the_simulator_always_had() -> None:
    gait = loads(CATERPILLAR)
    assert gait.robot.module == ModuleType() and gait.robot.size == (0.05, 0.05, 0.05)
    assert gait.robot.ideal_servo and gait.robot.module_type(3) == ModuleType() and gait.robot.type_name(3) == ""
    spelled = loads(caterpillar(**TODAY))
    assert build_mjcf(spelled.robot) == build_mjcf(gait.robot) == build_mjcf(gait.robot, Physics())


def test_the_default_description_simulates_exactly_as_before(default: Metrics) -> None:
    before = _run(CATERPILLAR, physics=Physics())  # the world Simulation has always built (flat, μ 1)
    assert _same(default, before)
    assert _same(_run(caterpillar(**TODAY)), default)  # today's numbers written out: the same run
    assert default.body_lengths > 3.0  # a gait that works, so the comparisons below mean something


# -- each field changes the gait as the real module would -----------------------------------------------------------


def test_heavier_modules_go_less_far(default: Metrics) -> None:
    heavy = _run(caterpillar(mass=0.6))
    assert heavy.mass == pytest.approx(3 * default.mass)
    assert heavy.distance < 0.95 * default.distance


def test_a_weak_servo_is_slower_and_never_exceeds_its_stall_torque(default: Metrics) -> None:
    weak = _run(caterpillar(stall_torque=0.3))
    assert weak.peak_torque <= 0.3 + 1e-9 and default.peak_torque > 0.3  # the limit bit
    assert weak.distance < 0.6 * default.distance


def _lag(text: str) -> tuple[float, float]:
    """RMS of |goal − angle| over every module and tick (degrees), and the fastest joint speed seen (deg/s)."""
    with Simulation(loads(text), trace=True) as sim:
        sim.start()
        errors, fastest = [], 0.0
        for _ in range(200):  # 4 s of 50 Hz ticks
            sim.step_tick()
            errors += [sim.goal(m) - sim.angle(m) for m in sim.modules]
            fastest = max(fastest, float(np.abs(sim.data.qvel[6:]).max()))
        return math.sqrt(float(np.mean(np.square(errors)))), math.degrees(fastest)


def test_a_slow_servo_lags_its_goals() -> None:
    ideal, ideal_speed = _lag(CATERPILLAR)
    slow, slow_speed = _lag(caterpillar(no_load_speed=60.0))
    assert slow > 2 * ideal
    assert ideal_speed > 120.0 and slow_speed < 90.0  # about its no-load speed: faster, the motor brakes (back-EMF)


HOLD = """name = "hold"
[robot]
modules = 2
axes = "yaw"
{module}
[automata.hold]
states = [{{ angle = 20.0, duration = 1.0 }}]
[[modules]]
id = 1
automaton = "hold"
[[modules]]
id = 2
automaton = "hold"
"""
"""Two yaw modules lying on the floor, told to hold 20°: gravity does not load the joints."""


def _steady_error(module: str) -> list[float]:
    with Simulation(loads(HOLD.format(module=module))) as sim:
        sim.start()
        sim.advance(3.0)
        return [sim.goal(m) - sim.angle(m) for m in sim.modules]


def test_a_deadband_leaves_a_steady_error_within_the_band() -> None:
    ideal = _steady_error("")
    banded = _steady_error("[robot.module]\ndeadband = 5.0")
    assert all(abs(e) < 0.5 for e in ideal)
    assert all(abs(e) <= 5.0 + 0.5 for e in banded)  # the servo corrects down to the band's edge, then stops
    assert max(abs(e) for e in banded) > 2.0  # and leaves the rest uncorrected


# -- the file -------------------------------------------------------------------------------------------------------


def test_a_description_round_trips_and_keeps_the_files_comments() -> None:
    text = caterpillar(mass=0.3, no_load_speed=300.0, width=0.04).replace("mass = 0.3", "mass = 0.3  # with battery")
    gait = loads(text)
    assert gait.robot.module == ModuleType(width=0.04, mass=0.3, no_load_speed=300.0)
    assert gait.robot.size == (0.05, 0.04, 0.05)
    assert from_dict(to_dict(gait)) == gait
    assert save(to_dict(gait), text) == text  # unchanged: byte for byte, comment included
    gait.robot.module.stall_torque = 2.5
    saved = save(to_dict(gait), text)
    assert "mass = 0.3  # with battery" in saved and loads(saved).robot.module.stall_torque == 2.5
    plain = annotated(to_dict(gait))
    assert "mass = 0.3  # kg" in plain and "no_load_speed = 300.0  # degrees per second" in plain
    assert tomllib.loads(plain) == to_dict(gait)


def test_only_the_heavy_caterpillar_of_the_library_describes_its_module() -> None:
    for path in sorted(LIBRARY.glob("*.toml")):
        if path.stem != "caterpillar_heavy":
            assert load(path).robot.module == ModuleType() and "module" not in to_dict(load(path))["robot"], path.name
    heavy = load(LIBRARY / "caterpillar_heavy.toml")
    assert heavy.robot.module == ModuleType(mass=0.35, stall_torque=1.2, no_load_speed=330.0, deadband=1.0)
    assert heavy.automata == loads(CATERPILLAR).automata  # the same wave: only the module differs


def test_the_heavy_caterpillar_still_crawls_within_its_servo(default: Metrics) -> None:
    with Simulation(load(LIBRARY / "caterpillar_heavy.toml")) as sim:
        heavy = sim.run(6.0, warmup=1.0)
    assert heavy.body_lengths > 2.0 and heavy.distance < default.distance
    assert heavy.peak_torque <= 1.2 + 1e-9 and not heavy.fell


def test_a_length_sets_the_module_size_and_sizes_the_model() -> None:
    text = CATERPILLAR.replace("module_size = 0.05\n", "", 1).replace(
        "[limits]", "[robot.module]\nlength = 0.08\nheight = 0.03\n\n[limits]", 1
    )
    gait = loads(text)
    assert gait.robot.module_size == 0.08 and gait.robot.size == (0.08, 0.08, 0.03)
    assert 'size="0.04 0.04 0.015"' in build_mjcf(gait.robot)  # half extents of a module's box
    assert from_dict(to_dict(gait)) == gait


def test_the_servo_numbers_reach_the_actuators() -> None:
    robot = Robot(module=ModuleType(kp=4.0, damping=0.3, stall_torque=0.7, range=60.0, mass=0.5))
    mjcf = build_mjcf(robot)
    assert 'kp="4" kv="0.3"' in mjcf and 'forcerange="-0.7 0.7"' in mjcf
    assert f'ctrlrange="{-math.radians(60):.6g} {math.radians(60):.6g}"' in mjcf and 'mass="0.5"' in mjcf


@pytest.mark.parametrize(
    ("fields", "path", "words"),
    [
        ({"mass": -1.0}, "robot.module.mass", "must be in [0.001, 1000] kg, not -1.0"),
        ({"mass": 1e-12}, "robot.module.mass", "must be in [0.001, 1000] kg, not 1e-12"),  # MuJoCo's mjMINVAL
        ({"width": 1e-9}, "robot.module.width", "must be in [0.001, 10] metres, not 1e-09"),
        ({"mass": 0.0}, "robot.module.mass", "not 0.0"),
        ({"stall_torque": 0}, "robot.module.stall_torque", "must be in [0.001, 10000] N·m, not 0"),
        ({"no_load_speed": -5.0}, "robot.module.no_load_speed", "degrees per second"),
        ({"kp": -1.0}, "robot.module.kp", "must be in [0, 100000]"),
        ({"damping": -0.1}, "robot.module.damping", "must be in [0, 10000]"),
        ({"deadband": 11.0}, "robot.module.deadband", "must be in [0, 10] degrees, not 11.0"),
        ({"mass": 1e300}, "robot.module.mass", "not 1e+300"),
        ({"stall_torque": 1e9}, "robot.module.stall_torque", "not 1000000000.0"),
        ({"width": 100.0}, "robot.module.width", "must be in [0.001, 10] metres"),
        ({"range": 200.0}, "robot.module.range", "must be in (0, 180]"),
        ({"length": 0.06}, "robot.module.length", "differs from robot.module_size"),
        ({"range": 45.0}, "limits", "exceeds the module's joint range ±45.0°"),
    ],
)
def test_hostile_values_are_refused_naming_the_field(fields: dict[str, float], path: str, words: str) -> None:
    with pytest.raises(GaitError) as caught:
        loads(caterpillar(**fields))
    assert f"{path}: " in str(caught.value) and words in str(caught.value)


@pytest.mark.parametrize(
    ("table", "path", "words"),
    [
        ('kp = "stiff"', "robot.module.kp", "must be a number, not 'stiff'"),
        ("mass = nan", "robot.module.mass", "finite"),
        ("stall_torque = inf", "robot.module.stall_torque", "not inf"),
        ("mass = true", "robot.module.mass", "must be a number"),
        ("torque = 1.0", "robot.module.torque", "unknown field"),
    ],
)
def test_values_that_are_not_numbers_are_refused_naming_the_field(table: str, path: str, words: str) -> None:
    text = CATERPILLAR.replace("[limits]", f"[robot.module]\n{table}\n\n[limits]", 1)
    with pytest.raises(GaitError) as caught:
        loads(text)
    assert f"{path}: " in str(caught.value) and words in str(caught.value)


def test_a_module_that_is_not_a_table_is_refused() -> None:
    with pytest.raises(GaitError, match=r"robot\.module: must be a table"):
        loads(CATERPILLAR.replace("module_size = 0.05\n", "module_size = 0.05\nmodule = 3\n", 1))


def test_the_editor_resizes_a_described_module_with_its_length() -> None:
    from web.document import GaitDocument

    text = CATERPILLAR.replace("module_size = 0.05\n", "", 1).replace(
        "[limits]", "[robot.module]\nlength = 0.05\n\n[limits]"
    )
    doc = GaitDocument(loads(text), text=text)
    doc.set_robot("module_size", 0.07)
    gait = loads(doc.text())  # still valid: the length followed the size
    assert gait.robot.module_size == 0.07 and gait.robot.module.length == 0.07 and gait.robot.size[2] == 0.07


@pytest.mark.timeout(60)
def test_a_servo_too_stiff_for_the_timestep_is_a_divergence_not_a_run_without_end(tmp_path) -> None:
    """A second user review: stall torque 1000 N·m and kp 10000 (both within the schema) made MuJoCo reset an
    unstable state again and again; `gaits simulate` never ended and `gaits tune` printed nothing."""
    import subprocess
    import sys
    from pathlib import Path

    text = caterpillar(stall_torque=1000.0, kp=10000.0)
    with pytest.raises(FloatingPointError, match="diverged"):
        _run(text, seconds=1.0)
    path = tmp_path / "stiff.toml"
    path.write_text(text, encoding="utf-8")
    done = subprocess.run([sys.executable, "-m", "gaits.cli", "simulate", str(path), "--seconds", "1"],
                          capture_output=True, text=True, timeout=50,
                          cwd=Path(__file__).resolve().parents[2])  # fmt: skip
    assert done.returncode == 1 and "diverged" in done.stderr.splitlines()[-1], done.stderr
