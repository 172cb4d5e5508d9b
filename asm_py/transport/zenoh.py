"""ASM over Zenoh: peers on loopback by default, client mode towards a router for many machines and robots.

The payload of every Zenoh message is the ASM protocol message, byte for byte as on CAN, so a bridge forwards it
without re-encoding. Every key comes from asm_py.keys: a session belongs to one **robot** (its namespace, default
``robot``) and has a **role** — ``"module"`` (it answers for a module name) or ``"tool"`` (the default: a studio, a
script, a command; its keys carry ``~`` before its name, so it can never answer for a module). A session refuses to
open, with :class:`NameTaken`, when its name is already alive in its robot and role.

Addresses (asm_py.keys): ``m3`` is module m3 of the session's robot, ``~studio`` a tool of it, ``b/m3`` module m3
of robot b. The robot e-stop reaches every node of the session's robot; the lab-wide one (``estop(lab=True)``)
every node of every robot.

Configuration (safe defaults, the rules for listening beyond loopback) is in asm_py.transport.zenoh_config.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any

import zenoh

from ..keys import (
    DEFAULT_ROBOT,
    Address,
    RobotKeys,
    Route,
    check_name,
    concrete,
    lab_estop,
    last,
    parse_address,
    segment,
    split,
)
from ..protocol import HEADER_SIZE, Kind, decode_timeout, has_timeout, kind_of
from . import zenoh_claim
from .base import ESTOP_REASON_MAX, PublicationHandler, PublicationSender, Transport
from .zenoh_claim import Holding, claimants, gives_way, refuse_if_claimed, settle_claim
from .zenoh_config import (  # noqa: F401  (re-exported: the configuration is part of this transport's interface)
    MAX_LINK_MESSAGE,
    InsecureEndpoint,
    endpoint_host,
    is_loopback_endpoint,
    make_config,
    security_problems,
)
from .zenoh_drain import IGNORE_REPLIES, drained
from .zenoh_requests import ReplyKeys, RequestQueue, refuse_busy
from .zenoh_watch import MAX_VIEWS, WatchedPublisher

log = logging.getLogger("asm_py.transport.zenoh")

FOREVER_QUERY = 86_400.0
"""Seconds a query for a request that may block forever stays open on the client (Zenoh needs a number)."""
QUERY_MARGIN = 5.0
ROLES = ("module", "tool")


class NameTaken(RuntimeError):
    """Another session already claims this node's name in its robot."""


class ZenohTransport(Transport):
    """A node's Zenoh session; see the module docstring."""

    direct_requests = True

    def __init__(
        self,
        *,
        robot: str = DEFAULT_ROBOT,
        role: str = "tool",
        mode: str = "peer",
        listen: Sequence[str] = (),
        connect: Sequence[str] = (),
        config_file: str | None = None,
        insecure: bool = False,
    ) -> None:
        super().__init__()
        if role not in ROLES:
            raise ValueError(f"a Zenoh session's role is 'module' or 'tool', not {role!r}")
        self._config = make_config(mode=mode, listen=listen, connect=connect, config_file=config_file,
                                   insecure=insecure)  # fmt: skip
        self.keys = RobotKeys(robot)
        self.robot = self.keys.robot
        self.role = role
        self.mode = mode
        self.listen = tuple(listen)
        self.connect = tuple(connect)
        self.segment = ""
        """This node's chunk in keys: its name, or ``~name`` for a tool."""
        self._session: zenoh.Session | None = None
        self._zid = ""
        self._attachment = b""
        """Sent with every request: this session's Zenoh ID, so a bridge tells apart sessions of the same name."""
        self._keep: list[Any] = []  # declared entities, kept alive until close
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._queriers: dict[tuple[str, float], zenoh.Querier] = {}
        self.max_queriers = 1024
        """Queriers kept (one per destination and deadline: 8 deadlines of 128 modules fit)."""
        self._routes: dict[str, Route] = {}
        self._senders: dict[str, PublicationSender] = {}  # published object -> its sender (publication_sender)
        self._views: dict[str, WatchedPublisher] = {}  # JSON view key -> its publisher, and whether it is watched
        self._kept_views: set[str] = set()  # the views of published attributes' senders: never forgotten
        self._claims: dict[str, set[str]] = {}  # segment -> sessions whose liveliness token claims it
        self._pub_lock = threading.Lock()
        self._reply_key = ReplyKeys(lambda source: self.keys.requests(self.segment, concrete(source)))
        self._holding = Holding()
        self._handoffs: list[RequestQueue[Any]] = []  # the requests', then one per subscription (zenoh_requests)
        self._token: Any = None
        self.name_lost = ""
        """The session this one gave its name to after keeping it ("" while it keeps it): see _rival_kept."""

    @property
    def session(self) -> zenoh.Session:
        if self._session is None:
            raise RuntimeError("zenoh transport is not open")
        return self._session

    @property
    def address(self) -> str:
        return self.segment

    @property
    def zid(self) -> str:
        """This session's Zenoh ID (hex)."""
        return self._zid

    # -- opening --------------------------------------------------------------------------------------------------

    def _open(self, name: str) -> None:
        self.segment = segment(name, tool=self.role == "tool")
        session = self._session = zenoh.open(self._config)
        self._holding = Holding()  # requests and messages for the name, held until it is this session's
        self._zid = str(session.info.zid())
        self._attachment = self._zid.encode()
        try:
            refuse_if_claimed(self._zid, lambda: self.claimants(self.segment), self._name_taken)
            keys = self.keys
            claiming = session.liveliness().declare_token(keys.claim(self.segment, self._zid))
            requests = self._handoff("requests", self._on_query, self._refuse_query, zenoh.Query.drop)
            self._keep += [
                claiming,
                session.declare_queryable(keys.requests(self.segment), requests),
                session.declare_subscriber(keys.messages(self.segment), self._handoff("messages", self._on_sample)),
                # every e-stop from elsewhere, whatever its sender's name (this node's own runs its handlers directly)
                session.declare_subscriber(keys.estop(), self._on_estop, allowed_origin=zenoh.Locality.REMOTE),
                session.declare_subscriber(lab_estop(), self._on_estop, allowed_origin=zenoh.Locality.REMOTE),
            ]
            settle_claim(self._zid, self._rivals, self._name_taken)
            # kept: the node's @alive token (discovery sees it from now on), then the claim withdrawn
            self._token = session.liveliness().declare_token(keys.alive(self.segment, self._zid))
            self._keep.append(self._token)
            self._keep.remove(claiming)
            claiming.undeclare()
        except BaseException:
            self._holding.give_up()
            self._close()
            raise
        self._holding.keep()
        # The watch of every node's token, only now the name is kept: beside a liveliness subscriber with history on
        # keys it overlaps, Zenoh 1.10.2's liveliness get answered without tokens that were there (under load: the
        # claim's looks missed the holder and a newcomer kept its name; bench/liveliness_looks.py). Its history
        # brings any rival that kept the name too to _rival_kept, as a later token would.
        try:
            self._keep.append(session.liveliness().declare_subscriber(keys.alive(), self._on_alive, history=True))
        except BaseException:
            self._close()
            raise

    def claimants(self, seg: str) -> set[str]:
        """The sessions that kept segment ``seg`` in this robot: their ``@alive`` tokens, from a query of the network
        and from this node's watch (a query beside the watch can miss tokens that are there: see _open)."""
        return claimants(self.session, self.keys.alive(seg)) | self._watched(seg)

    def _rivals(self) -> set[str]:
        """The sessions that kept this node's name or claim it now: what settle_claim looks at."""
        return claimants(self.session, self.keys.alive(self.segment), self.keys.claim(self.segment))

    def _watched(self, seg: str) -> set[str]:
        """The sessions whose ``@alive`` token for ``seg`` this node's watch has seen and not seen withdrawn."""
        with self._lock:
            return set(self._claims.get(seg, ()))

    def _name_taken(self, rival: str) -> NameTaken:
        role = "tool" if self.role == "tool" else "module"
        return NameTaken(f"a {role} named {self.segment.lstrip('~')!r} is already alive in robot {self.robot!r} "
                         f"(session {rival}): choose another name")  # fmt: skip

    def _join(self, group: str) -> None:
        handler = self._handoff(group, self._on_sample)
        self._keep.append(self.session.declare_subscriber(self.keys.group(group), handler))

    def _handoff(self, what: str, serve: Callable[[Any], None], refuse: Any = None, discard: Any = None) -> Any:
        """An entity's handler, a queue and a thread of its own (zenoh_requests). The requests' queue answers one it
        cannot hold BUSY (_refuse_query) and drops one left at close; a message refused or left is dropped."""
        self._handoffs.append(RequestQueue(serve, refuse, f"{self._name} {what}", discard=discard or (lambda _: None)))
        return self._handoffs[-1].callback()

    # -- receiving ------------------------------------------------------------------------------------------------

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if not self._holding.kept and self._holding.hold(lambda: self._on_sample(sample), None):
            return
        source = last(sample.key_expr)
        if source != self.segment:
            self._deliver(source, sample.payload.to_bytes())

    def _on_query(self, query: zenoh.Query) -> None:
        """On the node's request thread (zenoh_requests), not on Zenoh's own: a handler may block (a set's change
        callback calling another node) without holding Zenoh's network thread."""
        if not self._holding.kept and self._holding.hold(lambda: self._on_query(query), query.drop):
            return
        source = last(query.key_expr)
        key = self._reply_key(source)
        data = query.payload.to_bytes() if query.payload is not None else b""
        answered = False

        def respond(reply: bytes) -> None:
            nonlocal answered
            if not answered:
                answered = True
                try:
                    query.reply(key, reply, express=True)
                finally:
                    query.drop()

        self._deliver(source, data, respond)
        if not answered and not self._expects_reply(data):
            query.drop()

    def _refuse_query(self, query: zenoh.Query, closed: bool) -> None:
        """A request the queue cannot hold (zenoh_requests): BUSY at once to one that wants a reply, unless this
        session is closing or does not keep the name (a claim refused: the holder answers, never this one)."""
        if closed or not self._holding.kept:
            query.drop()
        else:
            refuse_busy(query, self._reply_key(last(query.key_expr)), self.segment)

    @staticmethod
    def _expects_reply(data: bytes) -> bool:
        return kind_of(data) == Kind.REQUEST_REPLY

    def _on_estop(self, sample: zenoh.Sample) -> None:
        source = last(sample.key_expr)
        self._estop_received(source, sample.payload.to_bytes()[:ESTOP_REASON_MAX].decode("utf-8", errors="replace"))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        chunks = split(sample.key_expr)  # asm/<robot>/@alive/<segment>/<session>
        if len(chunks) != 5:
            return
        seg, zid = chunks[3], chunks[4]
        alive = sample.kind == zenoh.SampleKind.PUT
        with self._lock:
            claims = self._claims.setdefault(seg, set())
            before = bool(claims)
            (claims.add if alive else claims.discard)(zid)
            now = bool(claims)
        if seg == self.segment:
            if alive and zid != self._zid:
                self._rival_kept(zid)
            return
        if before != now:
            self._peer_changed(seg, now)

    def _rival_kept(self, rival: str) -> None:
        """Another session kept this node's name too: their claims missed each other's tokens (a link slower than
        the settle). Of two sessions that both kept it, the lesser ID keeps it: the greater gives way at once (it
        answers nothing more for the name and withdraws its token). A session still claiming never triggers this:
        a newcomer does not displace a holder (asm_py.transport.zenoh_claim)."""
        if not self._holding.kept:  # still claiming (settle_claim decides) or given way already
            return
        if not gives_way(self._zid, rival):
            # resolved in this session's favour: a warning (the one that gives way logs the error)
            log.warning("another session (%s) kept this node's name %r in robot %r too: it gives way (the lesser ID "
                        "keeps the name)", rival, self.segment, self.robot)  # fmt: skip
            return
        if self._holding.give_up():
            self.name_lost = rival
            log.error("another session (%s) kept this node's name %r in robot %r too (their tokens met late): this "
                      "session gives way and no longer answers for it", rival, self.segment, self.robot)  # fmt: skip
            try:
                self._token.undeclare()
            except Exception:  # closing meanwhile
                log.debug("the token was gone already", exc_info=True)

    # -- addresses ------------------------------------------------------------------------------------------------

    def _route(self, dest: str) -> Route:
        route = self._routes.get(dest)  # the hot path: one dictionary lookup per message
        if route is None:
            address: Address = parse_address(dest)
            keys = self.keys if address.robot in (None, self.robot) else RobotKeys(address.robot)
            route = Route(keys, address.segment)
            if len(self._routes) > 4096:  # bounded: addresses come from callers, possibly many
                self._routes.clear()
            self._routes[dest] = route
        return route

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
            self._querier(dest, QUERY_MARGIN).get(IGNORE_REPLIES, payload=data, attachment=self._attachment)
        else:
            route = self._route(dest)
            self._publisher(route.keys.messages(route.segment, self.segment), reliable=True).put(
                data, attachment=self._attachment
            )

    def _query(self, dest: str, data: bytes) -> None:
        limit = decode_timeout(data[HEADER_SIZE]) if len(data) > HEADER_SIZE and has_timeout(data) else None
        timeout = FOREVER_QUERY if limit is None else limit + QUERY_MARGIN
        route = self._route(dest)

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                self._deliver(dest, reply.ok.payload.to_bytes())

        self.session.get(route.keys.requests(route.segment, self.segment), on_reply, payload=data, timeout=timeout,
                         congestion_control=zenoh.CongestionControl.BLOCK, attachment=self._attachment)  # fmt: skip

    def request(self, dest: str, data: bytes, wait: float) -> bytes | None:
        """A query answered in the caller's thread: the fast path for requests that cannot block.

        Goes through a Querier declared once per destination and deadline (Zenoh resolves its key once).
        """
        querier = self._querier(dest, wait)  # held until the reply is in: a querier dropped sooner loses it
        for reply in querier.get(payload=data, attachment=self._attachment):
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
        return None

    def _querier(self, dest: str, wait: float) -> zenoh.Querier:
        """The Querier for ``dest``'s requests with deadline ``wait``, declared once (Zenoh resolves its key once)."""
        querier = self._queriers.get((dest, wait))
        if querier is None:
            route = self._route(dest)
            with self._pub_lock:
                querier = self._queriers.get((dest, wait))
                if querier is None:
                    if len(self._queriers) >= self.max_queriers:  # bounded: forget the oldest quarter
                        for old in list(self._queriers)[: max(1, self.max_queriers // 4)]:
                            # dropped, not undeclared here: another thread may be in its get() (undeclaring under
                            # it raised "Already borrowed"); Zenoh undeclares it when the last reference goes
                            del self._queriers[old]
                    key = route.keys.requests(route.segment, self.segment)
                    congestion = zenoh.CongestionControl.BLOCK
                    querier = self.session.declare_querier(
                        key,
                        timeout=wait,
                        congestion_control=congestion,
                        express=True,
                        consolidation=zenoh.ConsolidationMode.NONE,
                    )
                    self._queriers[(dest, wait)] = querier
        return querier

    def _send_estop(self, reason: str, lab: bool) -> None:
        key = lab_estop(self.segment) if lab else self.keys.estop(self.segment)
        self.session.put(key, reason.encode("utf-8"), priority=zenoh.Priority.REAL_TIME,
                         congestion_control=zenoh.CongestionControl.BLOCK, express=True)  # fmt: skip

    def send_group(self, group: str, data: bytes) -> None:
        self._publisher(self.keys.group(group, self.segment), reliable=True).put(data, attachment=self._attachment)

    def publish(self, object_name: str, data: bytes, json_text: Callable[[], str] | None = None) -> None:
        """Through the object's sender when a published attribute made one; any other name goes through the bounded
        set of publishers (``publish`` takes any name, so it must not declare one publisher per name for good)."""
        sender = self._senders.get(object_name)
        if sender is not None:
            sender(data, json_text)
            return
        publisher = self._publisher(self.keys.publication(self.segment, object_name), reliable=False, express=False)
        key = self.keys.json_view(self.segment, object_name)
        view = (self._views.get(key) or self._watch(key)) if json_text is not None else None
        try:
            publisher.put(data)
            if view is not None and json_text is not None and view.watched:
                view.put(json_text())
        except zenoh.ZError:  # forgotten under it by another thread's publish (past the bounds): dropped, as when
            if self._session is None:  # congested; after the close, it is refused as before
                raise

    def publication_sender(self, object_name: str) -> PublicationSender:
        """A put on the object's declared publisher, and its JSON view's put when someone watches the view. The
        publisher is not one of ``_publisher``'s bounded set: a published attribute of this node asks for it, one per
        object of its registry."""
        known = self._senders.get(object_name)
        if known is not None:
            return known
        view = self._watch(self.keys.json_view(self.segment, object_name), keep=True)
        with self._pub_lock:
            known = self._senders.get(object_name)
            if known is not None:
                return known
            binary = self.keys.publication(self.segment, object_name)
            drop = zenoh.CongestionControl.DROP
            put = self.session.declare_publisher(binary, congestion_control=drop, express=False).put

            def sender(data: bytes, json_text: Callable[[], str] | None = None) -> None:
                put(data)
                if json_text is not None and view.watched:
                    view.put(json_text())

            self._senders[object_name] = sender
            return sender

    def _watch(self, key: str, *, keep: bool = False) -> WatchedPublisher:
        """The JSON view ``key``'s publisher, following whether anyone subscribes: nobody watching costs no
        formatting. ``keep``: a published attribute's (one per object of this node's registry); the others, made
        by ``publish`` under any name, are bounded: past 1,024 views the oldest quarter of them is forgotten."""
        with self._pub_lock:
            watched = self._views.get(key)
            if watched is None:
                if len(self._views) >= MAX_VIEWS:
                    for old in [k for k in self._views if k not in self._kept_views][: MAX_VIEWS // 4]:
                        self._views.pop(old).close()
                drop = zenoh.CongestionControl.DROP
                publisher = self.session.declare_publisher(key, congestion_control=drop, express=False)
                watched = self._views[key] = WatchedPublisher(publisher)
            if keep:
                self._kept_views.add(key)
            return watched

    def subscribe(
        self, node: str, object_name: str, callback: PublicationHandler, *, object_id: int | None = None
    ) -> Callable[[], None]:
        """Delivered on the subscription's own thread, through a ring that never blocks Zenoh's receive task (a hung
        listener drops its oldest publications, not the session's replies and e-stops): zenoh_drain."""
        check_name(object_name, "object name")
        route = self._route(node)
        key = route.keys.publication(route.segment, object_name)
        subscriber = drained(self.session.declare_subscriber, key, callback)

        def remove() -> None:
            if self._session is not None:
                subscriber.undeclare()

        return remove

    def peers(self) -> list[str]:
        with self._lock:  # what the watch saw, and what a query finds (either can miss a token: see _open)
            names = {self.segment, *(seg for seg, sessions in self._claims.items() if sessions)}
        for token in zenoh_claim.tokens(self.session, self.keys.alive()):
            chunks = split(token)
            if len(chunks) == 5:
                names.add(chunks[3])
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
        for handoff in self._handoffs:
            handoff.close()
        self._handoffs.clear()
        for watched in self._views.values():
            try:
                watched.close()
            except Exception:  # already gone with its session
                log.debug("undeclare failed during close", exc_info=True)
        self._views.clear()
        self._kept_views.clear()
        self._senders.clear()
        self._publishers.clear()
        self._queriers.clear()
        session.close()
