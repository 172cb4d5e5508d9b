"""A robot process's presence on Zenoh, beside its modules: who it is, how it is, where its bodies are.

Under ``asm/<robot>/@robot/`` (asm_py.keys, docs/protocol.md §10) the feed holds the robot's liveliness token
(``alive/<session>``: it vanishes the moment the process does, so a studio says "robot lost" at once), answers and
publishes its status (once a second and on every change; a query answers at once, so a studio lists the robots of
a network without waiting for a publication), publishes the simulated robot's poses, and answers its MJCF model.
Every reply carries the replier's own key, never the wildcard a query asked with.

A robot's name is unique on its network: :class:`RobotFeed` refuses to start (:class:`RobotNameTaken`) when another
process already holds a robot token of that name.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

import zenoh

from asm_module.feed import RobotStatus
from asm_py.keys import RobotKeys
from asm_py.transport.zenoh_claim import refuse_if_claimed, sessions_holding, settle_claim

log = logging.getLogger("asm_robot.feed")


class RobotNameTaken(RuntimeError):
    """Another robot process of this name is on the network."""


class RobotFeed:
    """The ``@robot`` keys of one robot process, on ``session``; see the module docstring."""

    def __init__(
        self,
        session: zenoh.Session,
        status: RobotStatus,
        mjcf: str | None = None,
        refresh: Callable[[RobotStatus], None] | None = None,
    ) -> None:
        self.session = session
        self.status = status
        self.refresh = refresh
        """Brings the status's fields that change between publications (the latched modules) up to date before a
        query is answered, so a tool that just pressed E-STOP reads what the modules did, not last second's."""
        self.keys = RobotKeys(status.robot)
        self.mjcf = mjcf
        self._lock = threading.Lock()
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._keep: list[Any] = []
        zid = str(session.info.zid())
        refuse_if_claimed(zid, self._claimants, self._name_taken)
        self._keep.append(session.liveliness().declare_token(self.keys.robot_alive(zid)))
        try:  # two robots named alike at the same moment: at most one keeps the name (asm_py.transport.zenoh_claim)
            settle_claim(zid, self._claimants, self._name_taken)
        except BaseException:  # given way, or the network failed: the token is withdrawn either way
            self.close()
            raise
        self._keep.append(session.declare_queryable(self.keys.robot_key("status"), self._answer_status))
        if mjcf is not None:
            self._keep.append(session.declare_queryable(self.keys.robot_key("mjcf"), self._answer_mjcf))

    def _claimants(self) -> set[str]:
        """The sessions whose robot token claims this robot's name now (a query of the network)."""
        return sessions_holding(self.session, self.keys.robot_alive())

    def _name_taken(self, rival: str) -> RobotNameTaken:
        return RobotNameTaken(f"a robot named {self.status.robot!r} is already on this Zenoh network (session "
                              f"{rival}): give this one another --name")  # fmt: skip

    def _put(self, what: str, payload: bytes | str) -> None:
        key = self.keys.robot_key(what)
        try:
            with self._lock:
                publisher = self._publishers.get(key)
                if publisher is None:
                    publisher = self._publishers[key] = self.session.declare_publisher(key, express=True)
            publisher.put(payload)
        except zenoh.ZError as exc:  # closing: the session or the publisher is gone
            log.debug("not published on %s: %s", key, exc)

    def publish_status(self) -> None:
        if self.refresh is not None:
            self.refresh(self.status)
        self._put("status", self.status.to_json())

    def publish_poses(self, frame: bytes) -> None:
        self._put("poses", frame)

    def _answer_status(self, query: zenoh.Query) -> None:
        try:
            if self.refresh is not None:
                self.refresh(self.status)
            query.reply(self.keys.robot_key("status"), self.status.to_json())
        finally:
            query.drop()

    def _answer_mjcf(self, query: zenoh.Query) -> None:
        try:
            query.reply(self.keys.robot_key("mjcf"), self.mjcf or "")
        finally:
            query.drop()

    def close(self) -> None:
        for entity in reversed(self._keep):
            try:
                entity.undeclare()
            except zenoh.ZError:
                log.debug("already undeclared", exc_info=True)
        self._keep.clear()
        with self._lock:
            publishers, self._publishers = list(self._publishers.values()), {}
        for publisher in publishers:
            try:
                publisher.undeclare()
            except zenoh.ZError:
                log.debug("already undeclared", exc_info=True)
