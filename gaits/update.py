"""A firmware update of a robot's modules that no deploy can start under: the update holds every module's
``gait.lease`` (gaits/lease.py), as a deployer does, from its check that no gait runs to its last module's return.

Without it, a deploy and an update started at the same instant both passed their checks (the update's "no gait
runs", the deploy's "no module receives an image") and the update's resets felled the robot mid-step. With it, the
second of the two is refused and told who holds the robot. A gait started without a lease (a group Start) while the
image streams is refused by the board itself: it takes no part of an update while its gait runs (LOCKED,
docs/protocol.md §12), and the tool reports that module refused.
"""

from __future__ import annotations

import logging
import random
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

from asm_module.firmware_image import check
from asm_module.flasher import ModuleUpdate, Progress, update_modules
from asm_module.names import is_module, module_id
from asm_py import Node
from asm_py.errors import AsmError, Locked

from .calls import DeployError, ModuleCalls
from .lease import LEASE_SECONDS, Lease, default_holder

log = logging.getLogger("gaits.update")

LEASE_CALL_TIMEOUT = 1.0
"""Seconds each take or renewal of a module's lease waits at most (twice: attempts=2)."""


class RobotHeld(DeployError, RuntimeError):
    """Another deployer or update holds some module's lease: nothing was sent; the text names the holder."""


class UpdateLease(Lease):
    """The lease an update holds. A module resets into its new image and is silent for its reboot (on a loaded
    machine, tens of seconds); a deploy's lease would lapse then and be given up, this one renews what answers —
    every module at once, so the silent ones do not hold up the others past their lease — and takes the lease
    again on a module that comes back without it."""

    def take(self) -> None:
        self._pool = ThreadPoolExecutor(max_workers=max(1, min(16, len(self.modules))), thread_name_prefix="asm-lease")
        super().take()

    def renew(self) -> None:
        with self._lock:
            for error in self._pool.map(self._renew_one, list(self.held)):
                if isinstance(error, DeployError) and isinstance(error.__cause__, Locked):
                    # a deployer took a module that came back from its reset without a lease, and gives it up when
                    # the next module refuses it: asked again at the next renewal, never given up (the update
                    # cannot be undone halfway; what it holds keeps every other deployer out)
                    log.warning("a module of the update's lease is held by another: %s", error)
                elif error is not None:
                    log.debug("renewing the update's lease: %s", error)  # rebooting: taken again when it is back

    def _renew_one(self, module: int) -> DeployError | None:
        try:
            self.calls.set(module, "gait.lease", self._record(LEASE_SECONDS), "lease")
        except DeployError as exc:
            return exc
        return None

    def release(self) -> None:
        super().release()
        pool = getattr(self, "_pool", None)
        if pool is not None:
            pool.shutdown(wait=True)


def update_robot(node: Node, modules: Sequence[str], image: bytes, *, progress: Progress | None = None,
                 timeout: float = 10.0, reboot_timeout: float = 30.0) -> list[ModuleUpdate]:  # fmt: skip
    """Update ``modules`` (node names) to ``image`` as asm_module.flasher.update_modules does, holding the lease of
    every module of the robot (those updated and the others alive) meanwhile. ImageError before anything is sent
    for what is not an image; RobotHeld when a deploy or another update holds the robot; GaitRunning when a gait
    runs on any module."""
    check(image)
    if not modules:
        return []
    alive = {n for n in node.discover() if is_module(n)}
    robot = sorted(alive | set(modules), key=lambda n: module_id(n) or 0)
    # each lease call short, whatever the update's own timeout: one module silent for its reboot must not hold up
    # the renewal of the others past their lease (5 s)
    calls = ModuleCalls(node, dict(enumerate(robot, start=1)), min(timeout, LEASE_CALL_TIMEOUT), attempts=2)
    holding = [index for index, name in calls.names.items() if _has_lease(node, name, timeout)]
    lease = UpdateLease(calls, holding, default_holder(node, "update by "), random.getrandbits(31) | 1)
    try:
        lease.take()
    except DeployError as exc:
        lease.release()
        raise RobotHeld(f"not sent: {exc}") from None
    try:
        return update_modules(node, modules, image, progress=progress, timeout=timeout, reboot_timeout=reboot_timeout)
    finally:
        lease.release()


def _has_lease(node: Node, name: str, timeout: float) -> bool:
    """Module ``name`` answers and has a gait lease (a silent module is the update's to report, not a refusal)."""
    try:
        node.lookup(name, "gait.lease", timeout=timeout)
    except (AsmError, OSError, LookupError):
        return False
    return True
