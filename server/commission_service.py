"""The robot process's commissioning service: the modules of its bus found by serial, wiggled and numbered for a
tool on Zenoh (the request and reply shapes: asm_module/commission_link.py; docs/protocol.md §7 and §10).

The robot process owns the bus (the simulated one, or the real one of ``asm-robot --can``), so commissioning runs
here: the commissioning protocol (asm_py.canbus.commission.Commissioner) on a bus handle of its own, and the joint
moved over ASM by the bridge's own CAN node (``bridge.node``: what reads tables already).

A wiggle of a module without an ID needs no protocol of its own: the module is given a free temporary ID (the
highest free one, so the chain's numbers stay free), moves its joint over ASM under it as every module does, and
has its ID erased again — each change a reset of the board, as a real one does. One request runs at a time (the
bus has one scan); another arriving meanwhile is refused at once, never queued behind a long list. Every refusal
names its cause: an ID outside 1..253 (0 erases), an ID another module holds (a commissioned one, or any node alive
on the bus, a Python module too), a serial no module answers to, a module that stops answering.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time
from collections.abc import Collection
from typing import Any

import can
import zenoh

from asm_module.commission_link import MAX_REQUEST
from asm_module.halts import read_halts
from asm_module.names import module_id
from asm_py.canbus.commission import (
    SERIAL_BYTES,
    UNCONFIGURED,
    Commissioner,
    CommissionOp,
    CommissionReply,
    CommissionScope,
    conflicts,
    parse_serial,
)
from asm_py.canbus.ids import MAX_NODE_ID, MIN_NODE_ID
from asm_py.errors import AsmError
from asm_py.keys import RobotKeys
from asm_py.node import Node
from asm_py.remote import RemoteAttribute

log = logging.getLogger("asm_robot.commission")
WIGGLE_DEGREES = (1.0, 30.0)
"""The least and most a wiggle moves a joint (default 15): seen by a person, harmless to a chain on the floor."""
ALIVE_TIMEOUT = 30.0
"""Seconds a board given an ID has to come up under it (it resets; an emulated one on a loaded machine is slow)."""
MOVE_TIMEOUT = 5.0
"""Seconds a wiggled joint has to get halfway there."""
ARRIVED = 1.0
"""Degrees short of the wiggle a joint counts as there (the answer said 8° of a 15° wiggle: it stopped watching
halfway, the joint still on its way)."""
SETTLED = 2.0
"""Seconds without progress after which a joint past halfway counts as stopped short. (0.4 s read a joint still on
its way as stopped at 12.5° of 15° when the emulated boards ran on a loaded machine: a fresh-clone run with four
test workers. 2 s since stop 54, for a physics starved of the CPU that holds a joint still longer; the 13.27° of 15°
taken then for such a stall was measured at stop 55 to be a true answer: the joint overshot to 16.7° and sat at
13.3° from its start, its chain moved by its neighbours' wiggles. A joint held short is answered a second later.)"""
FULL_MOVE_TIMEOUT = 2 * MOVE_TIMEOUT
"""Seconds a wiggled joint past halfway and still moving is watched, at most, before what it moved is the answer."""
ASM_TIMEOUT = 5.0
LATCH_TIMEOUT = 1.0
"""Seconds each module has to say whether its e-stop is latched before a commissioning operation."""
MAX_MODULE_ID = MAX_NODE_ID - 1
"""The highest ID a module is given: 254 is the tools' (a bridge's, asm-commission's own)."""


class Refused(ValueError):
    """A request the service will not carry out; the text says why."""


def _serial(request: dict[str, Any]) -> bytes:
    text = request.get("serial")
    if not isinstance(text, str):
        raise Refused(f"a serial is {2 * SERIAL_BYTES} hex digits, not {text!r}")
    try:
        return parse_serial(text)
    except ValueError as exc:
        raise Refused(str(exc)) from None


def _node_id(request: dict[str, Any], *, erase: bool) -> int:
    value = request.get("id")
    if not isinstance(value, int) or isinstance(value, bool):
        raise Refused(f"a node ID is a whole number, not {value!r}")
    if not (MIN_NODE_ID <= value <= MAX_MODULE_ID or (erase and value == UNCONFIGURED)):
        raise Refused(f"a module's node ID is {MIN_NODE_ID}..{MAX_MODULE_ID}" + (" (0 erases)" if erase else "") +
                      f", not {value}")  # fmt: skip
    return value


class CommissionService:
    """Answers ``asm/<robot>/@robot/commission`` on ``session`` for the bus ``bus_options`` opens; ``node`` is a CAN
    node on that bus (the bridge's) that moves joints. ``reserved``: node IDs no module may have on this bus (the
    bridge's own and the aliases it sends its Zenoh clients' requests from). ``close`` ends it."""

    def __init__(self, session: zenoh.Session, robot: str, bus_options: dict[str, Any], node: Node, *,
                 tool_id: int = 254, window: float = 0.3, reserved: Collection[int] = ()) -> None:  # fmt: skip
        self.node = node
        self.reserved = frozenset(reserved) | {tool_id}
        self.bus = can.Bus(**bus_options)
        self.tool = Commissioner(self.bus, tool_id=tool_id, window=window)
        self._lock = threading.Lock()
        self._running: str | None = None
        self._known: set[int] = set()
        """The IDs the last list found and those given since (the worker's)."""
        self._heard: tuple[float, str, str] | None = None
        """The last e-stop heard and not released: (time, source, reason)."""
        self._unlisten = node.on_estop(self._on_estop)
        self._jobs: queue.Queue[tuple[zenoh.Query, dict[str, Any]] | None] = queue.Queue()
        self._thread = threading.Thread(target=self._work, name="asm-robot-commission", daemon=True)
        self._thread.start()
        self.key = RobotKeys(robot).commission()
        try:
            self._queryable = session.declare_queryable(self.key, self._on_query)
        except BaseException:
            self.close()
            raise

    # -- the queryable: parse, refuse what is wrong or comes while busy, hand the rest to the worker -------------

    def _reply(self, query: zenoh.Query, answer: dict[str, Any]) -> None:
        try:
            query.reply(self.key, json.dumps(answer))
        except zenoh.ZError as exc:  # the asker gave up (timed out) or the session is closing
            log.debug("commission reply not sent: %s", exc)
        finally:
            query.drop()

    def _on_query(self, query: zenoh.Query) -> None:
        raw = query.payload.to_bytes() if query.payload is not None else b""
        try:
            if len(raw) > MAX_REQUEST:
                raise Refused(f"a commissioning request has at most {MAX_REQUEST} bytes, not {len(raw)}")
            try:
                request = json.loads(raw)
            except (ValueError, UnicodeDecodeError) as exc:
                raise Refused(f"a commissioning request is JSON: {exc}") from None
            if not isinstance(request, dict) or request.get("op") not in ("list", "wiggle", "assign", "release"):
                raise Refused('a commissioning request is {"op": "list"|"wiggle"|"assign"|"release", …}')
            if request["op"] == "release":  # at once, even while another request runs: it only clears a record
                self._reply(query, self.release())
                return
            with self._lock:
                if self._running is not None:
                    raise Refused(f"busy: another commissioning request ({self._running}) is still running")
                self._running = str(request["op"])
        except Refused as refusal:
            self._reply(query, {"error": str(refusal)})
            return
        self._jobs.put((query, request))

    def _work(self) -> None:
        while (job := self._jobs.get()) is not None:
            query, request = job
            try:
                answer = self.handle(request)
            except (Refused, LookupError, TimeoutError, ValueError) as exc:
                answer = {"error": str(exc)}
            except Exception as exc:  # a bus error, a module's refusal: said to the asker, the service goes on
                log.exception("commissioning request %s failed", request)
                answer = {"error": f"{type(exc).__name__}: {exc}"}
            finally:
                with self._lock:
                    self._running = None
            self._reply(query, answer)

    # -- the operations (also called directly: a robot's own code, tests) ------------------------------------------

    def handle(self, request: dict[str, Any]) -> dict[str, Any]:
        op = request.get("op")
        if op == "list":
            return self.list()
        if op == "release":
            return self.release()
        if op == "assign":
            serial, node_id = _serial(request), _node_id(request, erase=True)
            self._refuse_while_stopped("an ID given or erased resets the board")
            return self.assign(serial, node_id)
        if op == "wiggle":
            degrees = request.get("degrees", 15.0)
            if not isinstance(degrees, (int, float)) or isinstance(degrees, bool) or not math.isfinite(degrees) \
                    or not WIGGLE_DEGREES[0] <= degrees <= WIGGLE_DEGREES[1]:  # fmt: skip
                raise Refused(f"a wiggle moves {WIGGLE_DEGREES[0]:g}-{WIGGLE_DEGREES[1]:g}°, not {degrees!r}")
            self._refuse_while_stopped("a wiggle moves a joint and may lend the board an ID (a reset)")
            if "serial" in request:
                return self.wiggle_serial(_serial(request), float(degrees))
            return self.wiggle_id(_node_id(request, erase=False), float(degrees))
        raise Refused(f"no commissioning operation {op!r}")

    def list(self) -> dict[str, Any]:
        # in one order every time (numbered by ID, then the unnumbered by serial), as asm-commission lists them: the
        # scan's own order follows which board answered first
        found = sorted(self.tool.discover(CommissionScope.EVERY),
                       key=lambda m: (m.node_id == UNCONFIGURED, m.node_id, m.serial))  # fmt: skip
        self._known = {m.node_id for m in found} - {UNCONFIGURED}
        return {"modules": [{"serial": m.serial_hex, "id": m.node_id} for m in found],
                "conflicts": {str(k): [s.hex() for s in v] for k, v in conflicts(found).items()}}  # fmt: skip

    def _refuse_while_stopped(self, why: str) -> None:
        """Refused while an e-stop heard on the bus is not released (a module without an ID does not latch: the
        service does, for it), or any module alive on the bus has its e-stop latched or runs a gait (asm_module.halts);
        ``why`` says what the operation would do (a board reset releases its latch; a wiggle moves a joint)."""
        refusal = read_halts(self.node, [f"m{i}" for i in sorted(self._alive_ids())], LATCH_TIMEOUT).refusal(why)
        if refusal is not None:  # the modules that hold a latch, named first: what the user releases
            raise Refused(refusal)
        heard = self._heard
        if heard is not None:
            at, source, reason = heard
            raise Refused(f"refused: an e-stop was heard at {time.strftime('%H:%M:%S', time.localtime(at))} from "
                          f"{source}{': ' + reason if reason else ''} and commissioning was not released since; "
                          f"{why}, which the e-stop forbids: release it first (the studio's E-STOP Release, or "
                          '{"op": "release"})')  # fmt: skip

    def stopped(self) -> bool:
        """Latched on an e-stop and not released since (the robot's status says it)."""
        return self._heard is not None

    def _on_estop(self, source: str, reason: str) -> None:
        """Every e-stop the bus carries (the bridge's node hears its own and those it forwards from Zenoh): latched
        here until released, as a module latches (on the receive thread: a tuple assigned, nothing else)."""
        self._heard = (time.time(), source, reason)

    def release(self) -> dict[str, Any]:
        """Release the service's own latch (the modules' latches are each module's: released over ASM)."""
        heard, self._heard = self._heard, None
        if heard is not None:
            log.info("commissioning released after the e-stop from %s", heard[1])
        return {"released": heard is not None}

    def _alive_ids(self) -> set[int]:
        """The node IDs alive on the bus now (heard by the bridge's node): modules of every kind."""
        names = self.node.transport.peers()
        return {i for i in map(module_id, names) if i is not None}

    def _current_id(self, serial: bytes) -> int:
        node_id = self.tool.select(serial)
        self.tool.send(CommissionOp.UNMUTE)
        if node_id is None:
            raise LookupError(f"no module with serial {serial.hex()} answers")
        return node_id

    def assign(self, serial: bytes, node_id: int) -> dict[str, Any]:
        if node_id in self.reserved:
            raise Refused(
                f"node ID {node_id} is reserved on this bus (the bridge's own, or an alias it sends its "
                f"Zenoh clients' requests from: {min(self.reserved)}..{max(self.reserved)})"
            )
        current = self._current_id(serial)
        if node_id != UNCONFIGURED and node_id != current:
            holders = self._holders(node_id)
            if holders or node_id in self._alive_ids():
                held = f"module {holders[0]}" if holders else "a module alive on the bus"
                raise Refused(f"node ID {node_id} is taken by {held}: IDs are never shared")
        self.tool.assign(serial, node_id)
        self._known.add(node_id)
        log.info("module %s: node ID %d -> %d", serial.hex(), current, node_id)
        return {"serial": serial.hex(), "id": node_id}

    def _holders(self, node_id: int) -> list[str]:
        """The serials of the modules with ``node_id`` (one not heard on the bus yet: just given it). A first scan
        with one repetition, not the tool's three (an empty scan's every repetition is a wait, and it is the common
        case); only if something answers — the holder, or a late answer to an earlier scan — the whole search."""
        time.sleep(min(0.5, 2 * (self.tool.rtt or 0.05)))  # the answers to the last scan arrive, to be drained
        retries, self.tool.retries = self.tool.retries, 1
        try:
            answered = self.tool.ask(CommissionOp.SCAN, CommissionScope.NODE_ID, node_id, kind=CommissionReply.BYTE)
        finally:
            self.tool.retries = retries
            self.tool.send(CommissionOp.UNMUTE)
        if answered is None:
            return []
        return [m.serial_hex for m in self.tool.discover(CommissionScope.NODE_ID, node_id)]

    def _free_id(self) -> int:
        """The highest ID nobody has (the chain's numbers from 1 stay free): not alive on the bus, not reserved, not
        listed or given since (a module given an ID is alive under it within a heartbeat), and no module answering
        a scan for it."""
        taken = self._alive_ids() | self.reserved | self._known
        for node_id in range(MAX_MODULE_ID, MIN_NODE_ID - 1, -1):
            if node_id not in taken and not self._holders(node_id):
                return node_id
        raise Refused("no node ID is free for a temporary one")

    def wiggle_serial(self, serial: bytes, degrees: float) -> dict[str, Any]:
        current = self._current_id(serial)
        if current != UNCONFIGURED:
            return self.wiggle_id(current, degrees)
        temporary = self._free_id()
        self.tool.assign(serial, temporary)
        try:
            moved = self._wiggle(temporary, degrees)
        finally:
            self.tool.assign(serial, UNCONFIGURED)
        return {"serial": serial.hex(), "id": UNCONFIGURED, "temporary": temporary, "moved": moved}

    def wiggle_id(self, node_id: int, degrees: float) -> dict[str, Any]:
        if node_id in self.reserved:  # no module has it: refused at once (it waited 30 s for "did not answer")
            raise Refused(f"node ID {node_id} is reserved on this bus (the bridge's own, or its aliases): no module "
                          "has it")  # fmt: skip
        return {"id": node_id, "temporary": None, "moved": self._wiggle(node_id, degrees)}

    def _joint(self, name: str) -> tuple[RemoteAttribute, RemoteAttribute]:
        """Module ``name``'s joint.goal and joint.angle, looked up again until ALIVE_TIMEOUT while it is not there
        (a board given an ID resets into it: it may be heard once, then be gone for its reboot)."""
        deadline = time.monotonic() + ALIVE_TIMEOUT
        while True:
            try:
                if name not in self.node.transport.peers():
                    raise LookupError(f"{name} is not on the bus")
                goal = self.node.lookup(name, "joint.goal", timeout=ASM_TIMEOUT)
                angle = self.node.lookup(name, "joint.angle", timeout=ASM_TIMEOUT)
                if not isinstance(goal, RemoteAttribute) or not isinstance(angle, RemoteAttribute):
                    raise Refused(f"{name} has no joint.goal and joint.angle attributes to wiggle")
                return goal, angle
            except (LookupError, TimeoutError, AsmError) as exc:
                if time.monotonic() > deadline:
                    raise TimeoutError(f"{name} did not answer within {ALIVE_TIMEOUT:g} s: {exc}") from exc
                time.sleep(0.2)

    def _wiggle(self, node_id: int, degrees: float) -> float:
        """Move module ``node_id``'s joint ``degrees`` away and back over ASM; how far it was seen to move."""
        name = f"m{node_id}"
        goal, angle = self._joint(name)
        home = float(goal.get(timeout=ASM_TIMEOUT))
        start = float(angle.get(timeout=ASM_TIMEOUT))
        target = home - degrees if home > 0 else home + degrees  # towards the middle of its range
        moved = 0.0
        goal.set(target, wait=True, timeout=ASM_TIMEOUT)
        try:  # until it is there (within ARRIVED), or has got halfway and stopped moving, or the time is up
            began = progressed = time.monotonic()
            while moved < degrees - ARRIVED:
                elapsed = time.monotonic() - began
                if elapsed > FULL_MOVE_TIMEOUT or (moved < degrees / 2 and elapsed > MOVE_TIMEOUT):
                    break
                if self._heard is not None:  # the module latched and holds: nothing more is asked of it
                    raise Refused(f"stopped: an e-stop was heard during the wiggle of {name} (it moved {moved:.1f}°"
                                  " and holds there)")  # fmt: skip
                now = abs(float(angle.get(timeout=ASM_TIMEOUT)) - start)
                if now > moved + 0.1:
                    moved, progressed = now, time.monotonic()
                elif moved >= degrees / 2 and time.monotonic() - progressed > SETTLED:
                    break  # a limit or a load holds it short: what it moved is the answer
                time.sleep(0.05)
        finally:
            if self._heard is None:  # after an e-stop the goal stays where the latch holds it
                goal.set(home, wait=True, timeout=ASM_TIMEOUT)
        deadline = time.monotonic() + MOVE_TIMEOUT  # back before the answer: the next wiggle starts from rest
        while abs(float(angle.get(timeout=ASM_TIMEOUT)) - start) > 1.0 and time.monotonic() < deadline:
            if self._heard is not None:  # on its way back: it holds where the latch caught it, and the answer says so
                raise Refused(f"stopped: an e-stop was heard during the wiggle of {name} (on its way back; it holds "
                              "there)")  # fmt: skip
            time.sleep(0.05)
        if moved < degrees / 2:
            raise TimeoutError(f"{name}'s joint moved {moved:.1f}° of {degrees:g}° in {MOVE_TIMEOUT:g} s "
                               "(is its servo on, is it e-stopped?)")  # fmt: skip
        return round(moved, 2)

    def close(self) -> None:
        self._unlisten()
        queryable = getattr(self, "_queryable", None)
        if queryable is not None:
            try:
                queryable.undeclare()
            except zenoh.ZError:
                log.debug("already undeclared", exc_info=True)
            self._queryable = None
        self._jobs.put(None)
        self._thread.join(timeout=ALIVE_TIMEOUT + 10)
        self.bus.shutdown()
