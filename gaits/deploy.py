"""Deploying a gait to modules — simulated or real, over any transport — as a transaction, through ASM objects only.

A deploy never leaves a robot half running a new gait (docs/protocol.md §9, "Deployment"):

1. **check** — every table fits one message (nothing is sent otherwise);
2. **lease** — take ``gait.lease`` on every module, in module order, so a second deployer is told who holds the
   robot and changes nothing; a module whose e-stop is latched refuses the lease (ESTOP);
3. **stage** — write each module's ``gait.staged`` record (table, phase, direction, deploy ID) and read back
   ``gait.staged_checksum``; the modules keep running what they ran;
4. **activate** — one group SET of ``gait.activate`` = deploy ID to every module; each switches to its staged gait
   and starts it. The tool then reads back every module's ``gait.activate`` and ``gait.service`` and resends the
   broadcast to the ones that have not confirmed (an activation is idempotent), until the deadline;
5. **release** the leases.

A failure in steps 1-3 changes no module's gait and names the module and the step. Should activation not be
confirmed by every module in time, the tool stops every module's gait (so none runs another's gait) and says which
modules confirmed. Every call has a deadline, and calls that can be repeated safely are retried on a timeout, so
a lost frame costs a retry, never a hang.
"""

from __future__ import annotations

import os
import secrets
import socket
import time
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from asm_py import Node
from asm_py.errors import AsmError, AsmTimeout, EstopLatched
from asm_py.module.wire import Staged, checksum, encode_program, encode_staged
from asm_py.remote import RemoteObject
from asm_py.transport.base import BROADCAST

from .model import Gait
from .programs import module_program

MODULE_IDS = range(1, 200)
"""Node IDs modules may take: 200-253 are the bridge's aliases for Zenoh clients, 254 the bridge."""
LEASE_SECONDS = 30.0
"""How long a deployer holds the robot at most (it releases the lease when done)."""


class DeployError(AsmError):
    """A module could not be given its part of the gait (which module, and at which step, are in the message)."""


@dataclass
class DeployReport:
    """What a deploy did, as the modules confirmed it."""

    gait: str
    deploy_id: int
    checksums: dict[int, int] = field(default_factory=dict)
    """Module ID → CRC-32 of the staged record it reported (equal to what was sent)."""
    running: list[int] = field(default_factory=list)
    """Modules that confirmed running this deployment (empty when it was staged only)."""


def module_name(module_id: int) -> str:
    """The node name of gait module ``module_id`` (the studio and ``asm-module`` use it: m1, m2, …)."""
    return f"m{module_id}"


def module_tables(gait: Gait) -> dict[int, bytes]:
    """Each module's ``gait.table`` bytes."""
    return {a.id: encode_program(module_program(gait, a.id)) for a in gait.modules}


def default_holder(node: Node) -> str:
    """Who a lease names: the deploying node, its host and process, so a second deployer knows whom to ask."""
    return f"{node.name}@{socket.gethostname()}:{os.getpid()}"[:64]


_LOOKUPS: weakref.WeakKeyDictionary[Node, dict[tuple[str, str], RemoteObject]] = weakref.WeakKeyDictionary()
"""Client objects a deploying node looked up, kept across deploys: a lookup is a round trip, and a module that
restarted with other objects answers NOT_FOUND, after which the object is looked up again."""


class _Modules:
    """The deploying side's view of the modules: client objects looked up once, calls retried on timeouts."""

    def __init__(self, node: Node, names: dict[int, str], timeout: float, attempts: int) -> None:
        self.node = node
        self.names = names
        self.timeout = timeout
        self.attempts = attempts
        self._objects = _LOOKUPS.setdefault(node, {})

    def call(self, module: int, step: str, operation: Callable[[], object]) -> object:
        """Run ``operation`` (repeatable), retrying timeouts; DeployError naming the module and step otherwise."""
        for attempt in range(self.attempts):
            try:
                return operation()
            except AsmTimeout as exc:
                if attempt + 1 == self.attempts:
                    raise DeployError(f"module {module} ({self.names[module]}), {step}: {exc}") from exc
            except (AsmError, ValueError, LookupError, TypeError, PermissionError) as exc:
                raise DeployError(f"module {module} ({self.names[module]}), {step}: {exc}") from exc
        raise AssertionError("unreachable")

    def obj(self, module: int, name: str, step: str) -> RemoteObject:
        key = (self.names[module], name)
        if key not in self._objects:
            self._objects[key] = self.call(  # type: ignore[assignment]
                module, step, lambda: self.node.lookup(self.names[module], name, timeout=self.timeout)
            )
        return self._objects[key]

    def on(self, module: int, name: str, step: str, operation: Callable[[RemoteObject], object]) -> object:
        """``operation(obj)`` on the module's object ``name``; looked up again once if the module no longer has it
        (it restarted)."""
        try:
            return self.call(module, step, lambda: operation(self.obj(module, name, step)))
        except DeployError as exc:
            if not isinstance(exc.__cause__, LookupError):
                raise
            self._objects.pop((self.names[module], name), None)
            return self.call(module, step, lambda: operation(self.obj(module, name, step)))

    def peek(self, module: int, name: str, step: str) -> object:
        return self.on(module, name, step, lambda obj: obj.peek())  # type: ignore[attr-defined]

    def set(self, module: int, name: str, value: object, step: str) -> None:
        self.on(module, name, step, lambda obj: obj.set(value, timeout=self.timeout))  # type: ignore[attr-defined]

    def running(self, module: int, step: str) -> bool:
        return bool(self.on(module, "gait.service", step, lambda obj: obj.running))  # type: ignore[attr-defined]

    def check_not_latched(self, modules: Sequence[int], step: str) -> None:
        latched = [m for m in modules if self.peek(m, "estop", step)]
        if latched:
            listed = ", ".join(f"module {m} ({self.names[m]})" for m in latched)
            raise DeployError(f"{step}: the emergency stop is latched on {listed}; release it first")


def deploy(
    node: Node,
    gait: Gait,
    *,
    name_of: Callable[[int], str] = module_name,
    direction: int = 1,
    progress: Callable[[int, int, str], None] | None = None,
    timeout: float = 2.0,
    attempts: int = 3,
    start: bool = True,
    deadline: float | None = None,
    holder: str | None = None,
) -> DeployReport:
    """Stage, verify and (``start``) activate ``gait`` on its modules; see the module docstring.

    ``progress(done, total, message)`` is called after each module is staged and after activation. ``direction``
    -1 deploys the gait reversed. ``timeout`` bounds each call, ``attempts`` how often a timed-out call is tried,
    ``deadline`` (seconds, default 2 s + 0.25 s per module) the activation's confirmation. With ``start`` False the
    gait is staged only: :func:`activate` starts it later.
    """
    tables = module_tables(gait)
    deploy_id = secrets.randbits(32) or 1
    records = {}
    for a in gait.modules:  # step 1: sizes, before anything is sent
        try:
            records[a.id] = encode_staged(Staged(deploy_id, a.phase, a.direction * direction, tables[a.id]))
        except ValueError as exc:
            raise DeployError(f"module {a.id} ({name_of(a.id)}), check: {exc}") from None
    modules = _Modules(node, {a.id: name_of(a.id) for a in gait.modules}, timeout, attempts)
    ids = sorted(records)
    report = DeployReport(gait.name, deploy_id)
    lease = {"holder": holder or default_holder(node), "token": deploy_id, "seconds": LEASE_SECONDS}
    leased: list[int] = []
    try:
        for module in ids:  # step 2, in module order: two deployers never each hold part of the robot
            try:
                modules.set(module, "gait.lease", lease, "lease")
            except DeployError as exc:
                if isinstance(exc.__cause__, EstopLatched):
                    raise DeployError(f"lease: the emergency stop is latched on module {module} "
                                      f"({modules.names[module]}); release it first") from None  # fmt: skip
                raise
            leased.append(module)
        for done, module in enumerate(ids, start=1):  # step 3
            data = records[module]
            modules.set(module, "gait.staged", data, "stage")
            reported = modules.peek(module, "gait.staged_checksum", "verify")
            if reported != checksum(data):
                raise DeployError(f"module {module} ({modules.names[module]}), verify: checksum {reported:#010x}, "
                                  f"sent {checksum(data):#010x}")  # fmt: skip
            report.checksums[module] = reported  # type: ignore[assignment]
            if progress is not None:
                progress(
                    done, len(ids), f"module {module} staged and verified ({len(data)} bytes, crc {reported:#010x})"
                )
        if start:
            _activate(node, modules, report, ids, deadline, progress)
    finally:
        for module in leased:  # step 5, best effort: a lease also expires by itself
            try:
                modules.set(module, "gait.lease", {**lease, "seconds": 0.0}, "release")
            except DeployError:
                pass
    return report


def activate(
    node: Node,
    report: DeployReport,
    *,
    name_of: Callable[[int], str] = module_name,
    timeout: float = 2.0,
    attempts: int = 3,
    deadline: float | None = None,
) -> DeployReport:
    """Activate a deployment staged by ``deploy(..., start=False)`` (steps 4 of the module docstring)."""
    ids = sorted(report.checksums)
    modules = _Modules(node, {m: name_of(m) for m in ids}, timeout, attempts)
    modules.check_not_latched(ids, "activate")
    _activate(node, modules, report, ids, deadline, None)
    return report


def _activate(
    node: Node,
    modules: _Modules,
    report: DeployReport,
    ids: list[int],
    deadline: float | None,
    progress: Callable[[int, int, str], None] | None,
) -> None:
    until = time.monotonic() + (deadline if deadline is not None else 2.0 + 0.25 * len(ids))
    activation = node.group(BROADCAST).attribute("gait.activate", "uint32")
    waiting = list(ids)
    while True:
        activation.set(report.deploy_id)
        time.sleep(0.02)
        waiting = [m for m in waiting if not _confirmed(modules, m, report.deploy_id)]
        if not waiting or time.monotonic() >= until:
            break
    report.running = [m for m in ids if m not in waiting]
    if waiting:
        stop_all(node)
        listed = ", ".join(f"module {m} ({modules.names[m]})" for m in waiting)
        raise DeployError(f"activate: {listed} did not confirm running deployment {report.deploy_id:#010x}; every "
                          f"module's gait was stopped, so none runs another gait than the rest")  # fmt: skip
    if progress is not None:
        progress(len(ids), len(ids), f"{len(ids)} modules confirmed running {report.gait}")


def _confirmed(modules: _Modules, module: int, deploy_id: int) -> bool:
    try:
        return modules.peek(module, "gait.activate", "activate") == deploy_id and modules.running(module, "activate")
    except DeployError:
        return False


def start_all(
    node: Node, modules: Sequence[str] = (), *, group: str = BROADCAST, timeout: float = 2.0, attempts: int = 3
) -> list[str]:
    """Start every module's gait at once (one group message, each at its own gait.phase).

    With ``modules`` (node names), refuse before sending when any of them has its e-stop latched, and confirm
    afterwards that each one runs; DeployError names those that do not. Returns the modules confirmed running.
    """
    by_index = dict(enumerate(modules, start=1))
    checker = _Modules(node, by_index, timeout, attempts)
    checker.check_not_latched(list(by_index), "start")
    node.group(group).service("gait.service").start()
    if not modules:
        return []
    deadline = time.monotonic() + timeout
    missing = list(by_index)
    while missing and time.monotonic() < deadline:
        time.sleep(0.02)
        missing = [m for m in missing if not _running(checker, m)]
    if missing:
        raise DeployError(f"start: {', '.join(by_index[m] for m in missing)} did not confirm running")
    return list(modules)


def _running(modules: _Modules, module: int) -> bool:
    try:
        return modules.running(module, "start")
    except DeployError:
        return False


def stop_all(node: Node, group: str = BROADCAST) -> None:
    """Stop every module's gait (one group message, sent three times: a stop must not be lost to one frame)."""
    service = node.group(group).service("gait.service")
    for _ in range(3):
        service.stop()


def release_all(node: Node, modules: Sequence[str], *, timeout: float = 2.0, attempts: int = 3) -> list[str]:
    """Release the e-stop of each module (node names) — set its ``estop`` to false, confirmed — and return those
    released; DeployError names the modules that could not be released (the others are released all the same)."""
    by_index = dict(enumerate(modules, start=1))
    checker = _Modules(node, by_index, timeout, attempts)
    released, failed = [], []
    for index, name in by_index.items():
        try:
            checker.set(index, "estop", False, "release")
            released.append(name)
        except DeployError as exc:
            failed.append(str(exc))
    if failed:
        raise DeployError(f"released {len(released)} of {len(modules)} modules; " + "; ".join(failed))
    return released
