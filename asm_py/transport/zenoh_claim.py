"""Claiming a name on a Zenoh network with a liveliness token and no coordinator (docs/protocol.md §6).

A session first asks for the tokens already claiming the name and refuses if there is one. Two sessions that ask
at nearly the same moment both find none, so each then declares its token, lets it travel (:data:`CLAIM_SETTLE`)
and asks again. What each then sees depends on how the race fell, and each must decide alone:

- a rival with a lesser session ID: this session gives way at once (the rival keeps the name, or gives way itself
  only to a yet lesser one);
- only rivals with greater IDs: either they saw this session and are giving way, or one of them asked before this
  session's token reached it and has already kept the name. This session cannot tell which, so it waits for them to
  withdraw their tokens and keeps the name only when they have; a rival still there after :data:`CLAIM_WAIT` has
  kept it, and this session gives way.

A session answers for the name only once it has kept it: what arrives for it while the claim is unsettled is held
(:class:`Holding`) and handled once the name is kept, or dropped unanswered if the session gives way — a session
about to give way answered for the name for up to CLAIM_WAIT before (a review measured 3,123 wrong answers in 3 s).

A session claims with a ``@claim`` token and declares its ``@alive`` token (what discovery sees) only once it has
kept the name. Tokens can take longer than CLAIM_SETTLE to travel (a look answers from what the session or its router
has heard: a review's delay proxy made both sessions keep a name at 60 ms between peers, 40 ms to a router), so the
rule goes on after the claim: a session that kept the name and then sees another ``@alive`` token for it — a rival
that kept it too — gives way at once if its ID is the greater (:meth:`Holding.give_up`: it answers nothing more for
the name and withdraws its token). A rival still claiming never triggers that, so a newcomer whose looks missed a
holder waits and gives way; it never displaces the holder.

So two sessions never both keep a name for longer than their tokens take to meet; under a stall longer than
:data:`CLAIM_WAIT` both may give way, the safe failure (each says the name is taken, and a second try succeeds).
An earlier rule had the greater ID give way and the lesser keep the name whatever it saw: a slow session whose token
arrived after its rival's second look kept the name beside it (seen once in the suite under load;
tests/transport/test_name_claims.py reproduces it). The bridge's mirrors claim, and watch, by the same rule; a robot
process's feed (server/robot_feed.py) claims and watches by it too, on its own two keys.
"""

from __future__ import annotations

import enum
import threading
import time
from collections.abc import Callable
from collections.abc import Set as AbstractSet

import zenoh

from ..keys import last

CLAIM_QUERY_TIMEOUT = 2.0
"""Seconds a session waits for the network to say whether its name is taken."""
CLAIM_SETTLE = 0.05
"""Seconds a session lets its own token travel before it asks again, and between later looks."""
CLAIM_WAIT = 3.0
"""Seconds a session whose rivals all have greater IDs waits for them to give way before it gives way itself."""


def tokens(session: zenoh.Session, key: str) -> set[str]:
    """The keys of the liveliness tokens matching ``key`` now: a query of the network."""
    replies = session.liveliness().get(key, timeout=CLAIM_QUERY_TIMEOUT)
    return {str(reply.ok.key_expr) for reply in replies if reply.ok is not None}


def sessions_holding(session: zenoh.Session, key: str) -> set[str]:
    """The session IDs (the last chunk) of the liveliness tokens matching ``key`` now: a query of the network."""
    return {last(token) for token in tokens(session, key)}


def claimants(session: zenoh.Session, alive: str, claim: str | None = None) -> set[str]:
    """The sessions that kept a name (the ``@alive`` tokens matching ``alive``) and, given ``claim``, those claiming
    it now (the ``@claim`` tokens matching it): what :func:`settle_claim` looks at. One query per key."""
    kept = sessions_holding(session, alive)
    return kept if claim is None else kept | sessions_holding(session, claim)


def gives_way(own: str, rival: str) -> bool:
    """After its claim: this session, which kept its name, must give it up on seeing ``rival``'s ``@alive`` token
    for it too (their tokens met late) — the lesser session ID keeps the name; a session's own token is no rival."""
    return rival != own and rival < own


def refuse_if_claimed(own: str, claimants: Callable[[], set[str]], refused: Callable[[str], Exception]) -> None:
    """Before declaring a token: raise ``refused(rival)`` if any other session already claims the name."""
    others = claimants() - {own}
    if others:
        raise refused(min(others))


class Verdict(enum.Enum):
    """What a session that declared its token does after one look at the claimants of its name."""

    KEEP = "keep"
    YIELD = "yield"
    WAIT = "wait"


def verdict(
    own: str, claimants: set[str], *, waited_enough: bool, previous: AbstractSet[str] = frozenset()
) -> tuple[Verdict, str]:
    """The rule of the module docstring for one look: the verdict, and the rival that decides it ("" if none).

    ``previous``: what the look before this one saw. A rival it saw that this look misses is looked for once more
    before the name is kept: under load a look through a router answered without a holder's token, and a newcomer
    kept the name beside the holder (tests/transport/test_name_claims.py, 3 of 8 runs beside two busy processes).
    The cause, found later: the session's own liveliness subscriber with history (its watch), which a node now
    declares only once its name is kept (asm_py.transport.zenoh._open; bench/liveliness_looks.py)."""
    others = claimants - {own}
    if not others:
        gone = previous - {own}
        if gone:
            return Verdict.WAIT, min(gone)
        return Verdict.KEEP, ""
    rival = min(others)
    if rival < own or waited_enough:
        return Verdict.YIELD, rival
    return Verdict.WAIT, rival


def settle_claim(
    own: str,
    claimants: Callable[[], set[str]],
    refused: Callable[[str], Exception],
    *,
    wait: float = CLAIM_WAIT,
) -> None:
    """After declaring this session's token: return once the name is this session's, or raise ``refused(rival)``
    when it must give way (the caller then withdraws its token)."""
    deadline = time.monotonic() + wait
    previous: set[str] = set()
    while True:
        time.sleep(CLAIM_SETTLE)
        seen = claimants()
        decided, rival = verdict(own, seen, waited_enough=time.monotonic() >= deadline, previous=previous)
        previous = seen
        if decided is Verdict.KEEP:
            return
        if decided is Verdict.YIELD:
            raise refused(rival)


class Holding:
    """What arrives for a name while its claim is unsettled: held, then handled once the name is kept (:meth:`keep`)
    or dropped if it is given up (:meth:`give_up`); bounded (beyond ``limit``, dropped at once)."""

    def __init__(self, limit: int = 1024) -> None:
        self.limit = limit
        self._lock = threading.Lock()
        self._held: list[tuple[Callable[[], None], Callable[[], None] | None]] = []
        self._state = Verdict.WAIT
        self.kept = False
        """True once the name is kept, for ever after: a hot path reads it (without the lock) before calling hold."""

    def hold(self, handle: Callable[[], None], drop: Callable[[], None] | None) -> bool:
        """True when the caller must not handle the arrival now: it was held, or dropped (``drop()`` called, if any:
        a query is dropped unanswered, a message simply forgotten)."""
        with self._lock:
            if self._state is Verdict.KEEP:
                return False
            if self._state is Verdict.WAIT and len(self._held) < self.limit:
                self._held.append((handle, drop))
                return True
        if drop is not None:
            drop()
        return True

    def give_up(self) -> bool:
        """The name is given up, whether or not it was kept (a rival that kept it too may have a lesser ID): drop
        what was held and everything after. False if it was given up already."""
        with self._lock:
            if self._state is Verdict.YIELD:
                return False
            self._state, held, self._held = Verdict.YIELD, self._held, []
            self.kept = False
        for _, drop in held:
            if drop is not None:
                drop()
        return True

    def keep(self) -> None:
        """The name is kept: handle what was held, in order, and everything after at once (once, while unsettled)."""
        with self._lock:
            if self._state is not Verdict.WAIT:
                return
            self._state, held, self._held = Verdict.KEEP, self._held, []
            self.kept = True
        for handle, _ in held:
            handle()
