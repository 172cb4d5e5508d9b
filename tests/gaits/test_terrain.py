"""Terrains: every kind builds and runs, the ground changes what a gait achieves (uphill is harder), a rough ground is
its seed's alone, and a bad spec is one clear error."""

from __future__ import annotations

import math

import mujoco
import pytest

from gaits.cli import main
from gaits.mjcf import Physics, build_mjcf
from gaits.model import LIBRARY, load
from gaits.sim import Simulation
from gaits.terrain import FLAT, parse

pytestmark = pytest.mark.timeout(120)
CATERPILLAR = LIBRARY / "caterpillar.toml"
SPECS = ["flat", "slope:5", "step:0.03", "rough:seed=3,roughness=0.02", "patches:friction=0.3"]


def _metrics(spec: str, seconds: float = 2.0):
    with Simulation(load(CATERPILLAR), terrain=parse(spec)) as sim:
        return sim.run(seconds, warmup=0.5)


@pytest.mark.parametrize("spec", SPECS)
def test_each_terrain_loads_and_runs(spec):
    terrain = parse(spec)
    assert parse(terrain.spec) == terrain  # the full spec reads back as the same terrain
    with Simulation(load(CATERPILLAR), terrain=terrain) as sim:
        model = sim.model
        grounds = [model.geom(name) for name in terrain.ground().names]
        metrics = sim.run(1.0, warmup=0.5)
        assert sim.touching, "the contact sensors see the terrain's ground"
    assert math.isfinite(metrics.distance) and metrics.distance > 0
    assert metrics.energy > 0 and 0 < metrics.cost_of_transport < math.inf
    assert not metrics.fell
    gravity = model.opt.gravity
    if terrain.kind == "slope":
        assert gravity[0] == pytest.approx(-9.81 * math.sin(math.radians(5)))
    else:
        assert tuple(gravity) == (0.0, 0.0, pytest.approx(-9.81))
    if terrain.kind == "rough":
        assert model.nhfield == 1 and grounds[0].type[0] == mujoco.mjtGeom.mjGEOM_HFIELD
        heights = model.hfield_data * model.hfield_size[0, 2]
        assert heights.max() == pytest.approx(0.02, abs=1e-4) and heights.min() == pytest.approx(0.0, abs=1e-4)
    if terrain.kind == "patches":
        frictions = {round(float(g.friction[0]), 3) for g in grounds[1:]}
        assert frictions == {0.3, 1.0}  # tiles of the patch's and of the ground's friction
    if terrain.kind == "step":
        assert len(grounds) == 5 and all(g.size[2] == pytest.approx(0.015) for g in grounds[1:])


def test_flat_terrain_is_the_model_it_always_was():
    """One plane at z = 0, MuJoCo's own gravity, no assets: the library's figures (bench/sim.py) still hold."""
    gait = load(CATERPILLAR)
    text = build_mjcf(gait.robot, Physics(), terrain=FLAT)
    model = mujoco.MjModel.from_xml_string(text)
    grounds = [g for g in range(model.ngeom) if model.geom_bodyid[g] == 0]
    assert len(grounds) == 1 and model.geom_type[grounds[0]] == mujoco.mjtGeom.mjGEOM_PLANE
    assert tuple(model.geom_pos[grounds[0]]) == (0.0, 0.0, 0.0)
    assert tuple(model.opt.gravity) == tuple(mujoco.MjModel.from_xml_string("<mujoco/>").opt.gravity)
    assert "<asset>" not in text and model.nhfield == 0


def test_uphill_goes_less_far_than_flat():
    flat, uphill = _metrics("flat"), _metrics("slope:10")
    assert uphill.along(0.0) < 0.9 * flat.along(0.0), (flat.summary(), uphill.summary())
    assert flat.along(0.0) > 0  # the caterpillar goes +x, so the slope (rising along +x) is uphill for it


def test_rough_ground_is_its_seeds():
    first, again, other = (_metrics(f"rough:seed={s},roughness=0.03") for s in (3, 3, 4))
    assert (first.displacement, first.peak_torque, first.energy) == (again.displacement, again.peak_torque,
                                                                      again.energy)  # fmt: skip
    assert first.displacement != other.displacement
    a, b = parse("rough:seed=3").elevations(), parse("rough:seed=4").elevations()
    assert (a == parse("rough:seed=3").elevations()).all() and not (a == b).all()


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ("slope:90", "angle must be in [-45, 45], not 90"),
        ("rough:seed=x", "seed must be an integer, not 'x'"),
        ("nonsense", "unknown kind 'nonsense'"),
        ("step:-1", "height must be in"),
        ("slope:nan", "angle must be in"),
        ("rough:seed=1,bumps=3", "rough has no parameter 'bumps'"),
        ("patches:0.3,0.5", "needs a name"),
        ("flat:1", "flat takes no parameters"),
        ("slope:", "nothing after the colon (e.g. slope:5)"),  # cut short: not the default slope in disguise
        ("slope:5,angle=6", "angle is given twice"),
        ("rough:seed=3,seed=4", "seed is given twice"),
        ("rough:cell=0.01,extent=20", "height-field cells"),
        ("patches:friction=0", "friction must be in [0.001, 5], not 0"),  # the robot diverged on μ 0 (a review)
    ],
)
def test_a_hostile_spec_is_one_clear_error(spec, says, capsys):
    with pytest.raises(ValueError, match=r"^terrain ") as caught:
        parse(spec)
    assert says in str(caught.value) and "\n" not in str(caught.value)
    with pytest.raises(SystemExit) as exited:
        main(["simulate", str(CATERPILLAR), "--terrain", spec])
    assert exited.value.code == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(errors) == 1 and says in errors[0]


def test_simulate_prints_metrics_per_terrain(capsys):
    assert main(["simulate", str(CATERPILLAR), "--seconds", "1", "--warmup", "0.5", "--terrain", "flat",
                 "--terrain", "slope:5"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert out.count("terrain      ") == 2 and "terrain      slope:angle=5,heading=0" in out
    assert out.count("cost of transport") == 2 and out.count("drift") == 2


def test_slippery_patches_slide_under_modules_of_a_higher_friction():
    """A tile's μ is what a module on it feels, below the modules' own as above it (MuJoCo takes the larger of two
    geoms' frictions unless one has priority: a user review found patches:friction=0.01 crawling as on flat)."""
    gait = load(LIBRARY / "caterpillar.toml")

    def distance(spec: str) -> float:
        with Simulation(gait, terrain=parse(spec)) as sim:
            return sim.run(2.0, warmup=1.0).distance

    grippy = distance("patches:friction=1.0,fraction=1")  # every tile of the ground's own μ
    assert distance("patches:friction=0.01,fraction=1") < 0.8 * grippy
    assert distance("patches:friction=0.3,fraction=1") != grippy


@pytest.mark.parametrize("ground", ["friction = 1e-12", "anisotropic = [1e-300, 1e-300]"])
def test_a_ground_too_slippery_to_simulate_is_refused(ground: str) -> None:
    """A second review: a [ground] μ of 1e-4 down to 5e-324 validated, and the robot diverged on flat ground."""
    from gaits.model import LIBRARY, GaitError, loads

    text = (LIBRARY / "caterpillar.toml").read_text(encoding="utf-8") + f"\n[ground]\n{ground}\n"
    with pytest.raises(GaitError, match=r"ground\.(friction|anisotropic\[0\]): must be in \[0\.001, 10\]"):
        loads(text)
