"""Module types by name (issue 30 part 1): a robot of several module types, in the gait's ``[robot]`` or a robot file
it names, each module simulated by its own type's mass, size, inertia and servo; the library's robots build exactly
the model they built before types existed. A simulated module reports its type (``module.type``, part 2)."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from asm_module.calibration import TYPE_NAME
from asm_py import Node
from asm_py.transport.can import CanTransport
from gaits.mjcf import Physics, build_mjcf
from gaits.model import LIBRARY, ModuleType, Robot, dumps, from_dict, load, loads, to_dict
from gaits.roundtrip import annotated
from gaits.sim import Metrics, Simulation
from gaits.terrain import parse
from gaits.tune import Setup, default_max_torque, evaluate
from gaits.validate import SCHEMA
from tests.helpers import wait_until
from tests.transports import FAST_BEATS, fresh_name

pytestmark = pytest.mark.timeout(120)
CATERPILLAR = (LIBRARY / "caterpillar.toml").read_text(encoding="utf-8")
HEAVY_MIDDLE = """
type = "light"
[robot.types.light]
mass = 0.2
[robot.types.heavy]
mass = 0.6
width = 0.07
height = 0.06
stall_torque = 3.0
ids = [4, 5]
"""
"""The caterpillar's modules 4 and 5 heavier, wider and stronger: a robot of two types."""


def caterpillar(description: str) -> str:
    """The library caterpillar with ``description`` (TOML lines of its [robot] table and below) after module_size."""
    return CATERPILLAR.replace("module_size = 0.05\n", "module_size = 0.05\n" + description.lstrip("\n"), 1)


def _run(text: str, seconds: float = 5.0) -> Metrics:
    with Simulation(loads(text)) as sim:
        return sim.run(seconds, warmup=1.0)


# -- the library builds what it built -------------------------------------------------------------------------------


def test_every_robot_described_as_before_builds_the_mjcf_it_built_before_types() -> None:
    golden = json.loads((Path(__file__).parent / "mjcf_before_types.json").read_text())["mjcf_sha256"]
    built = {}
    for path in sorted(LIBRARY.glob("*.toml")) + sorted((LIBRARY.parent / "tuned").glob("*.toml")):
        gait = load(path)
        for spec in ("flat", "slope:5"):
            physics = Physics(friction=gait.ground.friction, anisotropic=gait.ground.anisotropic)
            built[f"{path.parent.name}/{path.name} {spec}"] = build_mjcf(gait.robot, physics, name=gait.name,
                                                                          terrain=parse(spec))  # fmt: skip
    robots = {
        "chain 40 alternating": Robot(modules=40, axes="alternating"),
        "chain 1": Robot(modules=1),
        "chain 7 yaw 0.08x0.04x0.03 heavy": Robot(
            modules=7,
            axes="yaw",
            module_size=0.08,
            module=ModuleType(length=0.08, width=0.04, height=0.03, mass=0.6, range=120.0),
        ),
        "loop 6": Robot(shape="loop", modules=6),
        "legged 3 legs of 3": Robot(shape="legged", modules=9, legs=3),
        "legged 6 legs of 2": Robot(shape="legged", modules=12, legs=6, module=ModuleType(width=0.03, mass=0.3)),
    }
    for key, robot in robots.items():
        built[key] = build_mjcf(robot)
        built[key + " capsules"] = build_mjcf(robot, Physics(capsules=True))
    assert set(built) == set(golden)
    for key, text in built.items():
        assert hashlib.sha256(text.encode()).hexdigest() == golden[key], key


def test_one_named_type_for_every_module_is_the_unnamed_description() -> None:
    fields = "mass = 0.35\nstall_torque = 1.2\nno_load_speed = 330.0\ndeadband = 1.0\n"
    named = loads(caterpillar(f'type = "hobby"\n[robot.types.hobby]\n{fields}'))
    unnamed = loads(caterpillar(f"[robot.module]\n{fields}"))
    assert named.robot.type_name(3) == "hobby" and unnamed.robot.type_name(3) == ""
    assert named.robot.module_type(8) == unnamed.robot.module_type(8) == unnamed.robot.module
    assert build_mjcf(named.robot) == build_mjcf(unnamed.robot) == build_mjcf(load(LIBRARY / "caterpillar_heavy.toml")
                                                                              .robot)  # fmt: skip


# -- each module its own type ---------------------------------------------------------------------------------------


def test_each_module_gets_its_own_types_body_and_servo() -> None:
    gait = loads(caterpillar(HEAVY_MIDDLE))
    robot = gait.robot
    assert [robot.type_name(k) for k in range(1, 9)] == ["light"] * 3 + ["heavy"] * 2 + ["light"] * 3
    assert robot.size_of(4) == (0.05, 0.07, 0.06) and robot.size_of(3) == (0.05, 0.05, 0.05)
    model = mujoco.MjModel.from_xml_string(build_mjcf(robot))
    assert float(model.body_mass.sum()) == pytest.approx(6 * 0.2 + 2 * 0.6)
    assert float(model.body("b4").mass[0]) == pytest.approx(0.6)  # the two heavy halves about hinge 4..5
    assert float(model.body("b3").mass[0]) == pytest.approx(0.1 + 0.3)  # a light half and a heavy one
    forces = {k: float(model.actuator(f"m{k}").forcerange[1]) for k in range(1, 9)}
    assert forces == {k: 3.0 if k in (4, 5) else 1.5 for k in range(1, 9)}
    assert model.geom("b3_2").size[1] == pytest.approx(0.035), "a body of two cross-sections has a box for each"


def test_a_robot_with_heavier_modules_in_the_middle_simulates_differently() -> None:
    uniform, mixed = _run(CATERPILLAR), _run(caterpillar(HEAVY_MIDDLE))
    ends = _run(caterpillar(HEAVY_MIDDLE.replace("ids = [4, 5]", "ids = [1, 8]")))  # the same modules, elsewhere
    assert uniform.body_lengths > 2.0  # the comparison means something: the gait crawls
    assert mixed.mass == pytest.approx(uniform.mass + 2 * 0.4) == ends.mass
    assert mixed.distance != uniform.distance
    assert mixed.energy > 1.05 * uniform.energy and mixed.peak_torque > 1.1 * uniform.peak_torque
    assert ends.energy > 1.05 * mixed.energy, "where the heavy modules are matters, not only how many"
    assert ends.peak_torque == pytest.approx(1.5) and ends.peak_load == pytest.approx(1.0), (
        "their light neighbours' servos saturate at their own stall torque"
    )


def test_each_servo_is_its_modules_own() -> None:
    """Module 4's servo is weak and module 2's slow: each limits only its own joint."""
    text = caterpillar('[robot.types.weak]\nstall_torque = 0.3\nids = [4]\n[robot.types.slow]\nno_load_speed = 60.0\n'
                       "ids = [2]\n")  # fmt: skip
    with Simulation(loads(text)) as sim:
        sim.start()
        torque, errors = np.zeros(8), []
        for _ in range(200):  # 4 s of 50 Hz ticks
            sim.step_tick()
            torque = np.maximum(torque, np.abs(sim.data.actuator_force))
            errors.append([sim.goal(m) - sim.angle(m) for m in range(1, 9)])
    lag = np.sqrt(np.mean(np.square(errors), axis=0))  # RMS of goal − angle per module, degrees
    assert torque[3] <= 0.3 + 1e-9 and max(torque[k] for k in (2, 4)) > 0.5
    assert lag[1] > 2 * max(lag[k] for k in (0, 2, 5, 6)), lag


def test_a_given_inertia_is_the_modules_and_a_box_is_the_default() -> None:
    box = loads(caterpillar("[robot.types.heavy]\nmass = 0.6\nids = [4, 5]\n")).robot
    heavy = loads(caterpillar("[robot.types.heavy]\nmass = 0.6\ninertia = [0.0004, 0.0005, 0.0005]\nids = [4, 5]\n"))
    model = mujoco.MjModel.from_xml_string(build_mjcf(heavy.robot))
    assert model.body("b4").inertia == pytest.approx([0.0004, 0.0005, 0.0005])  # two halves give the module back
    assert mujoco.MjModel.from_xml_string(build_mjcf(box)).body("b4").inertia == pytest.approx(
        [0.6 * (0.05**2 + 0.05**2) / 12] * 3)  # fmt: skip
    assert _run(
        caterpillar("[robot.types.heavy]\nmass = 0.6\ninertia = [0.0004, 0.0005, 0.0005]\nids = [4, 5]\n"), seconds=2.0
    ) != _run(caterpillar("[robot.types.heavy]\nmass = 0.6\nids = [4, 5]\n"), seconds=2.0)


def test_legged_and_looped_robots_take_types_too() -> None:
    legged = (LIBRARY / "legged_walk.toml").read_text(encoding="utf-8")
    robot = loads(legged.replace("[limits]", "[robot.types.hip]\nmass = 0.5\nlength = 0.07\nids = [1]\n\n[limits]",
                                 1)).robot  # fmt: skip
    model = mujoco.MjModel.from_xml_string(build_mjcf(robot))
    assert float(model.body("leg0").mass[0]) == pytest.approx(0.25) and model.body("b2").pos[0] == pytest.approx(0.06)
    loop = (LIBRARY / "rolling_loop.toml").read_text(encoding="utf-8")
    heavy = loads(loop.replace("[limits]", "[robot.types.heavy]\nmass = 0.5\nids = [1, 2]\n\n[limits]", 1))
    assert float(mujoco.MjModel.from_xml_string(build_mjcf(heavy.robot)).body_mass.sum()) == pytest.approx(
        heavy.robot.modules * 0.2 + 2 * 0.3)  # fmt: skip


def test_the_tuner_holds_each_module_to_its_own_servo() -> None:
    assert default_max_torque(loads(CATERPILLAR)) == 1.425  # one servo: its N·m, as before
    weak = caterpillar("[robot.types.weak]\nstall_torque = 0.3\nids = [4]\n")
    assert default_max_torque(loads(weak)) is None
    outcome = evaluate(to_dict(loads(weak), inline=True), Setup(seconds=1.0, warmup=0.5))
    assert "of a module's stall torque > 95%" in outcome.problem  # the weak servo saturates
    strong = caterpillar("[robot.types.strong]\nstall_torque = 3.0\nids = [4]\n")
    assert evaluate(to_dict(loads(strong), inline=True), Setup(seconds=1.0, warmup=0.5)).feasible


# -- the file -------------------------------------------------------------------------------------------------------


def test_types_round_trip() -> None:
    gait = loads(caterpillar(HEAVY_MIDDLE + "inertia = [0.0004, 0.0005, 0.0005]\n"))
    assert from_dict(to_dict(gait)) == gait and loads(dumps(gait)) == gait
    assert to_dict(gait)["robot"]["types"]["heavy"]["ids"] == [4, 5]
    plain = annotated(to_dict(gait))  # a gait without a file: each named type's units in comments, as the module's
    assert "mass = 0.6  # kg" in plain and "stall_torque = 3.0  # N·m" in plain
    assert loads(plain) == gait


def _robot_file(folder: Path, description: str, gait_line: str = 'file = "robot.toml"') -> Path:
    (folder / "robot.toml").write_text("# the modules of my robot\n[robot]\n" + description.lstrip("\n"),
                                       encoding="utf-8")  # fmt: skip
    path = folder / "gait.toml"
    path.write_text(caterpillar(gait_line + "\n"), encoding="utf-8")
    return path


def test_a_robot_file_beside_the_gait_describes_its_modules(tmp_path: Path) -> None:
    gait = load(_robot_file(tmp_path, HEAVY_MIDDLE))
    inline = loads(caterpillar(HEAVY_MIDDLE))
    assert gait.robot.file == "robot.toml" and gait.robot.types == inline.robot.types
    assert build_mjcf(gait.robot) == build_mjcf(inline.robot)
    assert to_dict(gait)["robot"]["file"] == "robot.toml" and "types" not in to_dict(gait)["robot"]
    assert from_dict(to_dict(gait), path=tmp_path / "gait.toml") == gait
    standalone = loads(dumps(gait, inline=True))  # what a tuner's worker or the studio's robot process reads
    assert standalone.robot.file is None and build_mjcf(standalone.robot) == build_mjcf(gait.robot)
    (tmp_path / "robots").mkdir()
    (tmp_path / "robots" / "r.toml").write_text("[robot.module]\nmass = 0.3\n", encoding="utf-8")
    below = tmp_path / "below.toml"
    below.write_text(caterpillar('file = "robots/r.toml"\n'), encoding="utf-8")
    assert load(below).robot.module.mass == 0.3


def test_the_editor_keeps_the_robot_file_and_validates_against_it(tmp_path: Path) -> None:
    from web.document import GaitDocument

    path = _robot_file(tmp_path, HEAVY_MIDDLE)
    doc = GaitDocument(load(path), text=path.read_text(encoding="utf-8"), path=path)
    doc.set_robot("modules", 6)
    assert doc.gait().robot.type_name(5) == "heavy" and 'file = "robot.toml"' in doc.text()
    assert "[robot.types.heavy]" in doc.text(inline=True)
    doc.set_robot("modules", 4)  # module 5 is gone, the robot file still lists it
    assert [p.path for p in doc.problems] == ["robot.types.heavy.ids[1]"]
    doc.undo()
    assert not doc.problems


def test_the_editor_resizes_a_named_default_type_with_its_length() -> None:
    from web.document import GaitDocument

    text = CATERPILLAR.replace("module_size = 0.05\n", 'type = "long"\n[robot.types.long]\nlength = 0.05\n', 1)
    doc = GaitDocument(loads(text), text=text)
    doc.set_robot("module_size", 0.07)
    assert not doc.problems and doc.gait().robot.module.length == 0.07 == doc.gait().robot.module_size


def test_a_gait_read_without_its_folder_cannot_name_a_robot_file() -> None:
    with pytest.raises(Exception, match=r"robot\.file: this gait has no folder to find 'robot\.toml'"):
        loads(caterpillar('file = "robot.toml"\n'))


@pytest.mark.parametrize(
    ("name", "words"),
    [
        ("missing.toml", "no such file beside the gait file"),
        ("/etc/hostname", "must be a path relative to the gait file's folder"),
        ("../outside.toml", "lies outside the gait file's folder"),
        ("link.toml", "lies outside the gait file's folder"),  # a symbolic link out of the folder
        ("gait.toml", "names the gait file itself"),
        ("same.toml", "names the gait file itself"),  # a hard link to it
        ("folder", "is not a regular file"),
        ("fifo", "is not a regular file"),  # never opened: reading it would wait for ever
        ("nowhere/../gait.toml", "a folder on its path does not exist"),  # (it said "not a regular file")
        ("bad\0name", "cannot be read"),
    ],
)
def test_a_hostile_robot_file_name_is_refused_at_robot_file(tmp_path: Path, name: str, words: str) -> None:
    import os

    inner = tmp_path / "gaits"
    inner.mkdir()
    (tmp_path / "outside.toml").write_text("[robot.module]\nmass = 0.3\n", encoding="utf-8")
    (inner / "link.toml").symlink_to(tmp_path / "outside.toml")
    (inner / "folder").mkdir()
    os.mkfifo(inner / "fifo")
    path = inner / "gait.toml"
    path.write_text(caterpillar(f"file = {json.dumps(name)}\n"), encoding="utf-8")
    os.link(path, inner / "same.toml")
    with pytest.raises(Exception, match=r"robot\.file: ") as caught:
        load(path)
    assert words in str(caught.value) and type(caught.value).__name__ == "GaitError"


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b"[robot.module]\nmass = 0.3\n\xff\xfe\n", "not UTF-8 text: byte 0xff"),
        (b"x" * (2 * 1024 * 1024 + 10), "larger than 2 MiB"),
        (b"[robot.module\n", "not valid TOML"),
        (b'[robot]\nfile = "gait.toml"\n', "a robot file cannot name another robot file"),
        (b'[robot]\nshape = "loop"\n', "robot.shape: unknown field"),
        (b"[robot.module]\nmass = nan\n", "robot.module.mass: must be a finite number"),
        (b"[robot.types.big]\nmass = 1e300\nids = [1]\n", "robot.types.big.mass: must be in [0.001, 1000] kg"),
        (b"name = 3\n[robot]\n", "name: unknown field"),
        (b"description = 'robot'\n", "robot: missing"),
        (b"[robot.types.x]\nids = [9]\n", "robot.types.x.ids[0]: must be a module ID 1..8 (the gait's robot.modules)"),
    ],
)
def test_a_hostile_robot_file_is_refused_naming_that_file_and_field(tmp_path: Path, content: bytes,
                                                                    words: str) -> None:  # fmt: skip
    path = tmp_path / "gait.toml"
    path.write_text(caterpillar('file = "robot.toml"\n'), encoding="utf-8")
    (tmp_path / "robot.toml").write_bytes(content)
    with pytest.raises(Exception) as caught:
        load(path)
    assert type(caught.value).__name__ == "GaitError"
    assert str(caught.value).startswith(str(tmp_path / "robot.toml")) and words in str(caught.value), caught.value


@pytest.mark.parametrize(
    ("description", "path", "words"),
    [
        ('type = "nope"\n[robot.types.a]\nids = [1]\n', "robot.type", "unknown module type 'nope' (described: a)"),
        ('type = "a"\n[robot.types.a]\n[robot.module]\nmass = 0.3\n', "robot.type", "not both"),
        (
            "[robot.types.a]\nids = [1, 2]\n[robot.types.b]\nids = [2]\n",
            "robot.types.b.ids[0]",
            "module 2 is already of a type (robot.types.a.ids[1])",
        ),
        ("[robot.types.a]\nids = [3, 3]\n", "robot.types.a.ids[1]", "module 3 is already of a type"),
        ("[robot.types.a]\nids = [9]\n", "robot.types.a.ids[0]", "must be a module ID 1..8"),
        ("[robot.types.a]\nids = [0]\n", "robot.types.a.ids[0]", "must be in [1, 254]"),
        ("[robot.types.a]\nids = [1.5]\n", "robot.types.a.ids[0]", "must be an integer"),
        ("[robot.types.a]\nmass = 0.3\n", "robot.types.a", "no module is of this type"),
        ('[robot.types.a]\nmass = "heavy"\nids = [1]\n', "robot.types.a.mass", "must be a number, not 'heavy'"),
        ("[robot.types.a]\nstall_torque = 1e9\nids = [1]\n", "robot.types.a.stall_torque", "must be in [0.001, 10000]"),
        (
            "[robot.types.a]\nstall_torque = 1e-300\nids = [1]\n",
            "robot.types.a.stall_torque",
            "must be in [0.001, 10000]",
        ),
        ("[robot.types.a]\ntorque = 1.0\nids = [1]\n", "robot.types.a.torque", "unknown field"),
        ("[robot.module]\nids = [1]\n", "robot.module.ids", "unknown field"),
        ('[robot.types."a b"]\nids = [1]\n', "robot.types.a b", "a module type's name: 1 to 32 letters"),
        (f"[robot.types.{'x' * 33}]\nids = [1]\n", "robot.types." + "x" * 33, "1 to 32 characters long, not 33"),
        ("".join(f"[robot.types.t{k}]\nids = [1]\n" for k in range(33)), "robot.types", "must have 0 to 32 entries"),
        ("[robot.types.a]\ninertia = [0.001, 0.001]\nids = [1]\n", "robot.types.a.inertia", "must have 3 items, not 2"),
        (
            "[robot.types.a]\ninertia = [0.001, 0.001, -1.0]\nids = [1]\n",
            "robot.types.a.inertia[2]",
            "must be in [1e-09, 1000] kg·m²",
        ),
        (
            "[robot.types.a]\ninertia = [0.001, 0.0001, 0.0001]\nids = [1]\n",
            "robot.types.a.inertia",
            "is no body's: each moment must be at most the sum of the other two",
        ),
        (
            "[robot.types.a]\ninertia = [0.0001, 0.00002, 0.0001]\nids = [1]\n",
            "robot.types.a.inertia",
            "across and up must exceed m·L²/16 = 3.125e-05 kg·m²",
        ),
        ("[robot.types.a]\nrange = 45.0\nids = [1]\n", "limits", "exceeds the joint range of module type a ±45.0°"),
        ('type = "a"\n[robot.types.a]\nlength = 0.06\n', "robot.types.a.length", "differs from robot.module_size"),
        ('file = "r.toml"\n[robot.module]\nmass = 0.3\n', "robot.module", "describe them there only"),
    ],
)
def test_hostile_descriptions_are_refused_naming_the_field(description: str, path: str, words: str) -> None:
    with pytest.raises(Exception) as caught:
        loads(caterpillar(description))
    assert type(caught.value).__name__ == "GaitError"
    assert f"{path}: " in str(caught.value) and words in str(caught.value), caught.value


def test_a_type_name_with_an_escape_is_shown_as_written_at_its_own_line() -> None:
    """A NUL in a quoted key (TOML's \\u0000) was printed raw in the field path, at line 1 (the line index did not
    read the key's escapes)."""
    text = caterpillar('[robot.types."a\\u0000b"]\nids = [1]\n')
    header = text.splitlines().index('[robot.types."a\\u0000b"]') + 1
    with pytest.raises(Exception) as caught:
        loads(text)
    (problem,) = caught.value.problems  # type: ignore[attr-defined]
    assert problem.path == 'robot.types."a\\u0000b"' and problem.line == header and "\x00" not in str(caught.value)


def test_a_loops_modules_share_one_length() -> None:
    loop = (LIBRARY / "rolling_loop.toml").read_text(encoding="utf-8")
    with pytest.raises(Exception, match=r"robot\.types: a loop's modules must share one length"):
        loads(loop.replace("[limits]", "[robot.types.long]\nlength = 0.08\nids = [1]\n\n[limits]", 1))


def test_a_named_default_types_length_sizes_the_robot() -> None:
    gait = loads(CATERPILLAR.replace("module_size = 0.05\n", 'type = "long"\n[robot.types.long]\nlength = 0.08\n', 1))
    assert gait.robot.module_size == 0.08 and gait.robot.length == pytest.approx(8 * 0.08)
    assert math.isclose(loads(caterpillar("[robot.types.long]\nlength = 0.08\nids = [1]\n")).robot.length, 0.43)


# -- module.type ----------------------------------------------------------------------------------------------------


def test_the_gait_schema_and_the_module_runtime_agree_on_a_name() -> None:
    """Stated twice (gaits/schema.json for a file, asm_module for a module): the same rule."""
    schema = SCHEMA["$defs"]["type_name"]
    assert schema["pattern"] == "^" + TYPE_NAME.pattern.replace("{0,31}", "*") + "$" and schema["maxLength"] == 32


def test_a_simulated_robots_modules_report_their_gaits_types() -> None:
    """asm-robot --sim: each module, Python or C, reports the type its gait's description gives it."""
    text = (LIBRARY / "caterpillar.toml").read_text(encoding="utf-8").replace(
        "module_size = 0.05\n", 'module_size = 0.05\ntype = "light"\n[robot.types.light]\n[robot.types.heavy]\n'
        "mass = 0.6\nids = [2, 5]\n", 1)  # fmt: skip
    channel = fresh_name("sim-types")
    bus = {"interface": "virtual", "channel": channel}
    # FAST_BEATS: a peer counts as lost after 2 s of silence, not the default's fraction of a second (a fresh
    # clone's run on a loaded machine saw fewer than 8 modules for 20 s)
    tool = Node("tool", CanTransport(100, **FAST_BEATS, **bus))
    beats = {**FAST_BEATS, **bus}
    sim = Simulation(loads(text), node_of=lambda i: Node(f"m{i}", CanTransport(i, **beats)), c_modules=[4, 5],
                     bus_options=bus)  # fmt: skip
    try:
        assert wait_until(lambda: len(tool.discover()) >= 8, timeout=20)
        reported = {k: tool.lookup(f"m{k}", "module.type", timeout=5).get(timeout=5) for k in range(1, 9)}
        assert reported == {k: "heavy" if k in (2, 5) else "light" for k in range(1, 9)}  # m4, m5: the C runtime
    finally:
        sim.close()
        tool.close()


def test_a_nan_is_said_with_the_other_problems_at_once() -> None:
    """A second review: with mass = nan and kp = inf only kp was said; the nan came out once kp was fixed (a nan
    passes the schema's ranges, and the finite check ran only when the schema had nothing to say)."""
    with pytest.raises(Exception) as caught:
        loads(caterpillar("[robot.module]\nmass = nan\nkp = inf\n"))
    paths = [problem.path for problem in caught.value.problems]  # type: ignore[attr-defined]
    assert paths == ["robot.module.mass", "robot.module.kp"], caught.value
