"""One deployer at a time: the ``gait.lease`` of every module, held from staging through Start and cleanup.

A lease is granted for LEASE_SECONDS and renewed by a thread of the deployer every RENEW_EVERY seconds for as long as
the deployer holds it, so the lease of a deployer that dies — a studio killed, a bridge gone — frees the robot
within a few seconds, while a deployer that waits for its user's "Start" keeps it however long the user thinks.
Every refusal names the holder (the module's LOCKED text).
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from collections.abc import Sequence

from asm_py import Node
from asm_py.errors import EstopLatched, Locked
from asm_py.status import reply_text

from .calls import DeployError, ModuleCalls

log = logging.getLogger("gaits.lease")

LEASE_SECONDS = 5.0
"""How long one grant lasts: a dead deployer's lease frees the robot within this."""
RENEW_EVERY = 1.5
"""Seconds between renewals while the deployer holds the lease."""
MAX_HOLD = 300.0
"""Seconds a lease is renewed at most: a staged deployment nobody starts or cancels does not lock the robot for
good (the studio withdraws its question after a minute)."""


HOLDER_BYTES = 32
"""Bytes of UTF-8 of a holder's name a board keeps (firmware/include/asm/gait.h ASM_LEASE_HOLDER): it refuses a
longer one as VALUE_ERROR, so every lease is cut to this (a host name of 25 characters made every deploy to a board
fail with "value out of its domain")."""


def fit_holder(text: str) -> str:
    """``text`` cut to HOLDER_BYTES of UTF-8 at a character's end."""
    return text.encode("utf-8")[:HOLDER_BYTES].decode("utf-8", errors="ignore")


def default_holder(node: Node, role: str = "") -> str:
    """Who a lease names: ``role``, the deploying node, its host and process, so a second deployer knows whom to ask;
    within HOLDER_BYTES, the host shortened first (the node and the process say the most)."""
    head, tail = f"{role}{node.name}@", f":{os.getpid()}"
    room = HOLDER_BYTES - len(head.encode("utf-8")) - len(tail.encode("utf-8"))
    host = socket.gethostname().encode("utf-8")[: max(0, room)].decode("utf-8", errors="ignore")
    return fit_holder(f"{head}{host}{tail}")


class Lease:
    """The lease ``token`` on ``modules`` for ``holder``; see the module docstring. A context manager."""

    def __init__(self, calls: ModuleCalls, modules: Sequence[int], holder: str, token: int) -> None:
        self.calls = calls
        self.modules = list(modules)
        self.holder = fit_holder(holder)
        self.token = token
        self.held: list[int] = []
        self._renewed_at = 0.0
        self.lost: str | None = None
        """Why the lease was lost while held (another deployer took it after an expiry), or None."""
        self._stop = threading.Event()
        self._renewer: threading.Thread | None = None
        self._lock = threading.Lock()

    def _record(self, seconds: float) -> dict[str, object]:
        return {"holder": self.holder, "token": self.token, "seconds": seconds}

    def take(self) -> None:
        """Take the lease on every module, in module order (two deployers never each hold part of the robot), and
        keep renewing it; DeployError naming the holder (or the latched e-stop) otherwise."""
        for module in self.modules:
            try:
                self.calls.set(module, "gait.lease", self._record(LEASE_SECONDS), "lease")
            except DeployError as exc:
                if isinstance(exc.__cause__, EstopLatched):
                    self._refuse_latched(module)
                if isinstance(exc.__cause__, Locked) and reply_text(exc.__cause__) == "":  # a board's: no text
                    self._refuse_held(module, exc)
                raise
            self.held.append(module)
        self._renewed_at = time.monotonic()
        self._renewer = threading.Thread(target=self._renew_loop, name="asm-lease", daemon=True)
        self._renewer.start()

    def _refuse_latched(self, first: int) -> None:
        """DeployError naming every latched module (read now), not only ``first``, the one that refused the lease:
        a user releasing one module at a time would be refused eleven times on a robot of twelve."""
        try:
            latched = [first, *self.calls.latched([m for m in self.modules if m != first], "lease")]
        except DeployError:  # a module that does not answer: name the one known
            latched = [first]
        listed = ", ".join(f"module {m} ({self.calls.names[m]})" for m in sorted(latched))
        raise DeployError(f"lease: the emergency stop is latched on {listed}; release it first") from None

    def _refuse_held(self, module: int, refusal: DeployError) -> None:
        """DeployError naming who holds ``module``'s lease, read from the lease itself: a board's LOCKED reply
        carries no text (a Python module's does), and "locked" alone does not say whom to ask."""
        try:
            current = self.calls.get(module, "gait.lease", "lease")
            holder, seconds = current["holder"], float(current["seconds"])
        except (DeployError, KeyError, TypeError, ValueError):
            raise refusal from None
        name = self.calls.names[module]
        raise DeployError(f"module {module} ({name}), lease: the robot is held by {holder!r} (deploying or updating "
                          f"it; lease for another {seconds:.1f} s at most)") from refusal.__cause__  # fmt: skip

    def renew(self) -> None:
        """Renew the lease on every module now; DeployError if another deployer holds a module's lease, or if the
        lease lapsed since the last renewal (a module would grant it again, but another deployer may have held it
        in between: what this deployer staged may be gone)."""
        with self._lock:
            began = time.monotonic()
            if self.lost is None and began - self._renewed_at >= LEASE_SECONDS:
                self.lost = f"not renewed for {began - self._renewed_at:.1f} s: it lapsed"
            if self.lost is not None:
                raise DeployError(f"the deploy lease was lost: {self.lost}")
            for module in self.held:
                try:
                    self.calls.set(module, "gait.lease", self._record(LEASE_SECONDS), "lease")
                except DeployError as exc:
                    if isinstance(exc.__cause__, Locked | EstopLatched):
                        self.lost = str(exc)
                    raise
            self._renewed_at = began

    def check(self) -> None:
        """DeployError if the lease was lost or lapsed while held (a step must not go on without it)."""
        self.renew()

    def _renew_loop(self) -> None:
        until = time.monotonic() + MAX_HOLD
        while not self._stop.wait(RENEW_EVERY) and time.monotonic() < until:
            try:
                self.renew()
            except DeployError as exc:
                log.warning("renewing the deploy lease failed: %s", exc)
                if self.lost is not None:
                    return
            except RuntimeError as exc:  # the node closed under the lease (its studio closed mid-stage): it lapses
                log.info("the deploy lease is no longer renewed: %s", exc)
                return

    def release(self) -> None:
        """Release the lease (best effort: a lease also expires by itself)."""
        self._stop.set()
        if self._renewer is not None and self._renewer is not threading.current_thread():
            self._renewer.join(5)
        with self._lock:
            for module in self.held:
                try:
                    self.calls.set(module, "gait.lease", self._record(0.0), "release")
                except DeployError:
                    pass
            self.held.clear()

    def __enter__(self) -> Lease:
        self.take()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
