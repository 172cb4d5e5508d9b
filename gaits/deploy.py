"""Deploying a gait to modules — simulated or real, over any transport — as a transaction, through ASM objects only.

A deploy never leaves a robot half running a new gait (docs/protocol.md §9, "Deployment"):

1. **check** — every table fits one message, and every module that says its type (``module.type``) is of the type
   the gait describes for it (gaits/compatible.py), unless the caller accepts the difference (``accept``: the lines
   a user was shown and said yes to); nothing is sent otherwise (:class:`RobotMismatch` lists what differs);
2. **lease** — take ``gait.lease`` on every module, in module order, so a second deployer is told who holds the
   robot and changes nothing; a module whose e-stop is latched refuses the lease (ESTOP). The lease is held, and
   renewed, until the deploy ends — through the user's "Start" and any cleanup (gaits/lease.py);
3. **stage** — write each module's ``gait.staged`` record (table, phase, direction, deploy ID) and read back
   ``gait.staged_checksum``; the modules keep running what they ran;
4. **activate** — one group SET of ``gait.activate`` = deploy ID to every module; each switches to its staged gait
   and starts it. The tool then reads back every module's ``gait.activate`` and ``gait.service`` and resends the
   broadcast to the ones that have not confirmed (an activation is idempotent), until the deadline;
5. **release** the lease.

A failure in steps 1-3 changes no module's gait and names the module and the step. Should activation not be
confirmed by every module in time, the tool — still holding the lease, so no other deployer can have started
anything — stops every module's gait (so none runs another's gait) and says which modules confirmed. Every call has
a deadline that adapts to the round trips measured (gaits/calls.py), and calls that can be repeated safely are
retried on a timeout, so a lost frame costs a short retry, never a hang.

``deploy(..., start=False)`` stops after step 3 and returns a report that still holds the lease: :func:`activate`
starts it later (after a user said so), :meth:`DeployReport.cancel` gives it up.
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field
from typing import Any

from asm_module._profile import FIRMWARE_STATES
from asm_module.names import module_name
from asm_module.wire import Staged, checksum, encode_program, encode_staged
from asm_py import Node
from asm_py.transport.base import BROADCAST

from .calls import DeployError, ModuleCalls
from .compatible import commanded, type_mismatch
from .lease import Lease, default_holder
from .model import Gait
from .programs import module_program

__all__ = ["DeployError", "DeployReport", "RobotMismatch", "activate", "deploy", "module_name", "module_tables",
           "release_all", "start_all", "stop_all"]  # fmt: skip

CALL_TIMEOUT = 2.0
"""Seconds one call to a module may take at most (the adaptive timeout is usually far shorter)."""


class RobotMismatch(DeployError):
    """The robot's modules say they are other types than the gait describes: nothing was sent. ``problems`` are the
    lines to show a user; deploying again with them in ``accept`` goes ahead knowingly."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = problems
        super().__init__("check: not the robot this gait was made for: " + "; ".join(problems))


@dataclass
class DeployReport:
    """What a deploy did, as the modules confirmed it."""

    gait: str
    deploy_id: int
    checksums: dict[int, int] = field(default_factory=dict)
    """Module ID → CRC-32 of the staged record it reported (equal to what was sent)."""
    running: list[int] = field(default_factory=list)
    """Modules that confirmed running this deployment (empty when it was staged only)."""
    lease: Lease | None = None
    """The lease still held by a deployment staged and not yet started (``deploy(..., start=False)``)."""

    def cancel(self) -> None:
        """Give up a staged deployment: release its lease (the modules keep running what they ran)."""
        if self.lease is not None:
            self.lease.release()
            self.lease = None


def module_tables(gait: Gait) -> dict[int, bytes]:
    """Each module's ``gait.table`` bytes."""
    return {a.id: encode_program(module_program(gait, a.id)) for a in gait.modules}


def deploy(
    node: Node,
    gait: Gait,
    *,
    name_of: Callable[[int], str] = module_name,
    direction: int = 1,
    progress: Callable[[int, int, str], None] | None = None,
    timeout: float = CALL_TIMEOUT,
    attempts: int = 6,
    start: bool = True,
    deadline: float | None = None,
    holder: str | None = None,
    accept: Collection[str] = (),
) -> DeployReport:
    """Stage, verify and (``start``) activate ``gait`` on its modules; see the module docstring.

    ``progress(done, total, message)`` is called after each module is staged and after activation. ``direction``
    -1 deploys the gait reversed. ``timeout`` bounds each call, ``attempts`` how often a timed-out call is tried,
    ``deadline`` (seconds, default 2 s + 0.25 s per module) the activation's confirmation. With ``start`` False the
    gait is staged only, its lease kept: :func:`activate` starts it later. ``accept``: the lines of a
    :class:`RobotMismatch` the caller goes ahead despite (any other difference is still refused).
    """
    tables = module_tables(gait)
    deploy_id = secrets.randbits(32) or 1
    records = {}
    for a in gait.modules:  # step 1: sizes, before anything is sent
        try:
            records[a.id] = encode_staged(Staged(deploy_id, a.phase, a.direction * direction, tables[a.id]))
        except ValueError as exc:
            raise DeployError(f"module {a.id} ({name_of(a.id)}), check: {exc}") from None
    calls = ModuleCalls(node, {a.id: name_of(a.id) for a in gait.modules}, timeout, attempts)
    ids = sorted(records)
    problems = [line for m in ids if (line := type_mismatch(gait, m, calls.names[m], _reported_type(calls, m)))]
    if any(line not in accept for line in problems):
        raise RobotMismatch(problems)
    updating = [f"module {m} ({calls.names[m]})" for m in ids if _being_updated(calls, m)]
    if updating:  # it resets when the image is whole: a gait started on it now would stop there, the others walking
        raise DeployError(f"{', '.join(updating)}: a firmware update is being written; deploy when it has ended "
                          "(nothing was sent)")  # fmt: skip
    spans = commanded(gait)
    beyond = [line for m in ids if (line := _beyond_limits(calls, m, spans.get(m, (0.0, 0.0))))]
    if beyond:  # a module checks every table against its limits and refuses it: said now, nothing sent
        raise DeployError(
            "; ".join(beyond) + ": a module refuses a table beyond its joint limits. Widen its "
            "soft limits (joint.calibration, the Modules tab) or change the gait; nothing was sent"
        )
    report = DeployReport(gait.name, deploy_id)
    lease = Lease(calls, ids, holder or default_holder(node), deploy_id)
    try:
        lease.take()  # step 2
        for done, module in enumerate(ids, start=1):  # step 3
            data = records[module]
            calls.set(module, "gait.staged", data, "stage")
            reported = calls.peek(module, "gait.staged_checksum", "verify")
            if reported != checksum(data):
                raise DeployError(f"module {module} ({calls.names[module]}), verify: checksum {reported:#010x}, "
                                  f"sent {checksum(data):#010x}")  # fmt: skip
            report.checksums[module] = reported
            if progress is not None:
                progress(
                    done, len(ids), f"module {module} staged and verified ({len(data)} bytes, crc {reported:#010x})"
                )
        if start:
            _activate(node, calls, lease, report, ids, deadline, progress)
    except BaseException:
        lease.release()
        raise
    if start:
        lease.release()  # step 5
    else:
        report.lease = lease
    return report


def _peek_present(calls: ModuleCalls, module: int, name: str) -> Any | None:
    """Module ``module``'s ``name`` read in the check step; None when the module has no such object (a Python
    module has no firmware.status, an older one no module.type), however deep ModuleCalls' retries wrapped that
    LookupError. Every other failure is raised."""
    try:
        return calls.peek(module, name, "check")
    except DeployError as exc:
        cause: BaseException | None = exc
        while cause is not None and not isinstance(cause, LookupError):
            cause = cause.__cause__
        if cause is not None:
            return None
        raise


def _being_updated(calls: ModuleCalls, module: int) -> bool:
    """Module ``module`` is receiving a firmware image (firmware.status ``receiving``); a module without the
    object (a Python module) is not."""
    status = _peek_present(calls, module, "firmware.status")
    return status is not None and int(status.get("state", 0)) == FIRMWARE_STATES.index("receiving")


def _beyond_limits(calls: ModuleCalls, module: int, span: tuple[float, float]) -> str | None:
    """A line naming module ``module`` when its joint.limits cut off the angles ``span`` the gait commands it;
    None when they do not, or the module has no joint.limits (it checks nothing then)."""
    limits = _peek_present(calls, module, "joint.limits")
    if limits is None:
        return None
    low, high = (float(v) for v in limits)
    if low <= span[0] + 1e-3 and high >= span[1] - 1e-3:
        return None
    name = calls.names[module]
    return f"module {module} ({name}) allows {low:g}..{high:g}°, the gait commands {span[0]:g}..{span[1]:g}°"


def _reported_type(calls: ModuleCalls, module: int) -> str:
    """Module ``module``'s module.type; "" when it has none (a module older than the object says nothing)."""
    kind = _peek_present(calls, module, "module.type")
    return "" if kind is None else str(kind)


def activate(
    node: Node,
    report: DeployReport,
    *,
    name_of: Callable[[int], str] = module_name,
    timeout: float = CALL_TIMEOUT,
    attempts: int = 6,
    deadline: float | None = None,
) -> DeployReport:
    """Activate a deployment staged by ``deploy(..., start=False)`` (steps 4 and 5 of the module docstring), under
    the lease it still holds; DeployError, with nothing started, if the lease was lost meanwhile."""
    ids = sorted(report.checksums)
    lease = report.lease
    if lease is None:
        raise DeployError(f"deployment {report.deploy_id:#010x} holds no lease: it was started or cancelled")
    try:
        lease.check()
        lease.calls.check_not_latched(ids, "activate")
        for module in ids:  # what was staged is still there: nobody staged over it meanwhile
            reported = lease.calls.peek(module, "gait.staged_checksum", "activate")
            if reported != report.checksums[module]:
                raise DeployError(f"activate: module {module} ({lease.calls.names[module]}) holds another staged "
                                  f"gait (checksum {reported:#010x}): nothing was started")  # fmt: skip
        _activate(node, lease.calls, lease, report, ids, deadline, None)
    finally:
        report.cancel()
    return report


def _activate(
    node: Node,
    calls: ModuleCalls,
    lease: Lease,
    report: DeployReport,
    ids: list[int],
    deadline: float | None,
    progress: Callable[[int, int, str], None] | None,
) -> None:
    until = time.monotonic() + (deadline if deadline is not None else 2.0 + 0.25 * len(ids))
    activation = node.group(BROADCAST).attribute("gait.activate", "uint32")
    stopped: list[str] = []  # an e-stop heard meanwhile: not one more activation goes out after it
    forget = node.on_estop(lambda source, reason: stopped.append(source))
    try:
        waiting = list(ids)
        while not stopped:
            activation.set(report.deploy_id)
            time.sleep(0.02)
            waiting = [m for m in waiting if not _confirmed(calls, m, report.deploy_id)]
            if not waiting or time.monotonic() >= until:
                break
    finally:
        forget()
    report.running = [m for m in ids if m not in waiting]
    if stopped:
        raise DeployError(f"activate: an emergency stop (from {stopped[0]}) came while {report.gait} was starting; "
                          "no activation was sent after it, and every module dropped what was staged")  # fmt: skip
    if waiting:
        listed = ", ".join(f"module {m} ({calls.names[m]})" for m in waiting)
        if lease.lost is None:  # still ours: no other deployer can have started anything, so stopping is safe
            stop_all(node)
            raise DeployError(f"activate: {listed} did not confirm running deployment {report.deploy_id:#010x}; "
                              "every module's gait was stopped, so none runs another gait than the rest")  # fmt: skip
        raise DeployError(f"activate: {listed} did not confirm running deployment {report.deploy_id:#010x}, and the "
                          f"lease was lost ({lease.lost}): nothing was stopped")  # fmt: skip
    if progress is not None:
        progress(len(ids), len(ids), f"{len(ids)} modules confirmed running {report.gait}")


def _confirmed(calls: ModuleCalls, module: int, deploy_id: int) -> bool:
    try:
        return calls.peek(module, "gait.activate", "activate") == deploy_id and calls.running(module, "activate")
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
    calls = ModuleCalls(node, by_index, timeout, attempts)
    calls.check_not_latched(list(by_index), "start")
    node.group(group).service("gait.service").start()
    if not modules:
        return []
    deadline = time.monotonic() + timeout
    missing = list(by_index)
    while missing and time.monotonic() < deadline:
        time.sleep(0.02)
        missing = [m for m in missing if not _running(calls, m)]
    if missing:
        raise DeployError(f"start: {', '.join(by_index[m] for m in missing)} did not confirm running")
    return list(modules)


def _running(calls: ModuleCalls, module: int) -> bool:
    try:
        return calls.running(module, "start")
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
    calls = ModuleCalls(node, by_index, timeout, attempts)
    released, failed = [], []
    for index, name in by_index.items():
        try:
            calls.set(index, "estop", False, "release")
            released.append(name)
        except DeployError as exc:
            failed.append(str(exc))
    if failed:
        raise DeployError(f"released {len(released)} of {len(modules)} modules; " + "; ".join(failed))
    return released
