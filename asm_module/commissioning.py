"""A Python module whose node ID is commissioned over the bus (docs/protocol.md §7, "Commissioning").

Its serial and node ID live in a small JSON file (what flash is to a board; its joint.calibration in another next to
it, :func:`calibration_path`): a module without one boots unconfigured
and answers only the commissioning commands; once a tool assigns it an ID it stores it, starts its node ``m<ID>``
with its module runtime, and comes back under that ID after every restart. A later ASSIGN moves it to another ID
(its node restarts under it), an ASSIGN of 0 makes it unconfigured again.

One thread (``asm-commission:<serial>``) reads the commissioning commands from the module's own bus endpoint (a
Linux module opens a second socket on its interface), apart from the node's transport.
"""

from __future__ import annotations

import json
import logging
import os
import secrets
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

from asm_py.canbus.commission import (
    COMMAND_FILTER,
    SERIAL_BYTES,
    UNCONFIGURED,
    Commissionee,
    check_serial,
    is_command,
    reply_frame,
)
from asm_py.node import Node
from asm_py.transport.can import CanTransport

from .calibration import CalibrationFile
from .drivers import FakeDriver
from .names import module_name
from .runtime import ModuleRuntime

log = logging.getLogger("asm_module.commissioning")


class IdFile:
    """A module's non-volatile identity: ``{"serial": hex, "node_id": n}`` in ``path``. A file that does not exist
    yet is made with a random serial (or ``serial``) and no node ID; writes replace the file atomically."""

    def __init__(self, path: str | Path, serial: bytes | None = None) -> None:
        self.path = Path(path)
        if self.path.exists():
            record = json.loads(self.path.read_text())
            self.serial = check_serial(bytes.fromhex(record["serial"]))
            self.node_id = int(record.get("node_id", UNCONFIGURED))
            if serial is not None and check_serial(serial) != self.serial:
                raise ValueError(f"{self.path} holds serial {self.serial.hex()}, not {serial.hex()}")
        else:
            self.serial = check_serial(serial) if serial is not None else secrets.token_bytes(SERIAL_BYTES)
            self.node_id = UNCONFIGURED
            self.save(UNCONFIGURED)

    def save(self, node_id: int) -> None:
        temporary = self.path.with_name(self.path.name + ".tmp")
        temporary.write_text(json.dumps({"serial": self.serial.hex(), "node_id": node_id}) + "\n")
        os.replace(temporary, self.path)
        self.node_id = node_id


def calibration_path(id_file: str | Path) -> Path:
    """Where the module of ID file ``id_file`` keeps its calibration: ``<name>.calibration.json`` next to it."""
    path = Path(id_file)
    return path.with_name(path.stem + ".calibration.json")


RuntimeFactory = Callable[[Node, int], ModuleRuntime]
"""Makes the module runtime of a node under a node ID."""


def default_runtime(node: Node, node_id: int) -> ModuleRuntime:
    return ModuleRuntime(FakeDriver(), node=node, module_id=node_id)


class CommissionedModule:
    """One Python module on a CAN bus, numbered by commissioning; see the module docstring.

    ``open_bus()`` opens an endpoint of the module's bus (called once for the commissioning thread, once per node
    start); ``runtime`` makes the module runtime once the module has an ID; ``transport`` are CanTransport
    options. ``close`` stops everything it started (it is also a power cycle: a new instance on the same file is the
    module rebooted)."""

    def __init__(
        self,
        identity: IdFile,
        open_bus: Callable[[], can.BusABC],
        *,
        runtime: RuntimeFactory = default_runtime,
        **transport: Any,
    ) -> None:
        self.identity = identity
        self._open_bus = open_bus
        self._make_runtime = runtime
        self._transport = transport
        self._lock = threading.Lock()
        self.node: Node | None = None
        self.runtime: ModuleRuntime | None = None
        self._buses: list[can.BusABC] = []
        self.commissionee = Commissionee(identity.serial, identity.node_id, store=self._store)
        self._stop = threading.Event()
        self._bus = open_bus()
        try:
            self._bus.set_filters([COMMAND_FILTER])
            if identity.node_id != UNCONFIGURED:
                self._start(identity.node_id)
        except BaseException:
            self.close()
            raise
        self._thread = threading.Thread(target=self._listen, name=f"asm-commission:{identity.serial.hex()[:8]}",
                                        daemon=True)  # fmt: skip
        self._thread.start()

    @property
    def serial(self) -> bytes:
        return self.identity.serial

    @property
    def node_id(self) -> int:
        """The node ID it runs under (0: unconfigured)."""
        return self.identity.node_id

    def _listen(self) -> None:
        while not self._stop.is_set():
            try:
                frame = self._bus.recv(timeout=0.1)
            except (can.CanError, RuntimeError, ValueError):
                if self._stop.is_set():
                    return
                log.exception("commissioning receive failed")
                continue
            if frame is None or not is_command(frame):
                continue
            try:
                with self._lock:
                    answer = self.commissionee.command(bytes(frame.data))
                if answer is not None:
                    self._bus.send(reply_frame(answer), timeout=0.1)
            except Exception:  # a command that fails is not answered: the tool asks again
                log.exception("commissioning command %s failed", bytes(frame.data).hex())

    def _store(self, node_id: int) -> None:
        """ASSIGN: write the file first (an ID is answered only once it would survive a reset), then run under it."""
        self.identity.save(node_id)
        if self.node is not None and self.node.name == module_name(node_id):
            return
        self._stop_node()
        if node_id != UNCONFIGURED:
            self._start(node_id)

    def _start(self, node_id: int) -> None:
        bus = self._open_bus()
        self._buses.append(bus)
        node = Node(module_name(node_id), CanTransport(node_id, bus=bus, **self._transport))
        self.node = node
        self.runtime = self._make_runtime(node, node_id)

    def _stop_node(self) -> None:
        if self.runtime is not None:
            self.runtime.close()
            self.runtime = None
        if self.node is not None:
            self.node.close()
            self.node = None
        for bus in self._buses:
            bus.shutdown()
        self._buses.clear()

    def close(self) -> None:
        self._stop.set()
        thread = getattr(self, "_thread", None)
        if thread is not None and thread is not threading.current_thread():
            thread.join(5)
        with self._lock:
            self._stop_node()
        self._bus.shutdown()

    def __enter__(self) -> CommissionedModule:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Fleet:
    """``count`` commissionable Python modules on sim channel ``channel``, their ID files in ``directory``
    (``module<k>.json``), sharing one 50 Hz tick as a robot's modules do; for tests and benches. :meth:`reset`
    power-cycles them all; ``close`` stops everything."""

    def __init__(self, directory: Path, count: int, channel: str, **transport: Any) -> None:
        from asm_py.codec import FLOAT64
        from asm_py.event import Event, TimerTrigger

        self.directory, self.count, self.channel = directory, count, channel
        self.transport = {"heartbeat_period": 0.2, "missed_heartbeats": 10, "watch_bus": False, **transport}
        self.tick = Event("gait.tick", codec=FLOAT64)
        self.timer = TimerTrigger(0.02, name="fleet.tick")
        self.tick.add_trigger(self.timer)
        self.timer.start()
        self.modules: list[CommissionedModule] = []
        self.boot()

    def open_bus(self) -> can.BusABC:
        return can.Bus(interface="asm_sim", channel=self.channel)

    def runtime(self, node: Node, node_id: int, store: CalibrationFile | None = None) -> ModuleRuntime:
        return ModuleRuntime(FakeDriver(), node=node, tick=self.tick, inline=True, module_id=node_id,
                             calibration_store=store)  # fmt: skip

    def boot(self) -> None:
        """Start every module from its ID file (made, with a random serial, if missing) and calibration file."""
        try:
            for k in range(self.count):
                identity = IdFile(self.directory / f"module{k}.json")
                store = CalibrationFile(calibration_path(identity.path))

                def runtime(node: Node, node_id: int, store: CalibrationFile = store) -> ModuleRuntime:
                    return self.runtime(node, node_id, store)

                self.modules.append(CommissionedModule(identity, self.open_bus, runtime=runtime,
                                                       **self.transport))  # fmt: skip
        except BaseException:
            self.shutdown()
            raise

    def reset(self) -> None:
        """A power cycle: every module stops and boots again from its file."""
        self.shutdown()
        self.boot()

    def close(self) -> None:
        """Stop every module (:meth:`reset` boots them again) and the tick."""
        self.shutdown()
        self.timer.stop(timeout=5)

    def shutdown(self) -> None:
        for module in self.modules:
            module.close()
        self.modules.clear()
