"""A robot that is not the gait's is reported before a deploy: modules missing or extra, joint limits that would clamp
the gait, a module that says it is another type than the gait describes (module.type), and, where the types cannot
be compared so, a joint that turns further than the gait's module does (another module type). Read from real module
runtimes on a memory network, as the Deploy tab reads them."""

from __future__ import annotations

import pytest

from asm_module import FakeDriver, ModuleRuntime
from asm_py import Node
from asm_py.transport.memory import MemoryNetwork, MemoryTransport
from gaits.compatible import commanded, mismatches, module_lines, read_limits, read_objects, states_needed
from gaits.model import LIBRARY, load, loads

pytestmark = pytest.mark.timeout(60)
CATERPILLAR = load(LIBRARY / "caterpillar.toml")  # 8 modules, ±50° commanded, the default module (±90° hinge)


@pytest.fixture
def robot():
    """Start module runtimes m1..mN on a memory network (each with its limits and hardware range); a client."""
    network = MemoryNetwork()
    started: list[tuple[ModuleRuntime, Node]] = []
    client = Node("tool", MemoryTransport(network))

    def start(count: int, limits=(-90.0, 90.0), hardware=(-90.0, 90.0), odd: dict[int, tuple] | None = None,
              types: dict[int, str] | None = None):  # fmt: skip
        for k in range(1, count + 1):
            lo_hi, hw = (odd or {}).get(k, (limits, hardware))
            node = Node(f"m{k}", MemoryTransport(network))
            runtime = ModuleRuntime(FakeDriver(), node=node, limits=lo_hi, hardware_range=hw,
                                    module_type=(types or {}).get(k, ""))  # fmt: skip
            started.append((runtime, node))
        names = [f"m{k}" for k in range(1, count + 1)]
        return names, read_limits(client.lookup, names, timeout=1.0)

    start.client = client  # type: ignore[attr-defined]
    yield start
    for runtime, node in started:
        runtime.close()
        node.close()
    client.close()


def test_the_robot_the_gait_was_made_for_matches(robot):
    names, limits = robot(8)
    assert limits == {name: (-90.0, 90.0) for name in names}
    assert mismatches(CATERPILLAR, names, limits) == []
    assert commanded(CATERPILLAR)[1] == (-50.0, 50.0)


def test_missing_modules_are_named(robot):
    names, limits = robot(6)
    assert mismatches(CATERPILLAR, names, limits) == ["m7, m8 of the gait's 8 modules did not answer"]


def test_extra_modules_are_named(robot):
    names, limits = robot(10)
    (line,) = mismatches(CATERPILLAR, names, limits)
    assert line.startswith("m9, m10 answered but the gait has 8 modules")


def test_limits_that_would_clamp_the_gait_are_reported(robot):
    names, limits = robot(8, odd={3: ((-45.0, 45.0), (-90.0, 90.0))})
    assert mismatches(CATERPILLAR, names, limits) == [
        "m3 allows -45..45°, the gait commands -50..50°: it would refuse the table"
    ]


def test_a_joint_that_turns_further_than_the_gaits_module_is_another_type(robot):
    names, limits = robot(8, limits=(-135.0, 135.0), hardware=(-135.0, 135.0))
    lines = mismatches(CATERPILLAR, names, limits)
    assert len(lines) == 8 and "m1 turns -135..135°, beyond the ±90° hinge of the gait's module" in lines[0]


def test_a_module_that_does_not_answer_is_left_to_the_missing_line():
    client = Node("alone", MemoryTransport(MemoryNetwork()))
    try:
        assert read_limits(client.lookup, ["m1"], timeout=0.2) == {}
    finally:
        client.close()


def test_module_info_and_calibration_are_read_shown_and_checked(robot):
    """Each module's firmware and calibration go into the deploy's log; a module that holds fewer states than the
    gait gives it is reported (a C module keeps 64); a calibration's soft limits are the limits checked."""
    names, limits = robot(8, odd={2: ((-40.0, 40.0), (-90.0, 90.0))})
    client = robot.client
    calibration = client.lookup("m2", "joint.calibration", timeout=1.0)
    calibration.set({"zero": 10.0, "direction": -1, "min": -60.0, "max": 70.0}, wait=True)
    limits = read_limits(client.lookup, names, timeout=1.0)
    assert limits["m2"] == (-60.0, 70.0), "the soft limits, as the module clamps to them"
    infos = read_objects(client.lookup, names, "module.info", timeout=1.0)
    assert set(infos) == set(names) and infos["m1"]["language"] == 0
    assert mismatches(CATERPILLAR, names, limits, infos) == [], "-60..70 holds the gait's ±50°"
    lines = module_lines(infos, read_objects(client.lookup, names, "joint.calibration", timeout=1.0))
    assert len(lines) == 8 and lines[1].startswith("m2: Python 0.1.0 build ")
    assert lines[1].endswith("zero 10°, direction -1, soft limits -60..70°")
    needed = states_needed(CATERPILLAR)
    small = {name: dict(info, max_states=needed[1] - 1) if name == "m1" else info for name, info in infos.items()}
    assert mismatches(CATERPILLAR, names, limits, small) == [
        f"m1 holds {needed[1] - 1} states, the gait gives it {needed[1]}: it would refuse the table"
    ]
    assert read_objects(client.lookup, ["m99"], "module.info", timeout=0.2) == {}


TYPED = loads((LIBRARY / "caterpillar.toml").read_text(encoding="utf-8").replace(
    "module_size = 0.05\n", 'module_size = 0.05\ntype = "light"\n[robot.types.light]\n[robot.types.heavy]\n'
    "mass = 0.6\nrange = 120.0\nids = [4, 5]\n", 1))  # fmt: skip
"""The caterpillar described as light modules with two heavy ones (m4, m5) in the middle."""


def test_a_module_of_another_type_than_the_gait_describes_is_named(robot):
    said = {k: "heavy" if k in (4, 5) else "light" for k in range(1, 9)}
    names, limits = robot(8, types=said | {4: "servo_v1", 7: ""})  # m4 another type; m7 does not say
    types = read_objects(robot.client.lookup, names, "module.type", timeout=1.0)
    assert types == {f"m{k}": v for k, v in (said | {4: "servo_v1", 7: ""}).items()}
    assert mismatches(TYPED, names, limits, types=types) == [
        "m4 is module type servo_v1, the gait describes heavy (robot.types.heavy): another type of module than the "
        "one simulated"
    ]
    lines = module_lines({}, {}, types)
    assert lines[3] == "m4: type servo_v1" and lines[6] == "m7:"


def test_the_range_heuristic_judges_only_modules_whose_type_cannot_be_compared(robot):
    """m1 says its type, m2 says none: only m2's wide joint is judged by its range; the library gait names no type,
    so there every module is judged by the range (±90°), whatever it says it is."""
    names, limits = robot(8, limits=(-100.0, 100.0), hardware=(-100.0, 100.0), types={1: "light"})
    types = read_objects(robot.client.lookup, names, "module.type", timeout=1.0)
    lines = mismatches(TYPED, names, limits, types=types)
    assert [line.split(" ")[0] for line in lines] == ["m2", "m3", "m6", "m7", "m8"]  # m4, m5: ±120° heavy modules
    assert "beyond the ±90° hinge of the gait's module (robot.types.light.range)" in lines[0]
    assert len(mismatches(CATERPILLAR, names, limits, types=types)) == 8


def test_a_deploy_to_modules_of_other_types_is_refused_unless_accepted(robot):
    """gaits.deploy checks the types itself, whoever calls it (issue 30's review, defect 1: a simulated robot
    another person started, built of other module types, was deployed to without a word): nothing is sent until the
    caller accepts exactly what differs."""
    from gaits.deploy import RobotMismatch, deploy

    said = {k: "heavy" if k in (1, 2) else "light" for k in range(1, 9)}
    names, _ = robot(8, types=said | {7: ""})  # m7 says no type: nothing to compare
    with pytest.raises(RobotMismatch) as refused:
        deploy(robot.client, TYPED, timeout=1.0)
    assert [line.split(" ")[0] for line in refused.value.problems] == ["m1", "m2", "m4", "m5"]
    assert refused.value.problems[0] == ("m1 is module type heavy, the gait describes light (robot.types.light): "
                                         "another type of module than the one simulated")  # fmt: skip
    lease = read_objects(robot.client.lookup, names, "gait.lease", timeout=1.0)
    assert all(not held["holder"] for held in lease.values()), "nothing was sent: no lease taken"
    with pytest.raises(RobotMismatch):  # accepting some of it is not accepting all of it
        deploy(robot.client, TYPED, timeout=1.0, accept=refused.value.problems[:3])
    report = deploy(robot.client, TYPED, timeout=1.0, accept=refused.value.problems)
    assert report.running == list(range(1, 9))
    assert deploy(robot.client, CATERPILLAR, timeout=1.0).running == list(range(1, 9)), "a gait naming no type"


def test_a_deploy_beyond_a_modules_limits_is_refused_before_anything_is_sent_naming_each_module(robot):
    """Issue 28's review: a module calibrated with narrower soft limits refused the table at staging with only
    "value out of its domain", the lease taken and the modules before it staged. Every module's limits are read
    first and every one that would refuse is named, with the angles."""
    from gaits.deploy import DeployError, deploy

    names, _ = robot(8, odd={3: ((-45.0, 45.0), (-90.0, 90.0)), 6: ((-30.0, 20.0), (-90.0, 90.0))})
    with pytest.raises(DeployError) as refused:
        deploy(robot.client, CATERPILLAR, timeout=1.0)
    said = str(refused.value)
    assert "module 3 (m3) allows -45..45°, the gait commands -50..50°" in said, said
    assert "module 6 (m6) allows -30..20°" in said, said
    assert "refuse" in said and "soft limits" in said, said
    lease = read_objects(robot.client.lookup, names, "gait.lease", timeout=1.0)
    assert all(not held["holder"] for held in lease.values()), "nothing was sent: no lease taken"
    staged = read_objects(robot.client.lookup, names, "gait.staged_checksum", timeout=1.0)
    assert len(set(staged.values())) == 1, "no module staged anything"


def test_a_deploy_while_a_firmware_update_is_written_is_refused(robot, monkeypatch):
    """Issue 28's third review: a deploy during an update was accepted; the updated boards then reset and stopped,
    the others walked on. A module receiving an image (firmware.status) refuses the deploy, nothing sent."""
    from asm_module._profile import FIRMWARE_STATES
    from gaits.calls import ModuleCalls
    from gaits.deploy import DeployError, deploy

    names, _ = robot(8)
    peek = ModuleCalls.peek

    def receiving_on_m3(self, module, name, step):
        if name == "firmware.status" and module == 3:
            return {"state": FIRMWARE_STATES.index("receiving"), "running": 0x100, "other": 0, "received": 512}
        return peek(self, module, name, step)

    monkeypatch.setattr(ModuleCalls, "peek", receiving_on_m3)
    with pytest.raises(DeployError, match=r"^module 3 \(m3\): a firmware update is being written"):
        deploy(robot.client, CATERPILLAR, timeout=1.0)
    lease = read_objects(robot.client.lookup, names, "gait.lease", timeout=1.0)
    assert all(not held["holder"] for held in lease.values()), "nothing was sent: no lease taken"
    monkeypatch.setattr(ModuleCalls, "peek", peek)
    assert deploy(robot.client, CATERPILLAR, timeout=1.0).running == list(range(1, 9))
