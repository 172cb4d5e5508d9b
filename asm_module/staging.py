"""A module's side of a deployment as a transaction: stage, verify, activate with one broadcast — under a lease.

A deploying tool must never leave a robot half running a new gait. So a module keeps two gaits: the one it runs
(``gait.table``, ``gait.phase``, ``gait.direction``) and a *staged* one that does nothing until activated:

    gait.staged           bytes    a staged record (wire.py: deploy ID, phase, direction, table); set any time, even
                                   while the gait runs — the running gait is untouched
    gait.staged_checksum  uint32   CRC-32 of gait.staged (read-only), for the tool to verify the transfer
    gait.activate         uint32   set to a deploy ID: if it is the staged one, the module makes the staged gait its
                                   gait and starts it; its value is the deploy ID now running (0: none). Sent as one
                                   group message to every module; setting the ID already running changes nothing,
                                   so a tool can resend it until every module confirms
    gait.lease            record{holder:str,token:uint32,seconds:float32}
                                   one deployer at a time: a set is granted when the lease is free, expired, or
                                   already this token's; otherwise LOCKED, naming the holder. While a lease is held,
                                   only a staged record carrying its token as deploy ID is accepted. seconds 0
                                   releases it. A lease lasts at most MAX_LEASE seconds. While a lease is in
                                   force, clearing gait.staged (an empty value, which names no deploy ID) is LOCKED
                                   too.

Everything here refuses while the e-stop is latched (the node's guard answers ESTOP before these checks run).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from asm_py.attribute import Attribute, CheckedAttribute
from asm_py.codec import BYTES, FLOAT32, STR, UINT32, record
from asm_py.errors import EstopLatched, Locked

from .wire import Staged, checksum, decode_staged

if TYPE_CHECKING:
    from .runtime import ModuleRuntime

LEASE = record([("holder", STR), ("token", UINT32), ("seconds", FLOAT32)])
MAX_LEASE = 60.0
"""Seconds a lease lasts at most: a deployer that dies does not lock the robot for long."""
FREE = {"holder": "", "token": 0, "seconds": 0.0}


class Staging:
    """The staged gait, its activation and the deploy lease of one module; see the module docstring."""

    def __init__(self, runtime: ModuleRuntime) -> None:
        self._runtime = runtime
        clock = runtime.clock
        self._record: Staged | None = None
        self._expires = 0.0
        self.lease = CheckedAttribute("gait.lease", dict(FREE), codec=LEASE, check=self._take_lease, clock=clock)
        # a RESET of either is checked as the empty value a set would carry: it names no token, so it frees nothing
        # another holds
        self.staged = CheckedAttribute("gait.staged", b"", codec=BYTES, check=self._stage, clock=clock)
        self.staged_checksum = Attribute("gait.staged_checksum", checksum(b""), codec=UINT32, clock=clock)
        self.activate = CheckedAttribute("gait.activate", 0, codec=UINT32, check=self._activate, reset=lambda: 0,
                                         clock=clock)  # fmt: skip

    def holder(self) -> dict[str, Any] | None:
        """The lease now in force, or None when it is free or expired."""
        lease = self.lease.peek()
        if not lease["holder"] or self._runtime.clock.now() >= self._expires:
            return None
        return lease

    def _take_lease(self, wanted: dict[str, Any]) -> dict[str, Any]:
        if math.isnan(wanted["seconds"]):  # its domain first, as the C module checks it
            raise ValueError(f"a lease lasts a number of seconds, not {wanted['seconds']}")
        if self._runtime.latched and wanted["seconds"] > 0:
            raise EstopLatched("the module's emergency stop is latched: no deploy until it is released")
        current = self.holder()
        if current is not None and current["token"] != wanted["token"]:
            left = self._expires - self._runtime.clock.now()
            raise Locked(f"the robot is being deployed by {current['holder']!r} (lease for another {left:.1f} s)")
        seconds = min(float(wanted["seconds"]), MAX_LEASE)
        if seconds <= 0 or not wanted["holder"]:
            self._expires = 0.0
            return dict(FREE)
        self._expires = self._runtime.clock.now() + seconds
        return {"holder": wanted["holder"], "token": wanted["token"], "seconds": seconds}

    def _stage(self, data: bytes) -> bytes:
        if not data:  # clears what was staged; an empty value names no deploy ID, so not under anyone's lease
            current = self.holder()
            if current is not None:
                raise Locked(f"the robot is being deployed by {current['holder']!r}: nothing may clear its staged "
                             "gait until the lease is released")  # fmt: skip
            self._record = None
            self.staged_checksum.set(checksum(b""))
            return data
        staged = decode_staged(data)
        current = self.holder()
        if current is not None and current["token"] != staged.deploy_id:
            raise Locked(f"the robot is being deployed by {current['holder']!r}: only its deploy ID can stage")
        self._runtime.check_table(staged.table)
        self._record = staged
        self.staged_checksum.set(checksum(data))
        return data

    def discard(self) -> None:
        """Forget what was staged, whoever holds the lease (an e-stop: a deployment in progress is abandoned)."""
        self._record = None
        Attribute.set(self.staged, b"")
        self.staged_checksum.set(checksum(b""))

    def _activate(self, deploy_id: int) -> int:
        runtime = self._runtime
        since = runtime.latches  # before the staged record is read: an e-stop from here on refuses the switch
        if deploy_id == self.activate.peek():
            return deploy_id  # a resent activation: done once, never a restart (an e-stop may have stopped it)
        staged = self._record
        if staged is None or staged.deploy_id != deploy_id:
            raise ValueError(f"no gait is staged with deploy ID {deploy_id:#010x}")
        runtime.switch_gait(staged.table, staged.phase, staged.direction, since=since)
        return deploy_id
