"""A Zenoh subscription's delivery: a listener that hangs must not stop its whole session, and a burst arrives whole
and in order. (zenoh-python's default callback hands each sample to a Python thread through a 256-sample channel;
when that thread is stuck, the session's receive task blocks on the full channel, and with it every reply and
every e-stop on the link.)"""

from __future__ import annotations

import gc
import threading
import time
from collections.abc import Iterator

import pytest

from asm_py import Attribute
from asm_py.errors import RemoteError
from asm_py.node import Node
from asm_py.protocol import Status
from asm_py.transport.zenoh import ZenohTransport
from asm_py.transport.zenoh_drain import BACKLOG
from asm_py.transport.zenoh_requests import REQUEST_BACKLOG

from ..helpers import wait_until
from ..transports import free_port


class Hang:
    """A user's listener that never returns until the test lets it: ``entered`` once it is called."""

    def __init__(self) -> None:
        self.entered = threading.Event()
        self.released = threading.Event()

    def __call__(self, _: object) -> None:
        self.entered.set()
        self.released.wait(60)


@pytest.fixture
def hang() -> Iterator[Hang]:
    """A hung listener, released after the test (before its nodes close) whatever the outcome."""
    listener = Hang()
    try:
        yield listener
    finally:
        listener.released.set()


@pytest.fixture
def pair() -> Iterator[tuple[Node, Node]]:
    """A module and a tool on one Zenoh link, the tool seeing the module; both closed after the test."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    module = Node("module", ZenohTransport(listen=[endpoint], role="module"))
    tool = Node("tool", ZenohTransport(connect=[endpoint]))
    try:
        assert wait_until(lambda: "module" in tool.discover(), timeout=10)
        yield module, tool
    finally:
        tool.close()
        module.close()


def test_a_hung_change_listener_does_not_stop_its_session_hearing_replies_or_the_estop(
    pair: tuple[Node, Node], hang: Hang
) -> None:
    module, tool = pair
    stops: list[str] = []
    copy = Attribute("copy", codec="float32")
    try:
        stream = Attribute("stream", 0.0, codec="float32")
        module.register(stream)
        module.register(Attribute("joint.angle", 0.75, codec="float32"))
        stream.publish()
        remote_stream = tool.lookup("module", "stream", timeout=5)
        angle = tool.lookup("module", "joint.angle", timeout=5)
        tool.on_estop(lambda source, reason: stops.append(reason))
        copy.on_change(hang)
        copy.subscribe(remote_stream)
        assert wait_until(lambda: (stream.set(1.0), hang.entered.is_set())[1], timeout=10)
        for i in range(3 * BACKLOG):  # far past any channel between Zenoh and the listener's thread
            stream.set(float(i))
        assert angle.get(timeout=5) == 0.75  # the tool's session still hears replies
        module.estop("hung")  # a reason of one CAN frame
        assert wait_until(lambda: "hung" in stops, timeout=5)  # and the e-stop
    finally:
        hang.released.set()
        copy.unsubscribe()


def test_a_burst_of_publications_arrives_whole_and_in_order(pair: tuple[Node, Node]) -> None:
    module, tool = pair
    seen: list[int] = []
    copy = Attribute("copy", codec="int32")
    try:
        counter = Attribute("counter", 0, codec="int32")
        module.register(counter)
        counter.publish()
        copy.on_change(seen.append)
        copy.subscribe(tool.lookup("module", "counter", timeout=5))
        assert wait_until(lambda: (counter.set(-1), seen)[1], timeout=10)
        for i in range(BACKLOG // 2):  # within the backlog: nothing may be dropped
            counter.set(i)
        assert wait_until(lambda: seen[-1] == BACKLOG // 2 - 1, timeout=10)
        burst = [v for v in seen if v >= 0]
        assert burst == list(range(BACKLOG // 2))
    finally:
        copy.unsubscribe()


def test_sets_without_a_reply_to_a_module_that_does_not_answer_hold_no_thread_each(pair: tuple[Node, Node]) -> None:
    """Each set without a reply is a get the module never answers; zenoh-python started a Python thread for each
    one's plain callback, alive until its query ended (200 sets: 200 threads)."""
    module, tool = pair
    release = threading.Event()
    try:
        goal = Attribute("goal", 0.0, codec="float32")
        goal.on_change(lambda _: release.wait(30))  # the module takes the first set, then answers nothing
        module.register(goal)
        remote_goal = tool.lookup("module", "goal", timeout=5)
        threads = threading.active_count()
        for i in range(200):  # within the module's channel of 256: none of them blocks the tool
            remote_goal.set(float(i), wait=False)
        assert threading.active_count() - threads < 10
    finally:
        release.set()


def test_a_subscription_whose_remover_is_dropped_goes_on_delivering_and_survives_a_failing_listener(
    pair: tuple[Node, Node],
) -> None:
    module, tool = pair
    seen: list[float] = []

    def listener(value: float) -> None:
        seen.append(value)
        if len(seen) == 1:
            raise SystemExit("a listener that exits once")

    stream = Attribute("stream", 0.0, codec="float32")
    module.register(stream)
    stream.publish()
    tool.lookup("module", "stream", timeout=5).on_change(listener)  # its remover dropped at once
    gc.collect()
    assert wait_until(lambda: (stream.set(1.0), len(seen) >= 3)[1], timeout=10)


def test_a_hung_request_handler_under_a_flood_keeps_the_estop_and_refuses_what_it_cannot_hold(
    pair: tuple[Node, Node], hang: Hang
) -> None:
    """A set whose change listener hangs holds the module's requests behind it. zenoh-python handed them to that
    thread through a channel of 256 that blocks when full: past 256 the module's whole session stopped, the e-stop
    sent to it included. Now they wait in a queue of REQUEST_BACKLOG, and one past it is refused as BUSY at once."""
    module, tool = pair
    stops: list[str] = []
    try:
        goal = Attribute("goal", 0.0, codec="float32")
        goal.on_change(hang)
        module.register(goal)
        module.register(Attribute("joint.angle", 0.75, codec="float32"))
        module.on_estop(lambda source, reason: stops.append(reason))
        remote_goal = tool.lookup("module", "goal", timeout=5)
        remote_angle = tool.lookup("module", "joint.angle", timeout=5)
        remote_goal.set(1.0, wait=False)
        assert hang.entered.wait(10)
        for i in range(REQUEST_BACKLOG + 100):  # far past zenoh-python's channel of 256, and past the backlog
            remote_goal.set(float(i), wait=False)
        tool.estop("flood")
        assert wait_until(lambda: "flood" in stops, timeout=10)  # the module's session still hears the e-stop
        began = time.monotonic()
        with pytest.raises(RemoteError, match=f"holds {REQUEST_BACKLOG} requests behind one") as refused:
            remote_angle.get(timeout=20)
        assert refused.value.status == Status.BUSY and time.monotonic() - began < 10  # at once, not at the timeout
    finally:
        hang.released.set()

    def serves() -> bool:  # BUSY while the queue still holds what waited behind the hung set
        try:
            return remote_angle.get(timeout=5) == 0.75
        except RemoteError as exc:
            assert exc.status == Status.BUSY
            return False

    assert wait_until(serves, timeout=30)  # and serves again once it is free


def test_a_hung_group_set_under_a_flood_of_group_messages_keeps_the_estop(pair: tuple[Node, Node], hang: Hang) -> None:
    """The same for a group's messages (a set to every node with an object of a class): they came through
    zenoh-python's channel of 256 too, and a group set whose listener hung stopped the session past 256 more."""
    module, tool = pair
    stops: list[str] = []
    signal = Attribute("gait.signal", 0, codec="uint8")
    signal.on_change(hang)
    module.register(signal)
    module.on_estop(lambda source, reason: stops.append(reason))
    group = tool.group().attribute("gait.signal", "uint8")
    assert wait_until(lambda: (group.set(1), hang.entered.is_set())[1], timeout=10)
    for i in range(REQUEST_BACKLOG + 100):
        group.set(2 + i % 200)
    tool.estop("groups")
    assert wait_until(lambda: "groups" in stops, timeout=10)
