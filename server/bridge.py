"""The CAN ↔ Zenoh bridge: every node on a CAN bus appears on Zenoh as a Zenoh node, reachable like any other.

For each CAN node heard (by its heartbeat) the bridge declares, on Zenoh, the node's liveliness token and its
request keys (docs/protocol.md, "Zenoh key space"); it forwards the ASM message bytes unchanged both ways:

- a Zenoh query ``asm/<N>/req/<C>`` becomes the same message on CAN from an *alias* node ID standing for client C
  (one alias per Zenoh session — name and session ID — from a pool, least recently used reused first), with its
  transaction id replaced by one the bridge allocates and its timeout byte capped, and N's reply to that alias
  becomes the query's reply with the client's own transaction id back in place (so two sessions that share a name
  never receive each other's replies);
- puts on ``asm/<N>/msg/<C>`` and ``asm/@group/<G>/msg/<C>`` become node and group frames from C's alias;
- each publication of a CAN node becomes a put on ``asm/<N>/pub/<object>`` and its JSON view (object names and
  codecs come from a lookup of N's table, made once when N appears);
- e-stops cross in both directions.

The bridge is an edge, so it enforces the protocol's bounds before anything reaches the bus: a message over
``MAX_MESSAGE`` bytes is refused at once (TOO_LARGE) and never fragmented; each client has at most
``max_pending_per_client`` queries waiting for a reply (``max_pending`` in all) and a queue of at most
``max_queued_per_client`` messages; beyond that it is told BUSY. Queues are served round-robin, one message per
client in turn, by one sender thread, so a client flooding the bridge only delays itself. E-stops never queue: they
go straight to the bus as one priority-0 frame, from whichever Zenoh session sent them.

Zenoh clients therefore see CAN modules with lookup, get/set, services, events, publications and discovery, and
nothing is re-encoded. CLI: ``python -m server.bridge --can virtual:bus0 --zenoh-listen tcp/127.0.0.1:7447``.
"""

from __future__ import annotations

import argparse
import json
import logging
import queue
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import zenoh

from asm_py.canbus.fragments import frame_count
from asm_py.canbus.ids import Dest, check_node_id
from asm_py.cli import bitrate, can_channel, describe, input_file, node_id, run, stop_requested, zenoh_endpoint
from asm_py.codec import to_json
from asm_py.node import Node
from asm_py.protocol import (
    MAX_MESSAGE,
    MAX_TXN,
    Kind,
    Status,
    decode_timeout,
    encode_timeout,
    kind_of,
    reply_head,
    too_large,
)
from asm_py.remote import RemoteObject
from asm_py.transport.can import CanTransport, group_id, message_priority
from asm_py.transport.zenoh import make_config

from .heap import HeapTrimmer
from .realtime import prefer_latency

log = logging.getLogger("server.bridge")

REPLY_MARGIN = 5.0
"""Seconds a forwarded query waits for its CAN reply beyond the request's own timeout."""
MAX_BLOCK = 60.0
"""The longest a forwarded request may ask a CAN node to block: a longer (or endless) timeout byte is capped."""
MAX_BLOCK_CODE = encode_timeout(MAX_BLOCK)
DEFAULT_FRAME_RATE = 4000.0
"""Frames per second the bridge puts on the bus for Zenoh clients, at most: about half of what a 1 Mbit/s bus
carries (~7,700 frames of 8 bytes), so the modules' own traffic always has room and no receiver falls behind."""
BURST_FRAMES = 600
"""Frames the bridge may send at once after a quiet spell (one maximum-size message and some)."""


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


class _Mirror:
    """What the bridge declared on Zenoh for one CAN node."""

    def __init__(self, name: str, node_id: int) -> None:
        self.name = name
        self.node_id = node_id
        self.entities: list[Any] = []
        self.objects: dict[int, RemoteObject] = {}


@dataclass
class _Pending:
    """A forwarded query waiting for its CAN reply."""

    query: zenoh.Query
    txn: int
    """The client's own transaction id, put back into the reply."""
    deadline: float


@dataclass
class _Client:
    """One Zenoh session as the bus sees it: an alias node ID and a bounded queue of messages to send."""

    alias: int
    queue: deque[tuple[int, int, bytes]] = field(default_factory=deque)
    pending: int = 0


class CanZenohBridge:
    """See the module docstring."""

    def __init__(
        self,
        can_transport_options: dict[str, Any],
        *,
        node_id: int = 254,
        name: str = "bridge",
        aliases: Sequence[int] = range(200, 254),
        zenoh_mode: str = "peer",
        zenoh_listen: Sequence[str] = (),
        zenoh_connect: Sequence[str] = (),
        zenoh_config: str | None = None,
        insecure: bool = False,
        max_pending: int = 1024,
        max_pending_per_client: int = 32,
        max_queued_per_client: int = 64,
        max_frame_rate: float | None = DEFAULT_FRAME_RATE,
    ) -> None:
        self._lock = threading.Lock()
        self._ready = threading.Condition(self._lock)
        self._mirrors: dict[str, _Mirror] = {}
        self._alias_pool = [check_node_id(a) for a in aliases if a != node_id]
        self._clients: OrderedDict[tuple[str, bytes], _Client] = OrderedDict()  # (name, session) -> client, LRU
        self._pending: dict[tuple[int, int, int], _Pending] = {}  # (alias, CAN node ID, bridge txn) -> query
        self._next_txn = 0
        self.max_pending = max_pending
        self.max_pending_per_client = max_pending_per_client
        self.max_queued_per_client = max_queued_per_client
        self.max_frame_rate = max_frame_rate
        self._budget = float(BURST_FRAMES)
        self._budget_time = time.monotonic()
        self._work: queue.Queue[str | None] = queue.Queue()
        self.forwarded = {"to_can": 0, "to_zenoh": 0, "publications": 0, "unanswered": 0, "refused": 0}
        self.session = zenoh.open(make_config(mode=zenoh_mode, listen=zenoh_listen, connect=zenoh_connect,
                                              config_file=zenoh_config, insecure=insecure))  # fmt: skip
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
            self.session.declare_subscriber("asm/@group/*/msg/*", self._group_from_zenoh, allowed_origin=remote),
            self.session.declare_subscriber("asm/@estop/*", self._estop_from_zenoh, allowed_origin=remote),
        ]
        for alias in self._alias_pool:
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
        while not self._stop.is_set():
            try:
                item = self._work.get(timeout=0.2)
            except queue.Empty:
                item = ""  # nothing to bridge: only the housekeeping below
            if item is None:
                return
            try:
                if item.startswith("-"):
                    self._unmirror(item[1:])
                elif item:
                    self._mirror(item)
            except Exception:
                log.exception("bridging %s failed", item)
            self._expire_pending()
            self.heap.tick()

    def _mirror(self, name: str) -> None:
        node_id = self.can.resolve(name)
        if node_id is None or name in self._mirrors:
            return
        mirror = _Mirror(name, node_id)
        session = self.session
        mirror.entities = [
            session.declare_queryable(f"asm/{name}/req/*", lambda q, m=mirror: self._query_from_zenoh(m, q)),
            session.declare_subscriber(
                f"asm/{name}/msg/*",
                lambda s, m=mirror: self._put_from_zenoh(m, s),
                allowed_origin=zenoh.Locality.REMOTE,
            ),
            session.liveliness().declare_token(f"asm/@alive/{name}"),
        ]
        with self._lock:
            self._mirrors[name] = mirror
        try:
            mirror.objects = {obj.info.object_id: obj for obj in self.node.list_objects(name, timeout=2.0)}
        except Exception as exc:  # still bridged for requests; publications wait for the table
            log.warning("could not read the object table of %s: %s", name, exc)
        log.info("bridging CAN node %s (ID %d, %d objects)", name, node_id, len(mirror.objects))

    def _unmirror(self, name: str) -> None:
        with self._lock:
            mirror = self._mirrors.pop(name, None)
        if mirror is not None:
            for entity in reversed(mirror.entities):
                entity.undeclare()
            log.info("CAN node %s left", name)

    # -- Zenoh -> CAN ---------------------------------------------------------------------------------------------

    def _client(self, name: str, session: bytes) -> _Client:
        """The client for a Zenoh session (lock held): its alias, least recently used reused first."""
        key = (name, session)
        client = self._clients.get(key)
        if client is not None:
            self._clients.move_to_end(key)
            return client
        used = {c.alias for c in self._clients.values()}
        free = [a for a in self._alias_pool if a not in used]
        if free:
            alias = free[0]
        else:  # reuse the alias of the least recently used client without work in flight
            idle = next((k for k, c in self._clients.items() if not c.pending and not c.queue), None)
            if idle is None:
                raise _Refusal(Status.BUSY, "the bridge has no free alias: too many clients at work")
            alias = self._clients.pop(idle).alias
        client = self._clients[key] = _Client(alias)
        return client

    @staticmethod
    def _sender(key_expr: Any, attachment: Any) -> tuple[str, bytes]:
        name = str(key_expr).rsplit("/", 1)[-1]
        return name, (attachment.to_bytes()[:64] if attachment is not None else b"")

    def _query_from_zenoh(self, mirror: _Mirror, query: zenoh.Query) -> None:
        data = query.payload.to_bytes() if query.payload is not None else b""
        wants_reply = len(data) >= 4 and kind_of(data) == Kind.REQUEST_REPLY and data[0] >> 6 == 1
        try:
            if len(data) < 4:
                raise _Refusal(None, "")
            if len(data) > MAX_MESSAGE:
                raise _Refusal(Status.TOO_LARGE, too_large(len(data)))
            name, session = self._sender(query.key_expr, query.attachment)
            with self._lock:
                client = self._client(name, session)
                self._check_room(client)
                if wants_reply:
                    data = self._await_reply(client, mirror, query, data)
                self._enqueue(client, Dest.NODE, mirror.node_id, data)
        except _Refusal as refusal:
            self.forwarded["refused"] += 1
            if wants_reply and refusal.status is not None:
                query.reply(query.key_expr, reply_head(data, refusal.status) + refusal.text.encode("utf-8")[:120])
            query.drop()
            return
        if not wants_reply:
            query.drop()

    def _await_reply(self, client: _Client, mirror: _Mirror, query: zenoh.Query, data: bytes) -> bytes:
        """Register ``query`` as waiting for its reply (lock held); the request as it goes on the bus: a bridge
        transaction id, and a timeout byte of at most MAX_BLOCK."""
        if client.pending >= self.max_pending_per_client or len(self._pending) >= self.max_pending:
            raise _Refusal(Status.BUSY, f"too many requests in flight through the bridge ({client.pending} of yours)")
        for _ in range(MAX_TXN + 1):
            txn, self._next_txn = self._next_txn, (self._next_txn + 1) & MAX_TXN
            if (client.alias, mirror.node_id, txn) not in self._pending:
                break
        else:
            raise _Refusal(Status.BUSY, "all transaction ids to this node are in use")
        has_timeout = bool(data[1] & 0x80) and len(data) > 4
        limit = decode_timeout(data[4]) if has_timeout else 0.0
        if limit is None or limit > MAX_BLOCK:
            data = data[:4] + bytes((MAX_BLOCK_CODE,)) + data[5:]
            limit = MAX_BLOCK
        deadline = time.monotonic() + limit + REPLY_MARGIN
        self._pending[(client.alias, mirror.node_id, txn)] = _Pending(query, data[1] & MAX_TXN, deadline)
        client.pending += 1
        return data[:1] + bytes(((data[1] & 0x80) | txn,)) + data[2:]

    def _check_room(self, client: _Client) -> None:
        """BUSY when the client's queue is full (lock held)."""
        if len(client.queue) >= self.max_queued_per_client:
            raise _Refusal(Status.BUSY, "your queue at the bridge is full")

    def _enqueue(self, client: _Client, dest_kind: int, dest: int, data: bytes) -> None:
        """Queue a message for the bus (lock held, room checked)."""
        client.queue.append((dest_kind, dest, data))
        self._ready.notify()

    def _put_from_zenoh(self, mirror: _Mirror, sample: zenoh.Sample) -> None:
        self._forward_put(sample, Dest.NODE, mirror.node_id)

    def _group_from_zenoh(self, sample: zenoh.Sample) -> None:
        group = str(sample.key_expr).split("/")[2]
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
                client = self._client(*self._sender(sample.key_expr, sample.attachment))
                self._check_room(client)
                self._enqueue(client, dest_kind, dest, data)
        except _Refusal:
            self.forwarded["refused"] += 1

    def _send_loop(self) -> None:
        """Send the clients' queued messages round-robin, one message per client in turn."""
        while True:
            with self._lock:
                while not self._stop.is_set() and not any(c.queue for c in self._clients.values()):
                    self._ready.wait(0.5)
                if self._stop.is_set():
                    return
                batch = [(c.alias, c.queue.popleft()) for c in self._clients.values() if c.queue]
            for alias, (dest_kind, dest, data) in batch:
                self._pace(frame_count(len(data), frame_size=self.can.frame_size))
                try:
                    self.can.send_message(dest_kind, dest, data, message_priority(data), source=alias)
                    self.forwarded["to_can"] += 1
                except Exception:
                    log.exception("forwarding a message to the bus failed")

    def _pace(self, frames: int) -> None:
        """Wait until ``frames`` fit the bridge's frame rate (a token bucket of BURST_FRAMES)."""
        rate = self.max_frame_rate
        if rate is None:
            return
        now = time.monotonic()
        self._budget = min(BURST_FRAMES, self._budget + (now - self._budget_time) * rate)
        self._budget_time = now
        if self._budget < frames:
            self._stop.wait((frames - self._budget) / rate)
            self._budget_time = time.monotonic()
            self._budget = 0.0
        else:
            self._budget -= frames

    def _estop_from_zenoh(self, sample: zenoh.Sample) -> None:
        self.can.estop(sample.payload.to_bytes()[:64].decode("utf-8", errors="replace"))

    # -- CAN -> Zenoh ---------------------------------------------------------------------------------------------

    def _from_can_to_alias(self, source_id: int, alias: int, data: bytes) -> None:
        if len(data) < 4 or kind_of(data) != Kind.REPLY:
            return
        with self._lock:
            waiting = self._pending.pop((alias, source_id, data[1] & MAX_TXN), None)
            if waiting is not None:
                self._release(alias)
        if waiting is None:
            self.forwarded["unanswered"] += 1
            return
        query = waiting.query
        try:
            query.reply(query.key_expr, data[:1] + bytes((waiting.txn,)) + data[2:])
        finally:
            query.drop()
        self.forwarded["to_zenoh"] += 1

    def _release(self, alias: int) -> None:
        """One query of ``alias`` is done (lock held)."""
        for client in self._clients.values():
            if client.alias == alias:
                client.pending = max(0, client.pending - 1)
                return

    def _publication_from_can(self, source_id: int, data: bytes) -> None:
        mirror = self._mirrors.get(self.can.name_of(source_id))
        if mirror is None:
            return
        obj = mirror.objects.get(data[3])
        if obj is None:
            return
        self.session.put(f"asm/{mirror.name}/pub/{obj.name}", data)
        try:
            value = obj.codec.decode(data[4:])  # type: ignore[attr-defined]
        except ValueError:
            return
        view = {"node": mirror.name, "object": obj.name, "class": obj.info.class_name, "seq": data[1] & 0x7F,
                "t": time.time(), "value": to_json(value)}  # fmt: skip
        self.session.put(f"asm/{mirror.name}/json/{obj.name}", json.dumps(view))
        self.forwarded["publications"] += 1

    def _estop_from_can(self, source: str, reason: str) -> None:
        if source != self.node.name:  # the bridge's own e-stops came from Zenoh
            self.session.put(f"asm/@estop/{source}", reason.encode("utf-8"), priority=zenoh.Priority.REAL_TIME,
                             congestion_control=zenoh.CongestionControl.BLOCK, express=True)  # fmt: skip

    def _expire_pending(self) -> None:
        now = time.monotonic()
        with self._lock:
            expired = [k for k, p in self._pending.items() if p.deadline < now]
            queries = []
            for key in expired:
                queries.append(self._pending.pop(key).query)
                self._release(key[0])
        for query in queries:
            query.drop()

    @property
    def pending(self) -> int:
        """Forwarded queries waiting for a CAN reply now (bounded by ``max_pending``)."""
        return len(self._pending)

    @property
    def bridged(self) -> list[str]:
        """Names of the CAN nodes currently visible on Zenoh."""
        return sorted(self._mirrors)

    def close(self) -> None:
        for entity in self._keep:  # no new work from Zenoh first
            entity.undeclare()
        self._keep.clear()
        for name in list(self._mirrors):
            self._unmirror(name)
        with self._lock:
            self._stop.set()
            self._ready.notify_all()
        self._work.put(None)
        for thread in self._threads:
            thread.join(5)
        self.node.close()
        with self._lock:
            queries = [p.query for p in self._pending.values()]
            self._pending.clear()
            self._clients.clear()
        for query in queries:
            query.drop()
        self.session.close()


class _Refusal(Exception):
    """A request the bridge answers itself (status None: dropped without an answer)."""

    def __init__(self, status: int | None, text: str) -> None:
        super().__init__(text)
        self.status = status
        self.text = text


def add_zenoh_arguments(cli: argparse.ArgumentParser, *, listen_help: str | None = None) -> None:
    """The Zenoh options every command shares (as python-can's ``add_bus_arguments`` gives every tool the same bus
    flags); :func:`check_zenoh_arguments` checks them once parsed."""
    cli.add_argument("--zenoh-listen", action="append", default=[], type=zenoh_endpoint, metavar="ENDPOINT",
                     help=listen_help)  # fmt: skip
    cli.add_argument("--zenoh-connect", action="append", default=[], type=zenoh_endpoint, metavar="ENDPOINT")
    cli.add_argument("--zenoh-config", type=input_file, metavar="FILE",
                     help="a Zenoh JSON5 configuration (TLS, access control)")  # fmt: skip
    cli.add_argument("--insecure", action="store_true", help="allow Zenoh to listen beyond loopback without TLS "
                     "and access control (anyone who reaches the port can command the robot)")  # fmt: skip


def check_zenoh_arguments(cli: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """A usage error (exit 2, one line) for Zenoh endpoints that would be insecure or a config file that is bad."""
    try:
        make_config(mode=getattr(args, "zenoh_mode", "peer"), listen=args.zenoh_listen, connect=args.zenoh_connect,
                    config_file=args.zenoh_config, insecure=args.insecure)  # fmt: skip
    except (ValueError, OSError, zenoh.ZError) as exc:
        cli.error(describe(exc))


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-bridge", description=__doc__.splitlines()[0])
    cli.add_argument("--can", type=can_channel, required=True, metavar="INTERFACE:CHANNEL")
    cli.add_argument("--bitrate", type=bitrate)
    cli.add_argument("--fd", action="store_true")
    cli.add_argument("--node-id", type=node_id, default=254, help="the bridge's own CAN node ID (default 254)")
    add_zenoh_arguments(cli)
    cli.add_argument("--zenoh-mode", default="peer", choices=["peer", "client"])
    args = cli.parse_args(argv)
    check_zenoh_arguments(cli, args)
    return run(cli.prog, lambda: _serve(args))


def _serve(args: argparse.Namespace) -> int:
    prefer_latency()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    options = {**args.can, "fd": args.fd, **({"bitrate": args.bitrate} if args.bitrate else {})}
    bridge = CanZenohBridge(options, node_id=args.node_id, zenoh_mode=args.zenoh_mode,
                            zenoh_listen=args.zenoh_listen, zenoh_connect=args.zenoh_connect,
                            zenoh_config=args.zenoh_config, insecure=args.insecure)  # fmt: skip
    done = stop_requested()
    print("READY bridge", flush=True)
    done.wait()
    bridge.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
