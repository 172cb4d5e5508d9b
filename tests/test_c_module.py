"""A C module (firmware/, as a host library) on a python-can bus, driven by a Python client exactly as a Python
module is: discovery by heartbeat, lookups, gets and sets, read-only and domain refusals, publications, the e-stop
from a frame and from a set, and hostile frames it survives (issue 17)."""

from __future__ import annotations

import random
import shutil
import time
from collections.abc import Iterator

import can
import pytest

from asm_py import EstopLatched, ReadOnlyError
from asm_py.firmware import CModule
from asm_py.node import Node
from asm_py.transport.can import CanTransport

from .helpers import wait_until
from .transports import fresh_name

pytestmark = [pytest.mark.timeout(120), pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")]


@pytest.fixture
def bus_pair() -> Iterator[tuple[CModule, Node, str]]:
    channel = fresh_name("c-module")
    module = CModule("c1", 5, interface="virtual", channel=channel)
    tool = Node("tool", CanTransport(100, interface="virtual", channel=channel, heartbeat_period=0.1))
    try:
        assert wait_until(lambda: "c1" in tool.discover(), timeout=10), "the C module's heartbeat names it"
        yield module, tool, channel
    finally:
        tool.close()
        module.close()


def test_a_client_lists_reads_and_writes_a_c_module(bus_pair) -> None:
    module, tool, _ = bus_pair
    names = [obj.info.name for obj in tool.list_objects("c1", timeout=5)]
    assert names == ["joint.goal", "joint.angle", "joint.torque", "joint.limits", "servo.service", "sensor.contact",
                     "estop"]  # fmt: skip
    goal = tool.lookup("c1", "joint.goal", timeout=5)
    assert goal.info.class_id == 0x10 and goal.info.codec.descriptor() == b"\x0a"
    goal.set(30.0, wait=True)
    assert goal.peek() == 30.0
    angle = tool.lookup("c1", "joint.angle", timeout=5)
    assert wait_until(lambda: abs(angle.peek() - 30.0) < 0.5, timeout=10), "the joint follows the goal"
    goal.set(500.0, wait=True)
    assert goal.peek() == 90.0, "clamped to joint.limits"
    limits = tool.lookup("c1", "joint.limits", timeout=5)
    limits.set([-45.0, 45.0], wait=True)
    assert goal.peek() == 45.0, "the goal follows narrower limits"
    with pytest.raises(ValueError):
        limits.set([10.0, -10.0], wait=True)
    with pytest.raises(ValueError):
        goal.set(float("nan"), wait=True)
    with pytest.raises(ReadOnlyError):
        angle.set(1.0, wait=True)
    assert tool.lookup("c1", "joint.angle", timeout=5).info.read_only
    with pytest.raises(LookupError):
        tool.lookup("c1", "no.such.object", timeout=5)
    servo = tool.lookup("c1", "servo.service", timeout=5)
    assert servo.running


def test_publications_of_a_c_module_reach_a_python_subscriber(bus_pair) -> None:
    module, tool, _ = bus_pair
    seen: list[float] = []
    angle = tool.lookup("c1", "joint.angle", timeout=5)
    unsubscribe = angle.on_change(seen.append)
    try:
        tool.lookup("c1", "joint.goal", timeout=5).set(-20.0, wait=True)
        assert wait_until(lambda: seen and abs(seen[-1] + 20.0) < 0.5, timeout=10)
        count = len(seen)
        time.sleep(1.2)
        assert len(seen) > count, "refreshed while still"
    finally:
        unsubscribe()


def test_an_estop_latches_the_c_module_until_released(bus_pair) -> None:
    module, tool, _ = bus_pair
    goal = tool.lookup("c1", "joint.goal", timeout=5)
    goal.set(40.0, wait=True)
    tool.estop("test")
    assert wait_until(lambda: module.latched, timeout=5)
    with pytest.raises(EstopLatched):
        goal.set(-40.0, wait=True)
    with pytest.raises(EstopLatched):
        tool.lookup("c1", "servo.service", timeout=5).stop(wait=True)
    held = goal.peek()
    assert abs(held - module.driver.read().angle) < 5.0, "it holds where the joint was"
    estop = tool.lookup("c1", "estop", timeout=5)
    assert estop.peek() is True
    estop.set(False, wait=True)
    assert not module.latched
    goal.set(-40.0, wait=True)
    assert goal.peek() == -40.0
    estop.set(True, wait=True)
    assert module.latched, "a set latches as a frame does"


def test_hostile_frames_leave_the_c_module_answering(bus_pair) -> None:
    module, tool, channel = bus_pair
    rng = random.Random(17)
    attacker = can.Bus(interface="virtual", channel=channel)
    try:
        for _ in range(3000):
            dest_kind = rng.choice([0, 0, 1, 2])
            can_id = (rng.randrange(8) << 26 | dest_kind << 24 | (5 if dest_kind == 0 else rng.randrange(256)) << 16
                      | rng.randrange(1, 255) << 8 | rng.randrange(256))  # fmt: skip
            attacker.send(can.Message(arbitration_id=can_id, is_extended_id=True,
                                      data=bytes(rng.randrange(256) for _ in range(rng.randrange(9)))))  # fmt: skip
    finally:
        attacker.shutdown()
    assert wait_until(lambda: module.counters()["dropped"] > 0, timeout=10)
    goal = tool.lookup("c1", "joint.goal", timeout=5)
    if module.latched:  # a random frame may have been a valid e-stop or estop set: release it
        tool.lookup("c1", "estop", timeout=5).set(False, wait=True)
    goal.set(12.5, wait=True)
    assert goal.peek() == 12.5
