"""Name claims on Zenoh (asm_py.transport.zenoh_claim): however two claims of one name interleave, at most one
session keeps it. The race that broke this under load is replayed deterministically: sessions are given their
Zenoh IDs (so who is "greater" is known), and the late session's first look is made blind, as when its rival's token
had not reached it yet."""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from asm_py import Attribute, Node
from asm_py.keys import RobotKeys
from asm_py.transport import zenoh_claim
from asm_py.transport.zenoh import NameTaken, ZenohTransport
from asm_py.transport.zenoh_claim import (
    CLAIM_WAIT,
    Holding,
    Verdict,
    gives_way,
    refuse_if_claimed,
    sessions_holding,
    settle_claim,
    verdict,
)
from asm_py.transport.zenoh_config import make_config

from ..helpers import until_answered, wait_until
from .claims import GREATER, LESSER, blind_first_look, config_with_id

pytestmark = pytest.mark.timeout(60)


class Taken(Exception):
    pass


def looks(*answers: set[str]) -> Callable[[], set[str]]:
    """A network that answers each look with the next of ``answers`` (the last one from then on)."""
    given = itertools.chain(answers, itertools.repeat(answers[-1]))
    return lambda: next(given)


LOOKS_DECIDE, WAIT_DECIDES = 30.0, 0.3
"""The claim's wait in the cases below: long, where the looks alone decide (no delay of a look under the suite's load
comes near it), and short where it is the wait that decides (a greater rival that stays)."""


@pytest.mark.parametrize(
    ("answers", "kept", "wait"),
    [
        (({"me"},), True, LOOKS_DECIDE),  # only this session's own token
        (({"me", "a"},), False, LOOKS_DECIDE),  # a lesser rival: give way at once
        (({"me", "z"}, {"me", "z"}, {"me"}), True, LOOKS_DECIDE),  # a greater rival that gives way
        (({"me", "z"},), False, WAIT_DECIDES),  # a greater rival that stays: it kept the name
        (({"me", "z"}, {"me", "z", "a"}), False, LOOKS_DECIDE),  # a lesser rival arrives while waiting
        # one look that misses a holder still there (seen under load: a look through the router answered at once,
        # without the holder's token, and the newcomer kept the name beside it): looked at again before keeping
        (({"me", "z"}, {"me"}, {"me", "z"}), False, WAIT_DECIDES),
        (({"me", "z"}, {"me"}, {"me"}), True, LOOKS_DECIDE),  # gone in two looks running: it gave way
    ],
)
def test_the_rule_after_a_claim(answers: tuple[set[str], ...], kept: bool, wait: float) -> None:
    """A three-worker run failed the last case when every case waited 0.3 s: under the suite's load its first look
    came after the wait, and a greater rival already leaving was given way to on that one look."""
    began = time.monotonic()
    try:
        settle_claim("me", looks(*answers), Taken, wait=wait)
    except Taken:
        assert not kept
    else:
        assert kept
    assert time.monotonic() - began < 5


def test_a_rival_one_look_misses_is_looked_for_again_before_the_name_is_kept() -> None:
    """The rule itself, without the clock: under load the case above can reach its wait before its second look."""
    assert verdict("me", {"me"}, waited_enough=False, previous={"me", "z"}) == (Verdict.WAIT, "z")
    assert verdict("me", {"me"}, waited_enough=True, previous={"me", "z"}) == (Verdict.WAIT, "z")
    assert verdict("me", {"me"}, waited_enough=False, previous={"me"}) == (Verdict.KEEP, "")
    assert verdict("me", {"me", "z"}, waited_enough=False, previous={"me"}) == (Verdict.WAIT, "z")
    assert verdict("me", {"me", "z"}, waited_enough=True) == (Verdict.YIELD, "z")
    assert verdict("me", {"me", "a", "z"}, waited_enough=False) == (Verdict.YIELD, "a")


def test_once_kept_a_name_is_given_up_only_to_a_lesser_session_that_kept_it_too() -> None:
    """The rule every holder applies (a node's transport, a bridge mirror, a robot feed) to another ``@alive`` token
    of its name: one function, so the three cannot disagree."""
    assert gives_way("me", "a") and not gives_way("me", "z") and not gives_way("me", "me")


def test_the_first_look_refuses_any_rival_and_names_the_least() -> None:
    refuse_if_claimed("me", looks({"me"}), Taken)
    with pytest.raises(Taken, match=r"^a$"):
        refuse_if_claimed("me", looks({"z", "a"}), Taken)


def test_a_greater_rival_that_stays_is_waited_for_no_longer_than_the_claim_wait() -> None:
    began = time.monotonic()
    with pytest.raises(Taken):
        settle_claim("me", looks({"me", "z"}), Taken)
    assert CLAIM_WAIT <= time.monotonic() - began < CLAIM_WAIT + 5


@pytest.fixture
def session_with_id(router: str, tmp_path: Path) -> Iterator[Callable[[str], zenoh.Session]]:
    """Open client sessions of the router with the Zenoh IDs given; every one is closed at the end."""
    opened: list[zenoh.Session] = []

    def open_session(zid: str) -> zenoh.Session:
        opened.append(zenoh.open(make_config(mode="client", connect=[router],
                                             config_file=config_with_id(tmp_path, zid))))  # fmt: skip
        return opened[-1]

    yield open_session
    for session in opened:
        session.close()


def replies(session: zenoh.Session, key: str, timeout: float = 1.0) -> list[zenoh.Reply]:
    """The good replies to one query of ``key``."""
    return [reply for reply in session.get(key, timeout=timeout) if reply.ok is not None]


def test_a_late_claim_meets_a_session_that_kept_the_name_and_gives_way(
    router: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The greater ID looked before the lesser's token reached it and kept the name; the lesser, whose first look
    missed the greater's token, must not keep it too (the old tie-break let it)."""

    def transport(zid: str) -> ZenohTransport:
        return ZenohTransport(robot="a", role="module", mode="client", connect=[router],
                              config_file=config_with_id(tmp_path, zid))  # fmt: skip

    blind_first_look(monkeypatch, ZenohTransport, "claimants", lambda t: getattr(t, "zid", "") == LESSER)
    first = Node("m7", transport(GREATER))
    first.register(Attribute("where", "first", codec="str"))
    tool = Node("tester", ZenohTransport(robot="a", mode="client", connect=[router]))
    second: list[Node | BaseException] = []
    claiming = threading.Thread(target=lambda: second.append(_made(lambda: Node("m7", transport(LESSER)))))
    try:
        claiming.start()
        answers: list[object] = []
        while claiming.is_alive():  # the second claims for up to CLAIM_WAIT: it must answer nothing meanwhile
            answers.append(_made(lambda: tool.lookup("m7", "where", timeout=2).get()))
        claiming.join()
        assert len(second) == 1 and isinstance(second[0], NameTaken), second
        assert f"module named 'm7' is already alive in robot 'a' (session {GREATER}" in str(second[0])
        assert first.transport.claimants("m7") == {GREATER}  # type: ignore[attr-defined]  # (the refused token gone)
        assert len(answers) >= 10 and set(map(str, answers)) == {"first"}, set(map(repr, answers))
    finally:
        claiming.join(30)
        for node in (first, tool, *second):
            if isinstance(
                node, Node
            ):  # (a second kept in spite of the rule is closed too: no session outlives the test)
                node.close()


def test_two_sessions_that_both_kept_a_name_settle_it_once_their_tokens_meet(
    router: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Tokens slower than the claim's looks (every look blind here, as over a slow link): both keep the name; once
    each sees the other's token the greater ID gives way — answers nothing more, withdraws its token — and only the
    lesser answers."""
    real_claimants = ZenohTransport.claimants
    monkeypatch.setattr(ZenohTransport, "_rivals", lambda self: {self.zid})  # every look blind
    monkeypatch.setattr(ZenohTransport, "claimants", lambda self, seg: {self.zid})

    def module(zid: str, where: str) -> Node:
        node = Node("m7", ZenohTransport(robot="a", role="module", mode="client", connect=[router],
                                         config_file=config_with_id(tmp_path, zid)))  # fmt: skip
        node.register(Attribute("where", where, codec="str"))
        return node

    made: list[Node] = []
    try:
        made.append(module(GREATER, "greater"))
        made.append(module(LESSER, "lesser"))  # kept too: its looks saw nothing
        made.append(Node("tester", ZenohTransport(robot="a", mode="client", connect=[router])))
        greater, lesser, tool = made
        assert wait_until(lambda: greater.transport.name_lost == LESSER, timeout=10)  # type: ignore[attr-defined]
        assert lesser.transport.name_lost == ""  # type: ignore[attr-defined]
        assert wait_until(lambda: real_claimants(tool.transport, "m7") == {LESSER}, timeout=10)  # type: ignore[arg-type]
        answers = [_made(lambda: tool.lookup("m7", "where", timeout=2).get()) for _ in range(50)]
        assert set(map(str, answers)) == {"lesser"}, set(map(repr, answers))
    finally:
        for node in made:
            node.close()


def test_a_newcomer_that_claims_beside_a_holder_never_displaces_it(
    router: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A holder with the greater ID, and a newcomer (lesser ID) whose first look missed it: the holder ignores the
    newcomer's claim, the newcomer gives way after its wait; the holder answers throughout."""
    blind_first_look(monkeypatch, ZenohTransport, "claimants", lambda t: getattr(t, "zid", "") == LESSER)
    holder = Node("m7", ZenohTransport(robot="a", role="module", mode="client", connect=[router],
                                       config_file=config_with_id(tmp_path, GREATER)))  # fmt: skip
    try:
        with pytest.raises(NameTaken):
            Node("m7", ZenohTransport(robot="a", role="module", mode="client", connect=[router],
                                      config_file=config_with_id(tmp_path, LESSER)))  # fmt: skip
        assert holder.transport.name_lost == ""  # type: ignore[attr-defined]
        assert holder.transport.claimants("m7") == {GREATER}  # type: ignore[attr-defined]
    finally:
        holder.close()


def _made(make: Callable[[], object]) -> object:
    """What ``make()`` returned, or the exception it raised."""
    try:
        return make()
    except Exception as exc:
        return exc


def test_a_late_robot_meets_a_robot_of_its_name_and_gives_way(
    session_with_id: Callable[[str], zenoh.Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    from asm_module.feed import RobotStatus
    from server.robot_feed import RobotFeed, RobotNameTaken

    sessions = {zid: session_with_id(zid) for zid in (GREATER, LESSER)}
    blind_first_look(monkeypatch, RobotFeed, "_claimants", lambda f: f.session is sessions[LESSER])  # type: ignore[attr-defined]
    lost: list[str] = []
    feeds = [RobotFeed(sessions[GREATER], RobotStatus("z", "real", 0), on_lost=lost.append)]
    try:
        with pytest.raises(RobotNameTaken, match=f"session {GREATER}"):
            feeds.append(RobotFeed(sessions[LESSER], RobotStatus("z", "real", 0)))
        # the newcomer's claim never made the holder give way, though the newcomer's ID is the lesser
        assert feeds[0].lost is None and lost == []
        # looked at from a session of its own: the holder's session watches these tokens with history, and Zenoh
        # 1.10.2 leaves live tokens out of such a session's liveliness answers under load (bench/liveliness_looks.py;
        # a fresh-clone run with three workers read set() here)
        outside = session_with_id("7007")
        assert sessions_holding(outside, RobotKeys("z").robot_alive()) == {GREATER}
    finally:
        for feed in feeds:
            feed.close()


def test_two_robot_processes_that_both_kept_a_name_settle_it_once_their_tokens_meet(
    session_with_id: Callable[[str], zenoh.Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every look blind (as over a link slower than the claim's looks): both robot feeds keep the name; once each
    sees the other's token the greater ID gives way — says so, withdraws its token, answers and publishes nothing
    more — and only the lesser's robot answers to the name. (Before, both stayed: a studio's status query had two
    robots answer as one.)"""
    from asm_module.feed import RobotStatus
    from server.robot_feed import RobotFeed

    monkeypatch.setattr(zenoh_claim, "sessions_holding", lambda session, key: {str(session.info.zid())})
    sessions = {zid: session_with_id(zid) for zid in (GREATER, LESSER, "7007")}
    lost: dict[str, list[str]] = {GREATER: [], LESSER: []}
    feeds: list[RobotFeed] = []
    try:
        for zid in (GREATER, LESSER):
            feeds.append(RobotFeed(sessions[zid], RobotStatus("z", "real", 0), on_lost=lost[zid].append))
        greater, lesser = feeds
        # (lost is set before on_lost is called, on Zenoh's thread: wait for both)
        assert wait_until(lambda: greater.lost == LESSER and lost[GREATER] != [], timeout=10)
        assert lost == {GREATER: [LESSER], LESSER: []} and lesser.lost is None
        tool, keys = sessions["7007"], RobotKeys("z")
        assert wait_until(lambda: sessions_holding(tool, keys.robot_alive()) == {LESSER}, timeout=10)
        heard: list[bytes] = []
        watcher = tool.declare_subscriber(
            keys.robot_key("status"), lambda sample: heard.append(sample.payload.to_bytes())
        )
        try:
            # this session's first query of a queryable can go nowhere under load (a fresh-clone run with four
            # workers got no answer to one of the five): asked until the status answers first, then counted
            assert until_answered(tool, keys.robot_key("status"))
            for _ in range(5):  # one robot answers the status, and only the lesser publishes it
                assert len(replies(tool, keys.robot_key("status"), timeout=2)) == 1
                greater.publish_status()
            assert heard == []
            lesser.publish_status()
            assert wait_until(lambda: len(heard) == 1, timeout=10)
        finally:
            watcher.undeclare()
    finally:
        for feed in feeds:
            feed.close()


def test_a_feed_that_gives_way_while_it_starts_answers_nothing(
    session_with_id: Callable[[str], zenoh.Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The watch's first call can come at once, on Zenoh's thread, while the feed is still being made: what it
    withdraws must be everything the feed declared (a review saw the status queryable answer on after the feed gave
    way in 6 of 8 runs, and after close() in 5)."""
    from asm_module.feed import RobotStatus
    from server.robot_feed import RobotFeed

    monkeypatch.setattr(zenoh_claim, "sessions_holding", lambda session, key: {str(session.info.zid())})
    sessions = {zid: session_with_id(zid) for zid in (GREATER, LESSER, "7007")}
    keys, tool = RobotKeys("z"), sessions["7007"]
    token = sessions[LESSER].liveliness().declare_token(keys.robot_alive(LESSER))
    try:
        for _ in range(4):
            feed = RobotFeed(sessions[GREATER], RobotStatus("z", "real", 0), mjcf="<mujoco/>")
            try:
                assert wait_until(lambda feed=feed: feed.lost == LESSER, timeout=10)
                for what in ("status", "mjcf"):
                    assert replies(tool, keys.robot_key(what)) == []
            finally:
                feed.close()
            for what in ("status", "mjcf"):
                assert replies(tool, keys.robot_key(what)) == []
    finally:
        token.undeclare()


def test_asm_robot_that_finds_its_name_kept_by_a_lesser_session_ends_with_exit_1(
    router: str, tmp_path: Path, session_with_id: Callable[[str], zenoh.Session]
) -> None:
    """The process behind a feed that gave way: it closes in order and exits 1, saying which session kept the name."""
    from server.child import Child

    from ..processes import ROOT

    robot = Child("-m", "server.robot", "--name", "z", "--zenoh-mode", "client", "--zenoh-connect", router,
                  "--zenoh-config", config_with_id(tmp_path, GREATER), cwd=ROOT)  # fmt: skip
    rival = session_with_id(LESSER)
    try:
        robot.wait_for_line("READY robot z", timeout=60)
        token = rival.liveliness().declare_token(RobotKeys("z").robot_alive(LESSER))  # tokens that met late
        robot.popen.wait(timeout=30)
        assert robot.popen.returncode == 1, "".join(robot.output)
        assert f"kept the name too (session {LESSER}" in "".join(robot.output)
        token.undeclare()
    finally:
        robot.stop()


def test_a_bridge_mirror_that_claimed_late_beside_a_kept_name_is_withdrawn(
    router: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A CAN module m1 behind a bridge, and a Zenoh module m1 that already kept the name: the bridge, whose first
    look missed the Zenoh module's token, withdraws its mirror (and the Zenoh module alone answers for m1)."""
    from server.bridge import CanZenohBridge
    from server.zenoh_args import ZenohOptions

    from ..transports import FAST_BEATS, fresh_name

    can_options = {"interface": "virtual", "channel": fresh_name("asm-claims"), **FAST_BEATS}
    blind_first_look(monkeypatch, CanZenohBridge, "_claimants", lambda b: getattr(b, "_zid", "") == LESSER)
    network = ZenohOptions(mode="client", connect=(router,), config_file=config_with_id(tmp_path, LESSER))
    closing: list[Node | CanZenohBridge] = []
    try:
        zenoh_m1 = Node("m1", ZenohTransport(role="module", mode="client", connect=[router],
                                             config_file=config_with_id(tmp_path, GREATER)))  # fmt: skip
        closing.append(zenoh_m1)
        zenoh_m1.register(Attribute("where", "zenoh", codec="str"))
        bridge, tool = _bridged_can_module(closing, can_options, network, router)
        assert wait_until(lambda: "m1" in bridge.bridged, timeout=10)  # mirrored on the blind look
        answers: list[object] = []
        deadline = time.monotonic() + CLAIM_WAIT + 10
        while "m1" in bridge.bridged and time.monotonic() < deadline:  # the mirror answers nothing meanwhile
            answers.append(_made(lambda: tool.lookup("m1", "where", timeout=2).get()))
        assert "m1" not in bridge.bridged
        assert answers and set(map(str, answers)) == {"zenoh"}, set(map(repr, answers))
        assert tool.lookup("m1", "where", timeout=5).get() == "zenoh"
        time.sleep(1)  # and it stays withdrawn while the Zenoh module lives
        assert "m1" not in bridge.bridged
    finally:
        for made in reversed(closing):
            made.close()


def test_what_arrives_while_a_claim_is_unsettled_is_held_then_handled_or_dropped() -> None:
    handled: list[int] = []
    dropped: list[int] = []
    kept = Holding(limit=3)
    for k in range(4):  # the fourth is beyond the limit: dropped at once
        assert kept.hold(lambda k=k: handled.append(k), lambda k=k: dropped.append(k))
    assert handled == [] and dropped == [3] and not kept.kept
    kept.keep()
    assert handled == [0, 1, 2] and kept.kept
    assert not kept.hold(lambda: handled.append(9), None)  # after: the caller handles it at once
    given_up = Holding()
    assert given_up.hold(lambda: handled.append(5), lambda: dropped.append(5))
    assert given_up.hold(lambda: handled.append(6), None)  # a message: simply forgotten
    assert given_up.give_up() and not given_up.give_up()  # (given up once)
    given_up.keep()  # (settled: no change)
    assert given_up.hold(lambda: handled.append(7), lambda: dropped.append(7))  # after: dropped at once
    assert handled == [0, 1, 2] and dropped == [3, 5, 7] and not given_up.kept


def test_a_bridge_mirror_gives_way_to_a_lesser_session_that_kept_the_name_too(
    router: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The bridge (greater ID) kept m1 for its CAN module; a Zenoh module m1 (lesser ID) whose looks all missed the
    mirror's token kept it too: once the bridge sees its token, it withdraws the mirror, and only the Zenoh module
    answers for m1."""
    from server.bridge import CanZenohBridge
    from server.zenoh_args import ZenohOptions

    from ..transports import FAST_BEATS, fresh_name

    can_options = {"interface": "virtual", "channel": fresh_name("asm-claims"), **FAST_BEATS}
    network = ZenohOptions(mode="client", connect=(router,), config_file=config_with_id(tmp_path, GREATER))
    closing: list[Node | CanZenohBridge] = []
    try:
        bridge, tool = _bridged_can_module(closing, can_options, network, router)
        assert wait_until(lambda: tool.lookup("m1", "where", timeout=2).get() == "can", timeout=15)  # kept
        monkeypatch.setattr(ZenohTransport, "_rivals", lambda self: {self.zid})  # the Zenoh module's looks: blind
        monkeypatch.setattr(ZenohTransport, "claimants", lambda self, seg: {self.zid})
        zenoh_m1 = Node("m1", ZenohTransport(role="module", mode="client", connect=[router],
                                             config_file=config_with_id(tmp_path, LESSER)))  # fmt: skip
        closing.append(zenoh_m1)
        zenoh_m1.register(Attribute("where", "zenoh", codec="str"))
        assert wait_until(lambda: "m1" not in bridge.bridged, timeout=10)
        assert zenoh_m1.transport.name_lost == ""  # type: ignore[attr-defined]
        answers = [_made(lambda: tool.lookup("m1", "where", timeout=2).get()) for _ in range(30)]
        assert set(map(str, answers)) == {"zenoh"}, set(map(repr, answers))
    finally:
        for made in reversed(closing):
            made.close()


def _bridged_can_module(closing: list, can_options: dict, network: object, router: str) -> tuple:
    """A CAN module m1 (its ``where`` says "can"), a bridge for its bus, and a tool on the router; each added to
    ``closing`` as it is made."""
    from asm_py.transport.can import CanTransport
    from server.bridge import CanZenohBridge

    can_m1 = Node("m1", CanTransport(1, **can_options))
    closing.append(can_m1)
    can_m1.register(Attribute("where", "can", codec="str"))
    bridge = CanZenohBridge(can_options, network=network)  # type: ignore[arg-type]
    closing.append(bridge)
    tool = Node("tester", ZenohTransport(mode="client", connect=[router]))
    closing.append(tool)
    return bridge, tool


def test_the_session_that_keeps_a_name_warns_and_only_the_one_that_gives_way_logs_an_error(
    router: str, session_with_id: Callable[[str], zenoh.Session], caplog: pytest.LogCaptureFixture
) -> None:
    """Two holders of one name whose tokens met late: the race is resolved correctly, so the holder that keeps the
    name warns (it was told of a rival); only the one that gives way — it no longer answers — says so as an error.
    (Before, the keeper logged an ERROR too, for a state it had just resolved.)"""
    from types import SimpleNamespace

    from asm_module.feed import RobotStatus
    from server.robot_feed import RobotFeed

    caplog.set_level(logging.WARNING)
    node = Node("m7", ZenohTransport(robot="a", role="module", mode="client", connect=[router]))
    try:
        node.transport._rival_kept("f" * 32)  # type: ignore[attr-defined]  # a greater rival: this node keeps m7
        assert node.transport.name_lost == ""  # type: ignore[attr-defined]
    finally:
        node.close()
    feed = RobotFeed(session_with_id(LESSER), RobotStatus("z", "real", 0))
    try:
        feed._on_alive(SimpleNamespace(key_expr=RobotKeys("z").robot_alive(GREATER), kind=zenoh.SampleKind.PUT))  # type: ignore[arg-type]
        assert feed.lost is None
    finally:
        feed.close()
    kept = [r for r in caplog.records if "the lesser ID keeps the name" in r.getMessage()]
    assert len(kept) == 2 and {r.levelno for r in kept} == {logging.WARNING}, [
        (r.levelname, r.getMessage()) for r in kept
    ]
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
