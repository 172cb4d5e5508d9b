"""The page's link to one robot: everything the panels do to a robot goes through here, and nothing here claims
what the robot did not confirm.

A :class:`RobotLink` owns the page's ASM node (a *tool* of that robot: asm_py.keys), the robot's feed (poses,
status, model: web/live.py) and the roster, and watches that the robot is there: the robot process's liveliness
token vanishes the moment the process does, and its status arrives once a second — either gone, the link says the
robot is **lost**, and the operations that would move it (deploy, start, drive) refuse until it is back.

The E-STOP is sent to every module of this robot (and only this robot), then read back from each module, resent to
those that have not latched, and reported per module: which latched, which could not be reached.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Collection, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import zenoh

from asm_module.commission_link import CommissionError, commission
from asm_module.feed import RobotStatus
from asm_module.names import module_name
from asm_py import Node
from asm_py.keys import RobotKeys
from asm_py.transport.zenoh import ZenohTransport
from gaits.calls import DeployError, ModuleCalls
from gaits.deploy import DeployReport, activate, deploy, release_all, start_all, stop_all
from gaits.drive import drive
from gaits.model import Gait

from .live import LiveFeed
from .monitor import Roster

log = logging.getLogger("asm_studio.link")

STATUS_STALE = 3.0
"""Seconds without a status after which a robot that still holds its token is reported lost (wedged)."""
ESTOP_ROUNDS = 3
"""Times the E-STOP is sent to modules that have not confirmed it."""
ESTOP_READ_TIMEOUT = 0.3
COMMISSION_RELEASE_TIMEOUT = 3.0
"""Seconds the robot's commissioning service has to answer a release (it answers at once, even while busy)."""


class RobotLost(RuntimeError):
    """The robot is not there: nothing that would move it is sent."""


@dataclass
class EstopReport:
    """What an E-STOP achieved, as the modules confirmed it."""

    robot: str
    latched: list[str] = field(default_factory=list)
    """Modules that read back latched."""
    unconfirmed: list[str] = field(default_factory=list)
    """Modules the page knows of that did not confirm (unreachable, or not latched)."""
    lost: bool = False
    """The robot was lost when the E-STOP was pressed: nothing can have confirmed it."""

    @property
    def confirmed(self) -> bool:
        return bool(self.latched) and not self.unconfirmed and not self.lost

    def text(self) -> str:
        if self.lost:
            return (f"sent, but robot {self.robot!r} is LOST: no module confirmed it — check the robot itself "
                    f"({len(self.latched)} latched)")  # fmt: skip
        if not self.latched and not self.unconfirmed:
            return f"sent to robot {self.robot!r}, which shows no modules: nothing confirmed it"
        done = f"latched on {len(self.latched)} of {len(self.latched) + len(self.unconfirmed)} modules (read back)"
        if self.unconfirmed:
            return f"{done}; NOT CONFIRMED by {', '.join(self.unconfirmed)}"
        return f"{done}: gaits stopped, joints holding"


class RobotLink:
    """The page's attachment to robot ``node.transport.robot``; see the module docstring. ``close`` ends it."""

    def __init__(self, node: Node) -> None:
        if not isinstance(node.transport, ZenohTransport) or node.transport.robot is None:
            raise TypeError("a robot link needs a node on a Zenoh transport (a tool of the robot)")
        self.node = node
        self.transport: ZenohTransport = node.transport
        self.robot: str = node.transport.robot
        self.session: zenoh.Session = self.transport.session
        self.keys = RobotKeys(self.robot)
        self.feed = LiveFeed(self.session, self.robot)
        self.roster = Roster(node)
        self._lock = threading.Lock()
        self._tokens: set[str] = set()
        self._changed_at = time.monotonic()
        self._on_change: list[Callable[[bool], None]] = []
        self._liveliness = self.session.liveliness().declare_subscriber(
            self.keys.robot_alive(), self._on_alive, history=True
        )
        self._pool = ThreadPoolExecutor(max_workers=8, thread_name_prefix="studio-link")

    # -- is the robot there --------------------------------------------------------------------------------------

    def _on_alive(self, sample: zenoh.Sample) -> None:
        session = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            before = bool(self._tokens)
            if sample.kind == zenoh.SampleKind.PUT:
                self._tokens.add(session)
            else:
                self._tokens.discard(session)
            now = bool(self._tokens)
            if before != now:
                self._changed_at = time.monotonic()
            callbacks = list(self._on_change) if before != now else []
        for callback in callbacks:
            callback(now)

    def on_presence(self, callback: Callable[[bool], None]) -> None:
        """Call ``callback(present)`` when the robot process appears or vanishes (on a Zenoh thread)."""
        self._on_change.append(callback)

    @property
    def status(self) -> RobotStatus | None:
        return self.feed.status

    def lost(self) -> str | None:
        """Why the robot is lost, or None while it is there."""
        with self._lock:
            present, since = bool(self._tokens), time.monotonic() - self._changed_at
        if not present:
            return f"robot {self.robot!r} is not on the network (for {since:.1f} s)"
        age = self.feed.status_age()
        if age is not None and min(age, since) > STATUS_STALE:  # a robot that just came back has a moment
            return f"robot {self.robot!r} has sent no status for {age:.1f} s"
        return None

    def await_present(self, timeout: float) -> bool:
        """Wait up to ``timeout`` for the robot to be there (:meth:`lost` None); whether it is. A robot the studio
        has just restarted is back on the network a moment after its modules are heard."""
        deadline = time.monotonic() + timeout
        while self.lost() is not None:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.1)
        return True

    def require(self, action: str) -> None:
        """RobotLost, naming ``action``, when the robot is lost."""
        why = self.lost()
        if why is not None:
            raise RobotLost(f"{action} refused: {why}")

    # -- modules -------------------------------------------------------------------------------------------------

    def modules(self) -> list[str]:
        """The module nodes the roster knows (m1, m2, …), alive or lost, in module order."""
        names = [name for name, _, _ in self.roster.rows() if name.startswith("m") and name[1:].isdigit()]
        return sorted(names, key=lambda n: int(n[1:]))

    def forget(self, names: Sequence[str]) -> None:
        """Nodes closed on purpose (a rebuilt robot): no longer listed, not even as lost."""
        self.roster.forget(list(names))

    def await_modules(self, names: set[str], timeout: float) -> bool:
        """Wait up to ``timeout`` for discovery to list every one of ``names``; whether it did."""
        deadline = time.monotonic() + timeout
        while not names <= set(self.node.discover()):
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.1)
        return True

    def alive_modules(self) -> list[str]:
        return [n for n in self.roster.alive() if n.startswith("m") and n[1:].isdigit()]

    def lookup(self, node: str, name: str, timeout: float = 2.0) -> Any:
        return self.node.lookup(node, name, timeout=timeout)

    def list_objects(self, node: str, timeout: float = 2.0) -> list[Any]:
        return self.node.list_objects(node, timeout=timeout)

    def lease_holder(self) -> str | None:
        """Who holds the robot's deploy lease (read from its first module), or None when it is free."""
        modules = self.alive_modules()
        if not modules:
            return None
        try:
            lease = self.lookup(modules[0], "gait.lease", timeout=0.5).peek(timeout=0.5)
        except Exception:
            return None
        return lease["holder"] or None if isinstance(lease, dict) else None

    # -- what moves the robot, or stops it -----------------------------------------------------------------------

    def estop(self, reason: str = "studio E-STOP") -> EstopReport:
        """Stop every module of this robot, read each one back, resend to those that did not latch; see the module
        docstring."""
        report = EstopReport(self.robot, lost=self.lost() is not None)
        modules = self.modules()
        calls = ModuleCalls(self.node, dict(enumerate(modules, start=1)), ESTOP_READ_TIMEOUT, 1)
        waiting = list(range(1, len(modules) + 1))
        for _ in range(ESTOP_ROUNDS):
            self.node.estop(reason)
            latched = list(self._pool.map(lambda m: _latched(calls, m), waiting))
            waiting = [m for m, yes in zip(waiting, latched, strict=True) if not yes]
            if not waiting:
                break
        report.latched = [modules[m - 1] for m in range(1, len(modules) + 1) if m not in waiting]
        report.unconfirmed = [modules[m - 1] for m in waiting]
        return report

    def release(self, modules: Sequence[str]) -> list[str]:
        return release_all(self.node, modules)

    def release_commissioning(self) -> bool:
        """Release the latch of the robot's commissioning service (it latches on every e-stop: a module without an
        ID cannot); False when it held none, or the robot has no such service."""
        try:
            answer = commission(self.session, self.robot, {"op": "release"}, timeout=COMMISSION_RELEASE_TIMEOUT)
        except (TimeoutError, CommissionError, zenoh.ZError) as exc:
            log.debug("no commissioning latch released: %s", exc)
            return False
        return bool(answer.get("released"))

    def stage(self, gait: Gait, progress: Callable[[int, int, str], None],
              accept: Collection[str] = ()) -> DeployReport:  # fmt: skip
        """Deploy steps 1-3 under a lease that stays held (gaits/deploy.py) until :meth:`start` or ``cancel``;
        RobotMismatch when a module says it is another type than the gait describes, unless its line is in
        ``accept`` (the user was asked)."""
        self.require("deploy")
        return deploy(self.node, gait, progress=progress, start=False, accept=accept)

    def start(self, report: DeployReport) -> DeployReport:
        self.require("start")
        return activate(self.node, report)

    def start_all(self, names: Sequence[str]) -> list[str]:
        self.require("start")
        return start_all(self.node, names)

    def stop_all(self) -> None:
        stop_all(self.node)

    def drive(self, gait: Gait, command: str, names: Sequence[str], direction: int) -> list[str]:
        self.require("drive")
        return drive(self.node, gait, command, names, direction=direction)

    def signal(self, number: int) -> None:
        from asm_module.neighbours import send_signal

        self.require("signal")
        send_signal(self.node, number)

    def module_names(self, gait: Gait) -> list[str]:
        return [module_name(a.id) for a in gait.modules]

    def close(self) -> None:
        try:
            self._liveliness.undeclare()
        except zenoh.ZError:
            log.debug("already undeclared", exc_info=True)
        self._pool.shutdown(wait=True)
        self.roster.close()
        self.feed.close()
        self.node.close()


def _latched(calls: ModuleCalls, module: int) -> bool:
    try:
        return bool(calls.peek(module, "estop", "e-stop read-back"))
    except DeployError:
        return False
