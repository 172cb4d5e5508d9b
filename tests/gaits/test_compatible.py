"""A robot that is not the gait's is reported before a deploy: modules missing or extra, joint limits that would clamp
the gait, and a joint that turns further than the gait's module does (another module type). Read from real module
runtimes on a memory network, as the Deploy tab reads them."""

from __future__ import annotations

import pytest

from asm_module import FakeDriver, ModuleRuntime
from asm_py import Node
from asm_py.transport.memory import MemoryNetwork, MemoryTransport
from gaits.compatible import commanded, mismatches, read_limits
from gaits.model import LIBRARY, load

pytestmark = pytest.mark.timeout(60)
CATERPILLAR = load(LIBRARY / "caterpillar.toml")  # 8 modules, ±50° commanded, the default module (±90° hinge)


@pytest.fixture
def robot():
    """Start module runtimes m1..mN on a memory network (each with its limits and hardware range); a client."""
    network = MemoryNetwork()
    started: list[tuple[ModuleRuntime, Node]] = []
    client = Node("tool", MemoryTransport(network))

    def start(count: int, limits=(-90.0, 90.0), hardware=(-90.0, 90.0), odd: dict[int, tuple] | None = None):
        for k in range(1, count + 1):
            lo_hi, hw = (odd or {}).get(k, (limits, hardware))
            node = Node(f"m{k}", MemoryTransport(network))
            started.append((ModuleRuntime(FakeDriver(), node=node, limits=lo_hi, hardware_range=hw), node))
        names = [f"m{k}" for k in range(1, count + 1)]
        return names, read_limits(client.lookup, names, timeout=1.0)

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
        "m3 allows -45..45°, the gait commands -50..50°: it would be clamped and not move as previewed"
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
