"""The CAN ↔ Zenoh bridge: every node on a robot's CAN bus appears on Zenoh, in that robot's namespace, as a module.

For each CAN node heard (by its heartbeat) the bridge declares, on Zenoh, under ``asm/<robot>/`` (asm_py.keys), the
node's liveliness token and its request keys — unless the name is already alive in the robot (another process
answers for it: the bridge refuses to shadow it, says so, and looks again later). It forwards the ASM message bytes
unchanged both ways:

- a Zenoh query ``asm/<robot>/<N>/req/<C>`` becomes the same message on CAN from an *alias* node ID standing for
  client C (server/bridge_clients.py), with its transaction id replaced by one the bridge allocates and its timeout
  byte capped; N's reply to that alias becomes the query's reply with the client's own transaction id back;
- puts on ``asm/<robot>/<N>/msg/<C>`` and ``asm/<robot>/@group/<G>/msg/<C>`` become node and group frames from C's
  alias;
- each publication of a CAN node becomes a put on ``asm/<robot>/<N>/pub/<object>`` and its JSON view. Object names
  and codecs come from N's table, read by lookups when N appears — one lookup at a time, each retried with backoff
  until the whole table is read or N leaves, so a lost frame delays a module's publications, never silences them;
- the robot's e-stop and the lab-wide e-stop go onto the bus as one priority-0 frame at once, bypassing every queue;
  an e-stop from the bus becomes the robot's e-stop on Zenoh.

The bridge is an edge, so it enforces the protocol's bounds before anything reaches the bus (bridge_clients.py).
CLI: ``asm-bridge --can virtual:bus0 --robot-name a --zenoh-connect tcp/127.0.0.1:7447``.
"""

from __future__ import annotations

import argparse
import logging
import math
import queue
import threading
import time
from collections.abc import Sequence
from typing import Any

import zenoh

from asm_py.canbus.fragments import frame_count
from asm_py.canbus.ids import Dest
from asm_py.cli import add_bus_arguments, can_channel, close_and_exit, name, run, stop_requested, summary
from asm_py.keys import DEFAULT_ROBOT, RobotKeys, concrete, lab_estop, last, split
from asm_py.node import Node
from asm_py.protocol import (
    HEADER_SIZE,
    MAX_ERROR_TEXT,
    MAX_MESSAGE,
    VERSION,
    Kind,
    Method,
    Status,
    kind_of,
    reply_head,
    too_large,
    txn_of,
    version_of,
    with_txn,
)
from asm_py.remote import make_client
from asm_py.transport.can import CanTransport, group_id, message_priority
from asm_py.transport.zenoh_claim import CLAIM_SETTLE, Verdict, claimants, gives_way, verdict

from .bridge_clients import DEFAULT_FRAME_RATE, ClientTable, Pacer, Refusal
from .bridge_mirror import Mirror
from .bridge_outlets import Outlet, direct
from .heap import HeapTrimmer
from .realtime import prefer_latency
from .zenoh_args import ZenohOptions, add_zenoh_arguments, zenoh_options

log = logging.getLogger("server.bridge")

TABLE_LOOKUP_TIMEOUT = 0.3
"""Seconds one lookup of a CAN node's table may take before it is tried again (a lookup is a round trip of ~1 ms)."""
TAKEN_RETRY = 5.0
"""Seconds before the bridge looks again at a name that another process answered for."""


class _GatewayTransport(CanTransport):
    """The bridge's CAN side: its own node's traffic goes to its node, the aliases' traffic to the bridge."""

    bridge: CanZenohBridge

    def on_message(self, source_id: int, dest_kind: int, dest: int, data: bytes) -> None:
        if dest_kind == Dest.NODE and dest != self.node_id:
            self.bridge._from_can_to_alias(source_id, dest, data)
            return
        if dest_kind == Dest.BROADCAST and len(data) >= 4 and kind_of(data) == Kind.PUBLICATION:
            self.bridge._publication_from_can(source_id, data)
        super().on_message(source_id, dest_kind, dest, data)


class CanZenohBridge:
    """See the module docstring."""

    def __init__(
        self,
        can_transport_options: dict[str, Any],
        *,
        robot: str = DEFAULT_ROBOT,
        network: ZenohOptions | None = None,
        node_id: int = 254,
        name: str = "bridge",
        aliases: Sequence[int] = range(200, 254),
        max_pending: int = 1024,
        max_pending_per_client: int = 32,
        max_queued_per_client: int = 64,
        max_frame_rate: float | None = DEFAULT_FRAME_RATE,
    ) -> None:
        self.keys = RobotKeys(robot)
        self.robot = self.keys.robot
        self._mirrors: dict[str, Mirror] = {}
        self._taken: dict[str, float] = {}  # name -> when to look again (another process answers for it)
        self.clients = ClientTable([a for a in aliases if a != node_id], max_pending=max_pending,
                                   max_pending_per_client=max_pending_per_client,
                                   max_queued_per_client=max_queued_per_client)  # fmt: skip
        self._lock = self.clients.lock
        self._pacer = Pacer(max_frame_rate)
        self._work: queue.Queue[str | None] = queue.Queue()
        self.forwarded = {"to_can": 0, "to_zenoh": 0, "publications": 0, "unanswered": 0, "refused": 0, "estops": 0}
        self.session = (network or ZenohOptions()).open()
        self._zid = str(self.session.info.zid())
        self._stop = threading.Event()
        self.heap = HeapTrimmer(lambda: sum(self.forwarded.values()))
        try:
            self.can = _GatewayTransport(node_id, **can_transport_options)
            self.can.bridge = self
            self.node = Node(name, self.can)
        except BaseException:
            self.session.close()
            raise
        remote = zenoh.Locality.REMOTE  # what this session put itself never comes back
        self._keep: list[Any] = [
            self.session.declare_subscriber(self.keys.group("*"), self._group_from_zenoh, allowed_origin=remote),
            self.session.declare_subscriber(self.keys.estop(), self._estop_from_zenoh, allowed_origin=remote),
            self.session.declare_subscriber(lab_estop(), self._estop_from_zenoh, allowed_origin=remote),
            self.session.liveliness().declare_subscriber(self.keys.alive(), self._alive_from_zenoh),
        ]
        for alias in self.clients.alias_pool:
            self.can.accept_node_id(alias)
        self.can.on_estop(self._estop_from_can)
        self.node.on_discovery(self._can_peer)
        self._threads = [
            threading.Thread(target=self._work_loop, name=f"asm-bridge:{name}", daemon=True),
            threading.Thread(target=self._send_loop, name=f"asm-bridge-tx:{name}", daemon=True),
        ]
        for thread in self._threads:
            thread.start()
        for peer in self.can.peers():
            self._can_peer(peer, True)

    # -- CAN nodes appearing and leaving --------------------------------------------------------------------------

    def _can_peer(self, name: str, alive: bool) -> None:
        if name == self.node.name:
            return
        self._work.put(name if alive else f"-{name}")

    def _work_loop(self) -> None:
        """Mirror the nodes that appeared and unmirror those that left (all of them, at once), then read one more
        entry of a table that is due; between the two, the housekeeping."""
        while not self._stop.is_set():
            try:
                wait = self._table_wait()
                item = self._work.get_nowait() if wait <= 0 else self._work.get(timeout=wait)
            except queue.Empty:
                item = ""
            while item is not None and not self._stop.is_set():
                self._handle(item)
                try:
                    item = self._work.get_nowait()
                except queue.Empty:
                    break
            if item is None or self._stop.is_set():
                return
            try:
                self._retry_taken()
                self._settle_claims()
                for _ in range(64):  # back to back, but never long without looking at nodes that came or went
                    if not self._read_a_table() or not self._work.empty():
                        break
                for query in self.clients.expire():
                    query.drop()
                self.heap.tick()
            except Exception:
                if self._stop.is_set():  # closed under it (the session gone): nothing left to keep
                    return
                log.exception("the bridge's housekeeping failed; it goes on in a second")
                if self._stop.wait(1.0):  # an error that comes back every time is logged once a second, no more
                    return

    def _alive_from_zenoh(self, sample: zenoh.Sample) -> None:
        """Another session kept the name of a node mirrored here (their claims missed each other's tokens): the
        lesser ID keeps it, as for any session (asm_py.transport.zenoh_claim); the work loop withdraws the mirror."""
        chunks = split(sample.key_expr)  # asm/<robot>/@alive/<node>/<session>
        mirror = self._mirrors.get(chunks[3]) if len(chunks) == 5 else None
        kept = mirror is not None and mirror.holding.kept
        if sample.kind == zenoh.SampleKind.PUT and kept and gives_way(self._zid, chunks[4]):
            self._work.put(f"!{chunks[3]}/{chunks[4]}")

    def _handle(self, item: str) -> None:
        try:
            if item.startswith("!"):
                name, rival = item[1:].split("/")
                self._unmirror(name)
                self._refuse(name, rival)
            elif item.startswith("-"):
                self._unmirror(item[1:])
            elif item:
                self._mirror(item)
        except Exception:
            if not self._stop.is_set():  # (closed under it: the session gone)
                log.exception("bridging %s failed", item)

    def _claimants(self, name: str, *, claiming: bool = True) -> set[str]:
        return claimants(self.session, self.keys.alive(name), self.keys.claim(name) if claiming else None)

    def _refuse(self, name: str, other: str) -> None:
        if name not in self._taken:
            log.error("not bridging CAN node %s: a node named %s is already alive in robot %r (session %s)",
                      name, name, self.robot, other)  # fmt: skip
        self._taken[name] = time.monotonic() + TAKEN_RETRY

    def _settle_claims(self) -> None:
        """The bridge's mirrors claim their names as any session does, without blocking the work loop: each due
        mirror looks once; one that must give way is withdrawn (and tried again every TAKEN_RETRY seconds)."""
        now = time.monotonic()
        for mirror in [m for m in list(self._mirrors.values()) if not m.holding.kept and m.claim_due <= now]:
            if self._stop.is_set():  # a look may take 2 x CLAIM_QUERY_TIMEOUT: close() waits for none
                return
            seen = self._claimants(mirror.name)
            decided, rival = verdict(self._zid, seen, waited_enough=now >= mirror.claim_deadline,
                                     previous=mirror.last_look)  # fmt: skip
            mirror.last_look = seen
            if decided is Verdict.KEEP:
                claim = mirror.entities.pop()
                mirror.entities.append(self.session.liveliness().declare_token(self.keys.alive(mirror.name, self._zid)))
                claim.undeclare()
                mirror.holding.keep()
            elif decided is Verdict.YIELD:
                self._unmirror(mirror.name)  # (its held requests dropped unanswered)
                self._refuse(mirror.name, rival)
            else:
                mirror.claim_due = time.monotonic() + CLAIM_SETTLE

    def _mirror(self, name: str) -> None:
        node_id = self.can.resolve(name)
        if node_id is None or name in self._mirrors:
            return
        others = self._claimants(name, claiming=False) - {self._zid}
        if others:
            self._refuse(name, min(others))
            return
        self._taken.pop(name, None)
        mirror = Mirror(name, node_id)
        session, keys = self.session, self.keys
        # direct callbacks (indirect=False: on Zenoh's own threads): both only queue a frame under a short lock, and
        # zenoh-python's default runs each callback on a Python thread of its own — two per module (issue 31)
        mirror.entities = [
            session.declare_queryable(keys.requests(name), direct(lambda q, m=mirror: self._query_from_zenoh(m, q))),
            session.declare_subscriber(
                keys.messages(name),
                direct(lambda s, m=mirror: self._put_from_zenoh(m, s)),
                allowed_origin=zenoh.Locality.REMOTE,
            ),
            session.liveliness().declare_token(keys.claim(name, self._zid)),  # the last: replaced once kept
        ]
        with self._lock:
            self._mirrors[name] = mirror
        log.info("bridging CAN node %s (ID %d) as %s/%s", name, node_id, self.robot, name)

    def _unmirror(self, name: str) -> None:
        self._taken.pop(name, None)
        with self._lock:
            mirror = self._mirrors.pop(name, None)
        if mirror is not None:
            mirror.holding.give_up()  # (what is held, or arrives in the meantime, is dropped)
            for entity in reversed(mirror.entities):
                entity.undeclare()
            for outlet in mirror.outlets.values():
                outlet.close()
            mirror.outlets.clear()
            log.info("CAN node %s left", name)

    def _retry_taken(self) -> None:
        now = time.monotonic()
        for node in [n for n, when in self._taken.items() if when <= now]:
            if node in self.can.peers():
                self._mirror(node)
            else:
                self._taken.pop(node, None)

    def _table_wait(self) -> float:
        """Seconds until a table read is due (0: now), at most the housekeeping period."""
        mirrors = list(self._mirrors.values())
        attempts = [m.next_attempt for m in mirrors if not m.table_read]
        attempts += [m.claim_due for m in mirrors if not m.holding.kept]
        return min(0.2, max(0.0, min(attempts, default=math.inf) - time.monotonic()))

    def _read_a_table(self) -> bool:
        """One lookup of the first table that is due: the next object, or a retry after a backoff; False when no
        table was due."""
        now = time.monotonic()
        due = [m for m in list(self._mirrors.values()) if not m.table_read and m.next_attempt <= now]
        if not due:
            return False
        mirror = min(due, key=lambda m: m.next_attempt)
        object_id = len(mirror.objects) + 1
        try:
            reply = self.node.port(mirror.name).call(Method.LOOKUP, 0, object_id, timeout=TABLE_LOOKUP_TIMEOUT)
        except LookupError:  # past the last object: the table is complete
            mirror.table_read = True
            log.info("read the table of %s: %d objects (%d retries)", mirror.name, len(mirror.objects),
                     mirror.attempts)  # fmt: skip
            return True
        except Exception as exc:  # a lost frame, a busy module: try again a little later
            mirror.lookup_failed(object_id, exc, now, unreadable=False)
            return True
        try:
            client = make_client(self.node.port(mirror.name), reply.data)
        except Exception as exc:  # a description this side cannot read
            mirror.lookup_failed(object_id, exc, now, unreadable=True)
            return True
        mirror.object_read(object_id, client)
        return True

    @property
    def unread_tables(self) -> list[str]:
        """Bridged nodes whose object table is not read yet: their publications do not reach Zenoh yet."""
        return sorted(n for n, m in list(self._mirrors.items()) if not m.table_read)

    # -- Zenoh -> CAN ---------------------------------------------------------------------------------------------

    @staticmethod
    def _sender(key_expr: Any, attachment: Any) -> tuple[str, bytes]:
        return last(key_expr), (attachment.to_bytes()[:64] if attachment is not None else b"")

    def _query_from_zenoh(self, mirror: Mirror, query: zenoh.Query) -> None:
        if not mirror.holding.kept and mirror.holding.hold(lambda: self._query_from_zenoh(mirror, query), query.drop):
            return
        data = query.payload.to_bytes() if query.payload is not None else b""
        wants_reply = len(data) >= HEADER_SIZE and kind_of(data) == Kind.REQUEST_REPLY and version_of(data) == VERSION
        try:
            if len(data) < 4:
                raise Refusal(None, "")
            if len(data) > MAX_MESSAGE:
                raise Refusal(Status.TOO_LARGE, too_large(len(data)))
            with self._lock:
                client = self.clients.client(*self._sender(query.key_expr, query.attachment))
                if len(client.queue) >= self.clients.max_queued_per_client:
                    raise Refusal(Status.BUSY, "your queue at the bridge is full")
                if wants_reply:
                    data = self.clients.await_reply(client, mirror.node_id, query, data, self._reply_key(mirror, query))
                self.clients.enqueue(client, Dest.NODE, mirror.node_id, data)
        except Refusal as refusal:
            self.forwarded["refused"] += 1
            if wants_reply and refusal.status is not None:
                reply = reply_head(data, refusal.status) + refusal.text.encode("utf-8")[:MAX_ERROR_TEXT]
                query.reply(self._reply_key(mirror, query), reply)
            query.drop()
            return
        if not wants_reply:
            query.drop()

    def _reply_key(self, mirror: Mirror, query: zenoh.Query) -> str:
        """The replier's own concrete key, whatever wildcard the query used."""
        return self.keys.requests(mirror.name, concrete(last(query.key_expr)))

    def _put_from_zenoh(self, mirror: Mirror, sample: zenoh.Sample) -> None:
        if not mirror.holding.kept and mirror.holding.hold(lambda: self._put_from_zenoh(mirror, sample), None):
            return
        self._forward_put(sample, Dest.NODE, mirror.node_id)

    def _group_from_zenoh(self, sample: zenoh.Sample) -> None:
        group = split(sample.key_expr)[3]  # asm/<robot>/@group/<group>/msg/<source>
        if group == "all":
            self._forward_put(sample, Dest.BROADCAST, 0)
        else:
            self._forward_put(sample, Dest.GROUP, group_id(group, self.can.group_table))

    def _forward_put(self, sample: zenoh.Sample, dest_kind: int, dest: int) -> None:
        data = sample.payload.to_bytes()
        if not 4 <= len(data) <= MAX_MESSAGE or kind_of(data) == Kind.REQUEST_REPLY:
            self.forwarded["refused"] += 1  # a put has nobody to answer: what cannot be served is dropped
            return
        try:
            with self._lock:
                client = self.clients.client(*self._sender(sample.key_expr, sample.attachment))
                self.clients.enqueue(client, dest_kind, dest, data)
        except Refusal:
            self.forwarded["refused"] += 1

    def _send_loop(self) -> None:
        """Send the clients' queued messages round-robin, one message per client in turn."""
        while (batch := self.clients.next_batch(self._stop)) is not None:
            for alias, (dest_kind, dest, data) in batch:
                self._pacer.wait(frame_count(len(data), frame_size=self.can.frame_size), self._stop)
                try:
                    self.can.send_message(dest_kind, dest, data, message_priority(data), source=alias)
                    self.forwarded["to_can"] += 1
                except Exception:
                    log.exception("forwarding a message to the bus failed")

    def _estop_from_zenoh(self, sample: zenoh.Sample) -> None:
        self.can.estop(sample.payload.to_bytes()[:64].decode("utf-8", errors="replace"))
        self.forwarded["estops"] += 1

    # -- CAN -> Zenoh ---------------------------------------------------------------------------------------------

    def _from_can_to_alias(self, source_id: int, alias: int, data: bytes) -> None:
        if len(data) < 4 or kind_of(data) != Kind.REPLY:
            return
        with self._lock:
            waiting = self.clients.answered(alias, source_id, txn_of(data))
        if waiting is None:
            self.forwarded["unanswered"] += 1
            return
        query = waiting.query
        try:
            query.reply(waiting.key, with_txn(data, waiting.txn))
        finally:
            query.drop()
        self.forwarded["to_zenoh"] += 1

    def _publication_from_can(self, source_id: int, data: bytes) -> None:
        mirror = self._mirrors.get(self.can.name_of(source_id))
        if mirror is None:
            return
        outlet = mirror.outlets.get(data[3])
        if outlet is None:
            obj = mirror.objects.get(data[3])
            if obj is None:
                return
            with self._lock:
                if self._mirrors.get(mirror.name) is not mirror:
                    return  # unmirrored meanwhile: nothing may be declared for it any more
                outlet = mirror.outlets[data[3]] = Outlet(self.session, self.keys.publication(mirror.name, obj.name),
                                                          self.keys.json_view(mirror.name, obj.name), mirror.name,
                                                          obj)  # fmt: skip
        outlet.forward(data)
        self.forwarded["publications"] += 1

    def _estop_from_can(self, source: str, reason: str) -> None:
        if source != self.node.name:  # the bridge's own e-stops came from Zenoh
            self.session.put(self.keys.estop(source), reason.encode("utf-8"), priority=zenoh.Priority.REAL_TIME,
                             congestion_control=zenoh.CongestionControl.BLOCK, express=True)  # fmt: skip

    @property
    def pending(self) -> int:
        """Forwarded queries waiting for a CAN reply now (bounded by ``max_pending``)."""
        return len(self.clients.pending)

    @property
    def bridged(self) -> list[str]:
        """Names of the CAN nodes currently visible on Zenoh."""
        return sorted(self._mirrors)

    def close(self) -> None:
        for entity in self._keep:  # no new work from Zenoh first
            entity.undeclare()
        self._keep.clear()
        self._stop.set()
        for query in self.clients.clear():
            query.drop()
        self._work.put(None)
        for thread in self._threads:
            thread.join(5)
        # the mirrors are the work loop's: withdrawn once it has ended (withdrawn from here while it settled a claim,
        # it died with "Undeclared LivelinessToken"); a loop still looking keeps them, the session's close ends them
        if all(not thread.is_alive() for thread in self._threads):
            for node in list(self._mirrors):
                self._unmirror(node)
        self.node.close()
        for query in self.clients.clear():
            query.drop()
        self.session.close()


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-bridge", description=summary(__doc__))
    cli.add_argument("--can", type=can_channel, required=True, metavar="INTERFACE:CHANNEL")
    add_bus_arguments(cli)
    cli.add_argument("--robot-name", type=name, default=DEFAULT_ROBOT,
                     help="the robot (Zenoh namespace) the bus's modules belong to (default robot)")  # fmt: skip
    add_zenoh_arguments(cli)
    args = cli.parse_args(argv)
    options = zenoh_options(cli, args)
    return run(cli.prog, lambda: _serve(args, options))


def _serve(args: argparse.Namespace, zenoh_opts: ZenohOptions) -> int:
    prefer_latency()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    options = {**args.can, "fd": args.fd, **({"bitrate": args.bitrate} if args.bitrate else {})}
    bridge = CanZenohBridge(options, robot=args.robot_name, network=zenoh_opts, node_id=args.node_id)
    done = stop_requested()
    print("READY bridge", flush=True)
    done.wait()
    close_and_exit(bridge.close, "asm-bridge")


if __name__ == "__main__":
    raise SystemExit(main())
