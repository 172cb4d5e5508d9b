"""A robot process's presence on Zenoh, beside its modules: who it is, how it is, where its bodies are.

Under ``asm/<robot>/@robot/`` (asm_py.keys, docs/protocol.md §10) the feed holds the robot's liveliness token
(``alive/<session>``: it vanishes the moment the process does, so a studio says "robot lost" at once), answers and
publishes its status (once a second and on every change; a query answers at once, so a studio lists the robots of
a network without waiting for a publication), publishes the simulated robot's poses, and answers its MJCF model.
Every reply carries the replier's own key, never the wildcard a query asked with.

A robot's name is unique on its network: :class:`RobotFeed` refuses to start (:class:`RobotNameTaken`) when another
process already holds a robot token of that name, claims it by the rule of asm_py.transport.zenoh_claim (a ``claim``
token first, the ``alive`` token once kept), and after that gives way — withdraws its token, answers and publishes
nothing more, and says so through ``on_lost`` — should another process of the name with a lesser session ID turn out
to have kept it too (their tokens met late). The robot process then ends: two robots answering to one name would
let a studio's deploy or e-stop reach the wrong one.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

import zenoh

from asm_module.feed import RobotStatus
from asm_py.keys import RobotKeys, last
from asm_py.transport.zenoh_claim import claimants, gives_way, refuse_if_claimed, settle_claim

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
        on_lost: Callable[[str], None] | None = None,
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
        self._watch: Any = None
        self._closed = False
        self.on_lost = on_lost
        self.lost: str | None = None
        """The session that kept this robot's name when this feed gave it up after its claim (None: still kept)."""
        self._keep: list[Any] = []
        self._zid = zid = str(session.info.zid())
        refuse_if_claimed(zid, self._claimants, self._name_taken)
        claiming = session.liveliness().declare_token(self.keys.robot_claim(zid))
        self._keep.append(claiming)
        try:  # two robots named alike at the same moment: at most one keeps the name (asm_py.transport.zenoh_claim)
            settle_claim(zid, self._rivals, self._name_taken)
            self._keep.append(session.liveliness().declare_token(self.keys.robot_alive(zid)))
            self._keep.remove(claiming)
            claiming.undeclare()
            self._keep.append(session.declare_queryable(self.keys.robot_key("status"), self._answer_status))
            if mjcf is not None:
                self._keep.append(session.declare_queryable(self.keys.robot_key("mjcf"), self._answer_mjcf))
            # kept, everything declared (the watch's first call may come at once, on Zenoh's thread, and withdraws
            # all of it): from now on, another process that kept the name too (tokens that met late) is watched for
            self._watch = session.liveliness().declare_subscriber(self.keys.robot_alive(), self._on_alive, history=True)
        except BaseException:  # given way, or the network failed: the token is withdrawn either way
            self.close()
            raise

    def _claimants(self) -> set[str]:
        """The sessions that kept this robot's name (their ``alive`` tokens; a query of the network)."""
        return claimants(self.session, self.keys.robot_alive())

    def _rivals(self) -> set[str]:
        """The sessions that kept this robot's name or claim it now: what settle_claim looks at."""
        return claimants(self.session, self.keys.robot_alive(), self.keys.robot_claim())

    def _on_alive(self, sample: zenoh.Sample) -> None:
        """Another ``alive`` token of this name after the claim: the lesser session ID keeps the name (the rule of
        asm_py.transport.zenoh_claim); this feed gives way if its own ID is the greater."""
        rival = last(sample.key_expr)
        if sample.kind != zenoh.SampleKind.PUT or rival == self._zid:
            return
        if not gives_way(self._zid, rival):
            # resolved in this process's favour: a warning (the one that gives way logs the error)
            log.warning("another robot process (session %s) kept the name %r too: it gives way (the lesser ID "
                        "keeps the name)", rival, self.status.robot)  # fmt: skip
            return
        with self._lock:
            if self.lost is not None or self._closed:
                return
            self.lost = rival
        log.error("another robot process (session %s) kept the name %r too (their tokens met late): this one gives "
                  "way and withdraws", rival, self.status.robot)  # fmt: skip
        self._withdraw()
        if self.on_lost is not None:
            try:
                self.on_lost(rival)
            except Exception:  # on Zenoh's thread: said here, never raised into it
                log.exception("on_lost of the robot feed failed")

    def _name_taken(self, rival: str) -> RobotNameTaken:
        return RobotNameTaken(f"a robot named {self.status.robot!r} is already on this Zenoh network (session "
                              f"{rival}): give this one another --name")  # fmt: skip

    def _put(self, what: str, payload: bytes | str) -> None:
        key = self.keys.robot_key(what)
        try:
            with self._lock:
                if self.lost is not None or self._closed:  # given way: another process answers to this name now
                    return
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
            if self.lost is not None:  # given way: answered by the process that kept the name
                return
            if self.refresh is not None:
                self.refresh(self.status)
            query.reply(self.keys.robot_key("status"), self.status.to_json())
        finally:
            query.drop()

    def _answer_mjcf(self, query: zenoh.Query) -> None:
        try:
            if self.lost is not None:
                return
            query.reply(self.keys.robot_key("mjcf"), self.mjcf or "")
        finally:
            query.drop()

    def close(self) -> None:
        with self._lock:
            self._closed = True
        watch, self._watch = self._watch, None
        if watch is not None:
            try:
                watch.undeclare()
            except zenoh.ZError:
                log.debug("already undeclared", exc_info=True)
        self._withdraw()

    def _withdraw(self) -> None:
        """The token, the queryables and the publishers undeclared: nothing more answers to this name here."""
        with self._lock:  # once: the watch's thread and close may both get here
            keep, self._keep = self._keep, []
            publishers, self._publishers = list(self._publishers.values()), {}
        for entity in reversed(keep):
            try:
                entity.undeclare()
            except zenoh.ZError:
                log.debug("already undeclared", exc_info=True)
        for publisher in publishers:
            try:
                publisher.undeclare()
            except zenoh.ZError:
                log.debug("already undeclared", exc_info=True)
