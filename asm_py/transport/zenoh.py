"""ASM over Zenoh: peers on loopback by default, client mode towards a router for many machines.

The payload of every Zenoh message is the ASM protocol message, byte for byte as on CAN, so a bridge forwards it
without re-encoding. Key space (docs/protocol.md, "Zenoh key space"):

    asm/<node>/req/<source>        queryable: requests that want a reply (the reply is the query's reply)
    asm/<node>/msg/<source>        subscriber: requests that want no reply, and replies sent as messages
    asm/@group/<group>/msg/<source> subscriber: one-to-many requests (group "all": every node)
    asm/<node>/pub/<object>        publications of <node>'s attribute <object> (binary ASM message)
    asm/<node>/json/<object>       the same publication as JSON text, for any Zenoh tool or language
    asm/@alive/<node>              liveliness token: the node is up (discovery)
    asm/@estop/<source>            emergency stop from <source>, at Zenoh's real-time priority (data: reason)

Defaults are safe: peer mode, multicast scouting off, and a peer listens on a free loopback port
(``tcp/127.0.0.1:0``) unless endpoints are given — never on every interface; ``connect`` lists the peers or
router to reach. Peers that meet through a common peer connect to each other directly (gossip scouting).

Listening beyond loopback lets other machines command the robot, so :func:`make_config` allows it only with a
Zenoh configuration file that secures it — TLS (or QUIC) endpoints, mutual TLS (every peer shows a certificate
of the robot's CA) and access control enabled — or with ``insecure=True`` (the ``--insecure`` flag of the
commands), which logs a warning. docs/security.md shows a secured two-machine setup.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any

import zenoh

from ..protocol import MAX_MESSAGE, Kind, decode_timeout, kind_of
from .base import ESTOP_REASON_MAX, PublicationHandler, Transport

log = logging.getLogger("asm_py.transport.zenoh")

MAX_LINK_MESSAGE = 16 * MAX_MESSAGE
"""The largest Zenoh message a session accepts from its links (the rest is dropped by Zenoh, never buffered)."""
FOREVER_QUERY = 86_400.0
"""Seconds a query for a request that may block forever stays open on the client (Zenoh needs a number)."""
QUERY_MARGIN = 5.0


def _ignore(reply: zenoh.Reply) -> None:
    """The (absent) reply to a request that wants none."""


class InsecureEndpoint(ValueError):
    """A listening endpoint beyond loopback without TLS, mutual authentication and access control."""


def endpoint_host(endpoint: str) -> str:
    """The host of a Zenoh endpoint such as ``tcp/127.0.0.1:7447`` or ``tls/[::1]:7447#iface=lo``."""
    address = endpoint.split("#", 1)[0].split("?", 1)[0].partition("/")[2]
    return address.rpartition(":")[0].strip("[]") if ":" in address else address


def is_loopback_endpoint(endpoint: str) -> bool:
    host = endpoint_host(endpoint)
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def security_problems(config: zenoh.Config, endpoints: Sequence[str]) -> list[str]:
    """What keeps ``endpoints`` (listening beyond loopback) from being secured by ``config``; empty when secured."""
    problems = [f"{e} is not a tls/ or quic/ endpoint" for e in endpoints if not e.startswith(("tls/", "quic/"))]
    if json.loads(config.get_json("transport/link/tls/enable_mtls") or "null") is not True:
        problems.append("mutual TLS is off (transport/link/tls/enable_mtls)")
    if json.loads(config.get_json("access_control/enabled") or "false") is not True:
        problems.append("access control is off (access_control/enabled)")
    return problems


def make_config(
    *,
    mode: str = "peer",
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    config_file: str | None = None,
    insecure: bool = False,
) -> zenoh.Config:
    """A Zenoh configuration: ``mode`` peer/client/router, explicit endpoints, multicast scouting off.

    ``config_file`` (JSON5) gives everything else — TLS certificates, access control; the endpoints always come
    from ``listen`` and ``connect`` (no listen: a free loopback port, whatever the file says).

    InsecureEndpoint when a listening endpoint is beyond loopback and not secured (see the module docstring), unless
    ``insecure``.
    """
    if mode not in ("peer", "client", "router"):
        raise ValueError(f"zenoh mode must be 'peer', 'client' or 'router', not {mode!r}")
    config = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    # Never Zenoh's default listener (all interfaces): a peer or router listens on loopback unless told otherwise.
    if not listen and mode != "client":
        listen = ["tcp/127.0.0.1:0"]
    exposed = [e for e in listen if not is_loopback_endpoint(e)]
    if exposed:
        problems = security_problems(config, exposed)
        if problems and not insecure:
            raise InsecureEndpoint(f"refusing to listen on {', '.join(exposed)} beyond this machine: "
                                   f"{'; '.join(problems)}. Give a Zenoh config with TLS, mutual TLS and access "
                                   "control (docs/security.md), or --insecure")  # fmt: skip
        if problems:
            log.warning("INSECURE: listening on %s without %s: anyone who can reach it can command the robot",
                        ", ".join(exposed), "; ".join(problems))  # fmt: skip
    config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    # Zenoh buffers a message whole before anything sees it: bound that at the link (ASM messages are at most
    # MAX_MESSAGE bytes; between that and this bound a node answers TOO_LARGE, beyond it the message is dropped)
    config.insert_json5("transport/link/rx/max_message_size", str(MAX_LINK_MESSAGE))
    # Zenoh's shared-memory transport carries any message over 3 KiB as a reference into the sender's 16 MiB pool:
    # it bypasses the link limit above (a 10 MB query arrives whole) and lets every local client make this process
    # map its pool. ASM messages are at most MAX_MESSAGE bytes, so shared memory buys nothing here: off.
    config.insert_json5("transport/shared_memory/enabled", "false")
    # and drop what is larger before it reaches any callback
    config.insert_json5("low_pass_filter", json.dumps([{"flows": ["ingress"], "messages": ["put", "delete", "query",
                        "reply"], "key_exprs": ["**"], "size_limit": MAX_LINK_MESSAGE}]))  # fmt: skip
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return config


class ZenohTransport(Transport):
    """A node's Zenoh session; see the module docstring."""

    direct_requests = True

    def __init__(
        self,
        *,
        mode: str = "peer",
        listen: Sequence[str] = (),
        connect: Sequence[str] = (),
        config_file: str | None = None,
        insecure: bool = False,
    ) -> None:
        super().__init__()
        self._config = make_config(mode=mode, listen=listen, connect=connect, config_file=config_file,
                                   insecure=insecure)  # fmt: skip
        self.mode = mode
        self.listen = tuple(listen)
        self.connect = tuple(connect)
        self._session: zenoh.Session | None = None
        self._attachment = b""
        """Sent with every request: this session's Zenoh ID, so a bridge tells apart sessions of the same name."""
        self._keep: list[Any] = []  # declared entities, kept alive until close
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._queriers: dict[tuple[str, float], zenoh.Querier] = {}
        self._pub_keys: dict[str, tuple[str, str]] = {}  # object -> its publication and JSON view keys
        self._watched: dict[str, bool] = {}  # JSON key -> a subscriber matches it (kept by matching listeners)
        self._pub_lock = threading.Lock()

    @property
    def session(self) -> zenoh.Session:
        if self._session is None:
            raise RuntimeError("zenoh transport is not open")
        return self._session

    def _open(self, name: str) -> None:
        session = self._session = zenoh.open(self._config)
        self._keep += [
            session.declare_queryable(f"asm/{name}/req/*", self._on_query),
            session.declare_subscriber(f"asm/{name}/msg/*", self._on_sample),
            session.liveliness().declare_token(f"asm/@alive/{name}"),
            session.liveliness().declare_subscriber("asm/@alive/*", self._on_alive, history=True),
            # every e-stop from elsewhere, whatever its sender's name (this node's own runs its handlers directly)
            session.declare_subscriber("asm/@estop/*", self._on_estop, allowed_origin=zenoh.Locality.REMOTE),
        ]
        self._attachment = str(session.info.zid()).encode()

    def _join(self, group: str) -> None:
        self._keep.append(self.session.declare_subscriber(f"asm/@group/{group}/msg/*", self._on_sample))

    # -- receiving ------------------------------------------------------------------------------------------------

    def _on_sample(self, sample: zenoh.Sample) -> None:
        source = str(sample.key_expr).rsplit("/", 1)[-1]
        if source != self._name:
            self._deliver(source, sample.payload.to_bytes())

    def _on_query(self, query: zenoh.Query) -> None:
        source = str(query.key_expr).rsplit("/", 1)[-1]
        key = query.key_expr
        data = query.payload.to_bytes() if query.payload is not None else b""
        answered = False

        def respond(reply: bytes) -> None:
            nonlocal answered
            if not answered:
                answered = True
                try:
                    query.reply(key, reply)
                finally:
                    query.drop()

        self._deliver(source, data, respond)
        if not answered and not self._expects_reply(data):
            query.drop()

    @staticmethod
    def _expects_reply(data: bytes) -> bool:
        return kind_of(data) == Kind.REQUEST_REPLY

    def _on_estop(self, sample: zenoh.Sample) -> None:
        source = str(sample.key_expr).rsplit("/", 1)[-1]
        self._estop_received(source, sample.payload.to_bytes()[:ESTOP_REASON_MAX].decode("utf-8", errors="replace"))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        if name != self._name:
            self._peer_changed(name, sample.kind == zenoh.SampleKind.PUT)

    # -- sending --------------------------------------------------------------------------------------------------

    def _publisher(self, key: str, *, reliable: bool, express: bool = True) -> zenoh.Publisher:
        publisher = self._publishers.get(key)  # the hot path: no lock once declared
        if publisher is not None:
            return publisher
        with self._pub_lock:
            publisher = self._publishers.get(key)
            if publisher is None:
                if len(self._publishers) > 1024:  # bounded: forget the oldest declared publishers
                    for old in list(self._publishers)[:256]:
                        self._publishers.pop(old).undeclare()
                congestion = zenoh.CongestionControl.BLOCK if reliable else zenoh.CongestionControl.DROP
                publisher = self.session.declare_publisher(key, congestion_control=congestion, express=express)
                self._publishers[key] = publisher
            return publisher

    def send(self, dest: str, data: bytes) -> None:
        if self._expects_reply(data):
            self._query(dest, data)
        elif kind_of(data) == Kind.REQUEST:
            # A request without a reply goes the way of one with a reply (a query, dropped unanswered by the node):
            # Zenoh may hand a put and a query to the node on two threads, so a set followed by a get of the same
            # attribute could be served get first (119 times in 3,000). One path keeps a client's requests to a
            # node in the order it sent them, as a local call and a CAN bus do.
            self._querier(dest, QUERY_MARGIN).get(_ignore, payload=data, attachment=self._attachment)
        else:
            self._publisher(f"asm/{dest}/msg/{self.name}", reliable=True).put(data, attachment=self._attachment)

    def _query(self, dest: str, data: bytes) -> None:
        has_timeout = len(data) > 4 and data[1] & 0x80
        limit = decode_timeout(data[4]) if has_timeout else None
        timeout = FOREVER_QUERY if limit is None else limit + QUERY_MARGIN

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                self._deliver(dest, reply.ok.payload.to_bytes())

        self.session.get(f"asm/{dest}/req/{self.name}", on_reply, payload=data, timeout=timeout,
                         congestion_control=zenoh.CongestionControl.BLOCK, attachment=self._attachment)  # fmt: skip

    def request(self, dest: str, data: bytes, wait: float) -> bytes | None:
        """A query answered in the caller's thread: the fast path for requests that cannot block.

        Goes through a Querier declared once per destination and deadline (Zenoh resolves its key once).
        """
        for reply in self._querier(dest, wait).get(payload=data, attachment=self._attachment):
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
        return None

    def _querier(self, dest: str, wait: float) -> zenoh.Querier:
        """The Querier for ``dest``'s requests with deadline ``wait``, declared once (Zenoh resolves its key once)."""
        querier = self._queriers.get((dest, wait))
        if querier is None:
            with self._pub_lock:
                querier = self._queriers.get((dest, wait))
                if querier is None:
                    if len(self._queriers) > 256:  # bounded: forget the oldest
                        for old in list(self._queriers)[:64]:
                            self._queriers.pop(old).undeclare()
                    querier = self.session.declare_querier(
                        f"asm/{dest}/req/{self.name}", timeout=wait, congestion_control=zenoh.CongestionControl.BLOCK
                    )
                    self._queriers[(dest, wait)] = querier
        return querier

    def _send_estop(self, reason: str) -> None:
        self.session.put(f"asm/@estop/{self.name}", reason.encode("utf-8"), priority=zenoh.Priority.REAL_TIME,
                         congestion_control=zenoh.CongestionControl.BLOCK, express=True)  # fmt: skip

    def send_group(self, group: str, data: bytes) -> None:
        self._publisher(f"asm/@group/{group}/msg/{self.name}", reliable=True).put(data, attachment=self._attachment)

    def publish(self, object_name: str, data: bytes, json_text: Callable[[], str] | None = None) -> None:
        keys = self._pub_keys.get(object_name)
        if keys is None:
            keys = self._pub_keys[object_name] = (f"asm/{self.name}/pub/{object_name}",
                                                  f"asm/{self.name}/json/{object_name}")  # fmt: skip
        binary, view = keys
        self._publisher(binary, reliable=False, express=False).put(data)  # lock-free once declared
        if json_text is not None:
            watched = self._watched.get(view)
            if watched is None:
                watched = self._watch(view)
            if watched:
                self._publisher(view, reliable=False, express=False).put(json_text())

    def _watch(self, key: str) -> bool:
        """Follow whether anyone subscribes to the JSON view ``key``: nobody watching costs no formatting."""
        publisher = self._publisher(key, reliable=False, express=False)

        def on_matching(status: zenoh.MatchingStatus) -> None:
            self._watched[key] = status.matching

        with self._pub_lock:
            if key not in self._watched:
                self._watched[key] = publisher.matching_status.matching
                self._keep.append(publisher.declare_matching_listener(on_matching))
            return self._watched[key]

    def subscribe(
        self, node: str, object_name: str, callback: PublicationHandler, *, object_id: int | None = None
    ) -> Callable[[], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            try:
                callback(sample.payload.to_bytes())
            except Exception:
                log.exception("subscriber of %s/%s failed", node, object_name)

        subscriber = self.session.declare_subscriber(f"asm/{node}/pub/{object_name}", on_sample)

        def remove() -> None:
            if self._session is not None:
                subscriber.undeclare()

        return remove

    def peers(self) -> list[str]:
        names = set()
        for reply in self.session.liveliness().get("asm/@alive/*", timeout=2.0):
            if reply.ok is not None:
                names.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
        return sorted(names)

    def _close(self) -> None:
        session, self._session = self._session, None
        if session is None:
            return
        for entity in reversed(self._keep):
            try:
                entity.undeclare()
            except Exception:  # already gone with its session
                log.debug("undeclare failed during close", exc_info=True)
        self._keep.clear()
        self._publishers.clear()
        self._queriers.clear()
        session.close()
