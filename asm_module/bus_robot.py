"""A robot without physics: module runtimes on one simulated CAN bus (python-can's ``asm_sim``), ticked at 50 Hz.

What ``asm-robot`` runs, less MuJoCo: each joint a FakeDriver servo model, so a test or a benchmark exercises the
modules and the bus, and a tool under development can be tried against eight modules in a second. ``faults``
(asm_py.canbus.faults.FaultyBus options: drop, duplicate, reorder, corrupt) sit between each module and the bus,
and between a tool and the bus unless it asks for a clean one.
"""

from __future__ import annotations

import itertools
import os
from typing import Any

import can

from asm_py import Event, Node, TimerTrigger
from asm_py.canbus.faults import FaultyBus
from asm_py.codec import FLOAT64
from asm_py.transport.can import CanTransport

from .drivers import FakeDriver
from .names import module_name
from .runtime import ModuleRuntime

_channels = itertools.count()
TOOL_ID = 200
"""The default node ID of a tool on this bus (the first of the bridge's alias range: never a module's)."""


class BusRobot:
    """``count`` module runtimes m1..m<count> on a fresh channel, sharing one 50 Hz tick like a robot process's;
    ``close`` stops everything it made."""

    def __init__(
        self, count: int, *, faults: dict | None = None, heartbeat_period: float = 0.05, watch_bus: bool = True
    ) -> None:
        self.channel = f"bus-robot-{os.getpid()}-{next(_channels)}"
        self.options = {"heartbeat_period": heartbeat_period, "missed_heartbeats": 20}
        """CanTransport options every node here uses (a bridge on this channel takes the same)."""
        self.faults = faults
        self.tick = Event("gait.tick", codec=FLOAT64)
        self.timer = TimerTrigger(0.02, name="bus-robot.tick")
        self.tick.add_trigger(self.timer)
        self.timer.start()
        self.nodes: list[Node] = []
        self.buses: list[can.BusABC] = []
        self.drivers: list[FakeDriver] = []
        self.runtimes: list[ModuleRuntime] = []
        try:
            for module_id in range(1, count + 1):
                node = Node(module_name(module_id), self.transport(module_id, watch_bus=watch_bus))
                self.nodes.append(node)
                driver = FakeDriver()
                self.drivers.append(driver)
                self.runtimes.append(ModuleRuntime(driver, node=node, tick=self.tick, inline=True, module_id=module_id))
        except BaseException:
            self.close()
            raise

    def transport(self, node_id: int, *, seed: int | None = None, faulty: bool = True, **options: Any) -> CanTransport:
        """A CAN transport on this robot's bus for node ``node_id``, through the faults unless ``faulty`` is false
        (``seed``: the faults' random seed, the node ID by default)."""
        bus: can.BusABC = can.Bus(interface="asm_sim", channel=self.channel)
        self.buses.append(bus)
        if self.faults and faulty:
            bus = FaultyBus(bus, seed=node_id if seed is None else seed, **self.faults)
            self.buses.append(bus)
        return CanTransport(node_id, bus=bus, **{**self.options, **options})

    def tool(self, name: str = "tool", node_id: int = TOOL_ID, *, faulty: bool = True, **options: Any) -> Node:
        """A tool node on this bus (``options``: Node options, e.g. call_timeout); closed with the robot."""
        node = Node(name, self.transport(node_id, faulty=faulty), **options)
        self.nodes.append(node)
        return node

    def running(self) -> list[int]:
        """The deploy ID each module runs (0 when its gait is stopped)."""
        return [r.staging.activate.peek() if r.gait.running else 0 for r in self.runtimes]

    def close(self) -> None:
        self.timer.stop(timeout=5)
        for runtime in self.runtimes:
            runtime.close()
        for node in self.nodes:
            node.close()
        for bus in self.buses:
            bus.shutdown()

    def __enter__(self) -> BusRobot:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
