"""A robot of module runtimes on one simulated CAN bus, ticked at 50 Hz, for the benchmarks: what ``asm-robot``
runs without the physics (each joint a FakeDriver servo model), so a bench measures the modules and the bus."""

from __future__ import annotations

import itertools
import os

import can

from asm_module import FakeDriver, ModuleRuntime
from asm_module.names import module_name
from asm_py import Event, Node, TimerTrigger
from asm_py.canbus.faults import FaultyBus
from asm_py.codec import FLOAT64
from asm_py.transport.can import CanTransport

_channels = itertools.count()


class BusRobot:
    """``count`` module runtimes m1.. on a fresh ``asm_sim`` channel; ``faults`` (FaultyBus options) on each
    module's bus. ``close`` stops everything."""

    def __init__(self, count: int, *, faults: dict | None = None, heartbeat_period: float = 0.05) -> None:
        self.channel = f"bench-robot-{os.getpid()}-{next(_channels)}"
        self.options = {"heartbeat_period": heartbeat_period, "missed_heartbeats": 20}
        self.faults = faults
        self.tick = Event("gait.tick", codec=FLOAT64)
        self.timer = TimerTrigger(0.02, name="bench.tick")
        self.tick.add_trigger(self.timer)
        self.timer.start()
        self.nodes: list[Node] = []
        self.buses: list[can.BusABC] = []
        self.drivers: list[FakeDriver] = []
        self.runtimes: list[ModuleRuntime] = []
        for module_id in range(1, count + 1):
            node = Node(module_name(module_id), self.transport(module_id))
            self.nodes.append(node)
            driver = FakeDriver()
            self.drivers.append(driver)
            self.runtimes.append(ModuleRuntime(driver, node=node, tick=self.tick, inline=True, module_id=module_id))

    def transport(self, node_id: int) -> CanTransport:
        bus: can.BusABC = can.Bus(interface="asm_sim", channel=self.channel)
        self.buses.append(bus)
        if self.faults:
            bus = FaultyBus(bus, seed=node_id, **self.faults)
            self.buses.append(bus)
        return CanTransport(node_id, bus=bus, watch_bus=False, **self.options)

    def tool(self, name: str, node_id: int) -> Node:
        node = Node(name, CanTransport(node_id, interface="asm_sim", channel=self.channel, **self.options))
        self.nodes.append(node)
        return node

    def close(self) -> None:
        self.timer.stop(timeout=5)
        for runtime in self.runtimes:
            runtime.close()
        for node in self.nodes:
            node.close()
        for bus in self.buses:
            bus.shutdown()
