"""One-to-many ports: one message reaches the object of a class on every member of a group (memory and Zenoh)."""

from __future__ import annotations

import pytest

from asm_py import Attribute, GroupPort, Service
from asm_py.classes import well_known
from asm_py.group import class_id_of
from asm_py.node import Node

from ..helpers import wait_until
from ..transports import FACTORIES


class Gait(Service):
    def __init__(self) -> None:
        super().__init__("gait")
        self.params: tuple = ()

    def run(self, *params: object) -> None:
        self.params = params
        while self.sleep(0.01):
            pass


@pytest.mark.parametrize("kind", sorted(FACTORIES))
def test_group_start_set_stop_reach_every_member_and_only_members(kind: str) -> None:
    with FACTORIES[kind]() as make:
        controller = Node("controller", make())
        modules = [Node(f"m{i}", make()) for i in range(4)]
        gaits = [Gait() for _ in modules]
        goals = [Attribute("goal", 0.0, codec="float32") for _ in modules]
        try:
            for i, (node, gait, goal) in enumerate(zip(modules, gaits, goals, strict=True)):
                node.register(gait, class_name="gait.service")
                node.register(goal, class_name="joint.goal")
                if i < 3:
                    node.join_group("legs")
            names = {"controller", *(n.name for n in modules)}
            assert wait_until(lambda: names <= set(controller.discover()), timeout=30)  # a loaded machine: slow
            legs = controller.group("legs")
            assert isinstance(legs, GroupPort)
            # A Zenoh group subscription may take a moment to propagate: repeat the (idempotent) set until seen.
            assert wait_until(lambda: (legs.attribute("joint.goal", "float32").set(0.5), goals[0].peek())[1] == 0.5)
            assert wait_until(lambda: all(g.peek() == 0.5 for g in goals[:3]), timeout=10)
            legs.service("gait.service").start(2, "fast")
            # running is set as the thread starts, params a moment later (run's first line): wait for both
            assert wait_until(lambda: all(g.running and g.params == (2, "fast") for g in gaits[:3]), timeout=10)
            assert not gaits[3].started and goals[3].peek() == 0.0  # not a member
            controller.group().service("gait.service").stop()  # the broadcast reaches everyone
            assert wait_until(lambda: not any(g.started for g in gaits), timeout=10)
            assert legs.sent >= 2
        finally:
            controller.close()
            for node in modules:
                node.close()
            for gait in gaits:
                gait.stop(timeout=5)


def test_group_messages_for_an_absent_class_are_ignored() -> None:
    with FACTORIES["memory"]() as make:
        a, b = Node("a", make()), Node("b", make())
        try:
            a.group().service("servo.service").start()  # b has no servo service: nothing happens, nothing breaks
            goal = Attribute("goal", 1.0, codec="float32")
            b.register(goal, class_name="joint.goal")
            a.group().attribute("joint.goal", "float32").set(2.0)
            assert wait_until(lambda: goal.peek() == 2.0)
            assert b.transport.handler_errors == 0
        finally:
            a.close()
            b.close()


def test_group_class_must_mean_the_same_everywhere() -> None:
    assert class_id_of("joint.angle") == well_known()["joint.angle"]
    assert class_id_of(0x90) == 0x90
    with pytest.raises(LookupError, match="well-known"):
        class_id_of("my.private.thing")
    with pytest.raises(ValueError):
        class_id_of(0)


def test_a_bad_value_fails_before_anything_is_sent() -> None:
    with FACTORIES["memory"]() as make:
        node = Node("a", make())
        try:
            port = node.group()
            with pytest.raises(TypeError):
                port.attribute("joint.goal", "float32").set("high")
            assert port.sent == 0
        finally:
            node.close()
