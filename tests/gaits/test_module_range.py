"""A module type's ``range`` (its hinge, ± degrees) is what the simulated modules are (their hardware range), from
``gaits validate`` to ``gaits simulate``, ``gaits tune`` and ``asm-robot --sim``: a gait one of them accepts the others
run, and [limits] beyond a module's range — said or not (90°) — is refused by the loader, naming the field (issue
30's review, defect 2: ``range = 150`` validated and then failed in every simulation)."""

from __future__ import annotations

import pytest

from gaits.cli import main
from gaits.model import LIBRARY, GaitError, loads, to_dict
from gaits.sim import Simulation
from gaits.tune import Setup, evaluate
from tests.processes import Process

pytestmark = pytest.mark.timeout(180)
CATERPILLAR = (LIBRARY / "caterpillar.toml").read_text(encoding="utf-8")


def wide(description: str) -> str:
    """The caterpillar with [limits] of ±150° and a state at 130°, ``description`` in its [robot]."""
    text = CATERPILLAR.replace("min = -90.0\nmax = 90.0", "min = -150.0\nmax = 150.0", 1)
    text = text.replace("{ angle = 50.0,", "{ angle = 130.0,", 1)
    return text.replace("module_size = 0.05\n", "module_size = 0.05\n" + description, 1)


WIDE = {
    "robot.module": "[robot.module]\nrange = 150\n",
    "a named default type": 'type = "a"\n[robot.types.a]\nrange = 150\n[robot.types.b]\nids = [4]\nrange = 150\n',
}


@pytest.mark.parametrize("description", WIDE.values(), ids=list(WIDE))
def test_a_range_beyond_90_degrees_is_the_simulated_modules_hardware_range(description: str, tmp_path) -> None:
    gait = loads(wide(description))
    peak = {1: 0.0, 2: 0.0}
    with Simulation(gait, c_modules=(2,)) as sim:  # the Python runtime and the C runtime alike
        sim.start()
        for _ in range(100):  # 2 s of ticks
            sim.step_tick()
            peak = {k: max(v, abs(sim.goal(k))) for k, v in peak.items()}
    assert min(peak.values()) > 100.0, f"each module commands the gait's angles beyond ±90°: {peak}"
    path = tmp_path / "wide.toml"
    path.write_text(wide(description), encoding="utf-8")
    assert main(["validate", str(path)]) == 0
    assert main(["simulate", str(path), "--seconds", "0.5", "--warmup", "0"]) == 0
    outcome = evaluate(to_dict(gait, inline=True), Setup(seconds=0.5, warmup=0.2))  # a tuner's candidate
    assert "not simulated" not in outcome.problem and "invalid" not in outcome.problem, outcome.problem


@pytest.mark.parametrize(
    ("description", "says"),
    [
        ("", "±90.0° (robot.module.range, 90 unless given"),
        ("[robot.module]\nmass = 0.3\n", "±90.0° (robot.module.range, 90 unless given"),
        ('type = "a"\n[robot.types.a]\nmass = 0.3\n', "module type a ±90.0° (robot.types.a.range, 90 unless given"),
        ("[robot.types.b]\nids = [4]\nrange = 150\n", "±90.0° (robot.module.range, 90 unless given"),
        ('type = "a"\n[robot.types.a]\nrange = 150\n[robot.types.b]\nids = [4]\n', "module type b ±90.0°"),
        ("[robot.module]\nrange = 120\n", "the module's joint range ±120° (robot.module.range)"),
    ],
)
def test_limits_beyond_a_modules_range_said_or_not_are_refused(description: str, says: str) -> None:
    with pytest.raises(GaitError) as refused:
        loads(wide(description))
    assert [p.path for p in refused.value.problems] == ["limits"], refused.value
    assert says in str(refused.value), refused.value


def test_a_simulated_robot_runs_modules_of_a_wide_range(tmp_path) -> None:
    """asm-robot --sim builds the same modules: it starts, where it failed at the first module."""
    from tests.transports import free_port

    path = tmp_path / "wide.toml"
    path.write_text(wide(WIDE["robot.module"]), encoding="utf-8")
    robot = Process("-m", "server.robot", "--sim", str(path), "--zenoh-listen", f"tcp/127.0.0.1:{free_port()}")
    try:
        robot.wait_for_line("READY robot", timeout=90)
    finally:
        robot.stop()
