"""The CAN ↔ Zenoh bridge: every node on a CAN bus appears on Zenoh as a Zenoh node, reachable like any other.

For each CAN node heard (by its heartbeat) the bridge declares, on Zenoh, the node's liveliness token and its
request keys (docs/protocol.md, "Zenoh key space"); it forwards the ASM message bytes unchanged both ways:

- a Zenoh query ``asm/<N>/req/<C>`` becomes the same message on CAN from an *alias* node ID standing for client C
  (one alias per Zenoh client, from a pool, least recently used reused first), and N's reply to that alias becomes
  the query's reply, paired by (alias, N, transaction id);
- puts on ``asm/<N>/msg/<C>`` and ``asm/@group/<G>/msg/<C>`` become node and group frames from C's alias;
- each publication of a CAN node becomes a put on ``asm/<N>/pub/<object>`` and its JSON view (object names and
  codecs come from a lookup of N's table, made once when N appears);
- e-stops cross in both directions.

Zenoh clients therefore see CAN modules with lookup, get/set, services, events, publications and discovery, and
nothing is re-encoded. CLI: ``python -m server.bridge --can virtual:bus0 --zenoh-listen tcp/127.0.0.1:7447``.
"""

from __future__ import annotations

import argparse
import json
import logging
import queue
import signal
import threading
import time
from collections import OrderedDict
from collections.abc import Sequence
from typing import Any

import zenoh

from asm_py.canbus.ids import Dest, check_node_id
from asm_py.codec import to_json
from asm_py.node import Node
from asm_py.protocol import Kind, decode_timeout, kind_of
from asm_py.remote import RemoteObject
from asm_py.transport.can import CanTransport, group_id, message_priority
from asm_py.transport.zenoh import make_config

log = logging.getLogger("server.bridge")

REPLY_MARGIN = 5.0
"""Seconds a forwarded query waits for its CAN reply beyond the request's own timeout."""


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
    ) -> None:
        self._lock = threading.Lock()
        self._mirrors: dict[str, _Mirror] = {}
        self._alias_pool = [check_node_id(a) for a in aliases if a != node_id]
        self._aliases: OrderedDict[str, int] = OrderedDict()  # Zenoh client name -> alias ID (LRU order)
        self._pending: dict[tuple[int, int, int], tuple[zenoh.Query, float]] = {}
        self._work: queue.Queue[str | None] = queue.Queue()
        self.forwarded = {"to_can": 0, "to_zenoh": 0, "publications": 0, "unanswered": 0}
        self.session = zenoh.open(make_config(mode=zenoh_mode, listen=zenoh_listen, connect=zenoh_connect))
        self._keep: list[Any] = [
            self.session.declare_subscriber("asm/@group/*/msg/*", self._group_from_zenoh),
            self.session.declare_subscriber("asm/@estop/*", self._estop_from_zenoh),
        ]
        self.can = _GatewayTransport(node_id, **can_transport_options)
        self.can.bridge = self
        self.node = Node(name, self.can)
        for alias in self._alias_pool:
            self.can.accept_node_id(alias)
        self.can.on_estop(self._estop_from_can)
        self.node.on_discovery(self._can_peer)
        self._stop = threading.Event()
        self._worker = threading.Thread(target=self._work_loop, name=f"asm-bridge:{name}", daemon=True)
        self._worker.start()
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
                self._expire_pending()
                continue
            if item is None:
                return
            try:
                if item.startswith("-"):
                    self._unmirror(item[1:])
                else:
                    self._mirror(item)
            except Exception:
                log.exception("bridging %s failed", item)
            self._expire_pending()

    def _mirror(self, name: str) -> None:
        node_id = self.can.resolve(name)
        if node_id is None or name in self._mirrors:
            return
        mirror = _Mirror(name, node_id)
        session = self.session
        mirror.entities = [
            session.declare_queryable(f"asm/{name}/req/*", lambda q, m=mirror: self._query_from_zenoh(m, q)),
            session.declare_subscriber(f"asm/{name}/msg/*", lambda s, m=mirror: self._put_from_zenoh(m, s)),
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

    def _alias(self, client: str) -> int:
        with self._lock:
            alias = self._aliases.get(client)
            if alias is not None:
                self._aliases.move_to_end(client)
                return alias
            used = set(self._aliases.values())
            free = [a for a in self._alias_pool if a not in used]
            if free:
                alias = free[0]
            else:  # reuse the least recently used alias
                _, alias = self._aliases.popitem(last=False)
            self._aliases[client] = alias
            return alias

    def _query_from_zenoh(self, mirror: _Mirror, query: zenoh.Query) -> None:
        client = str(query.key_expr).rsplit("/", 1)[-1]
        data = query.payload.to_bytes() if query.payload is not None else b""
        if len(data) < 4:
            query.drop()
            return
        alias = self._alias(client)
        if kind_of(data) == Kind.REQUEST_REPLY:
            limit = decode_timeout(data[4]) if data[1] & 0x80 and len(data) > 4 else 0.0
            deadline = time.monotonic() + (limit if limit is not None else 86_400.0) + REPLY_MARGIN
            with self._lock:
                self._pending[(alias, mirror.node_id, data[1] & 0x7F)] = (query, deadline)
        else:
            query.drop()
        self._to_can(Dest.NODE, mirror.node_id, data, alias)

    def _put_from_zenoh(self, mirror: _Mirror, sample: zenoh.Sample) -> None:
        client = str(sample.key_expr).rsplit("/", 1)[-1]
        if client in self._mirrors:
            return
        self._to_can(Dest.NODE, mirror.node_id, sample.payload.to_bytes(), self._alias(client))

    def _group_from_zenoh(self, sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")
        group, client = parts[2], parts[-1]
        if client in self._mirrors:
            return  # a CAN node's own group message, already on the bus
        if group == "all":
            self._to_can(Dest.BROADCAST, 0, sample.payload.to_bytes(), self._alias(client))
        else:
            gid = group_id(group, self.can.group_table)
            self._to_can(Dest.GROUP, gid, sample.payload.to_bytes(), self._alias(client))

    def _to_can(self, dest_kind: int, dest: int, data: bytes, source: int) -> None:
        self.can.send_message(dest_kind, dest, data, message_priority(data), source=source)
        self.forwarded["to_can"] += 1

    def _estop_from_zenoh(self, sample: zenoh.Sample) -> None:
        source = str(sample.key_expr).rsplit("/", 1)[-1]
        if source in self._mirrors or source == self.node.name:
            return  # came from the bus through us
        self.can.estop(sample.payload.to_bytes().decode("utf-8", errors="replace"))

    # -- CAN -> Zenoh ---------------------------------------------------------------------------------------------

    def _from_can_to_alias(self, source_id: int, alias: int, data: bytes) -> None:
        if len(data) < 4 or kind_of(data) != Kind.REPLY:
            return
        with self._lock:
            waiting = self._pending.pop((alias, source_id, data[1] & 0x7F), None)
        if waiting is None:
            self.forwarded["unanswered"] += 1
            return
        query, _ = waiting
        try:
            query.reply(query.key_expr, data)
        finally:
            query.drop()
        self.forwarded["to_zenoh"] += 1

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
        if source != self.node.name:
            self.session.put(f"asm/@estop/{source}", reason.encode("utf-8"), priority=zenoh.Priority.REAL_TIME)

    def _expire_pending(self) -> None:
        now = time.monotonic()
        with self._lock:
            expired = [k for k, (_, deadline) in self._pending.items() if deadline < now]
            queries = [self._pending.pop(k)[0] for k in expired]
        for query in queries:
            query.drop()

    @property
    def bridged(self) -> list[str]:
        """Names of the CAN nodes currently visible on Zenoh."""
        return sorted(self._mirrors)

    def close(self) -> None:
        self._stop.set()
        self._work.put(None)
        self._worker.join(5)
        for name in list(self._mirrors):
            self._unmirror(name)
        self.node.close()
        with self._lock:
            queries = [q for q, _ in self._pending.values()]
            self._pending.clear()
        for query in queries:
            query.drop()
        for entity in self._keep:
            entity.undeclare()
        self.session.close()


def parse_can(spec: str) -> dict[str, Any]:
    """``INTERFACE:CHANNEL`` (e.g. ``socketcan:can0``, ``virtual:bus0``) as python-can keyword arguments."""
    interface, sep, channel = spec.partition(":")
    if not sep or not interface or not channel:
        raise argparse.ArgumentTypeError(f"{spec!r} is not INTERFACE:CHANNEL, e.g. socketcan:can0")
    return {"interface": interface, "channel": channel}


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="python -m server.bridge", description=__doc__.splitlines()[0])
    cli.add_argument("--can", type=parse_can, required=True, metavar="INTERFACE:CHANNEL")
    cli.add_argument("--bitrate", type=int)
    cli.add_argument("--fd", action="store_true")
    cli.add_argument("--node-id", type=int, default=254, help="the bridge's own CAN node ID")
    cli.add_argument("--zenoh-listen", action="append", default=[], metavar="ENDPOINT")
    cli.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT")
    cli.add_argument("--zenoh-mode", default="peer", choices=["peer", "client"])
    args = cli.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    options = {**args.can, "fd": args.fd, **({"bitrate": args.bitrate} if args.bitrate else {})}
    bridge = CanZenohBridge(options, node_id=args.node_id, zenoh_mode=args.zenoh_mode,
                            zenoh_listen=args.zenoh_listen, zenoh_connect=args.zenoh_connect)  # fmt: skip
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    print("READY bridge", flush=True)
    done.wait()
    bridge.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
