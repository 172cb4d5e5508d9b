"""The shared timers of a clock (asm_py.timers): one thread for every deadline, deterministic on a SimClock."""

from __future__ import annotations

import threading
import time

from asm_py import Attribute, Node, SimClock
from asm_py.timers import Timers, timers_of
from asm_py.transport.memory import MemoryNetwork, MemoryTransport

from ..helpers import wait_until


def _timer_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "asm:timers"]


def test_deadlines_run_in_order_on_a_sim_clock_and_advance_waits_for_them() -> None:
    clock = SimClock()
    timers = Timers(clock)
    seen: list[tuple[str, float]] = []

    def every(name: str, period: float):
        def tick(due: float) -> float:
            seen.append((name, due))
            return due + period

        return tick

    timers.call_at(0.3, every("slow", 0.3))
    timers.call_at(0.1, every("fast", 0.1))
    try:
        clock.advance(0.65)  # returns only once each deadline due by then has run
        assert [d for _, d in seen] == sorted(d for _, d in seen)
        assert [n for n, _ in seen].count("fast") == 6 and [n for n, _ in seen].count("slow") == 2
        clock.advance(0.3)
        assert [n for n, _ in seen].count("fast") == 9 and seen[-1][1] <= 0.95
    finally:
        timers.close()


def test_the_thread_exists_only_while_there_are_deadlines() -> None:
    clock = SimClock()
    timers = Timers(clock)
    handle = timers.call_at(1.0, lambda due: due + 1.0)
    assert wait_until(lambda: len(_timer_threads()) >= 1, timeout=5)
    handle.cancel()
    clock.advance(0.5)
    assert wait_until(lambda: timers._worker is None, timeout=5)
    ran: list[float] = []
    timers.call_at(2.0, lambda due: ran.append(due))  # None: once
    clock.advance(2.0)
    assert ran == [2.0]
    assert wait_until(lambda: timers._worker is None and timers.pending == 0, timeout=5)


def test_a_failing_callback_ends_only_its_own_timer() -> None:
    clock = SimClock()
    timers = Timers(clock)
    good: list[float] = []

    def bad(due: float) -> float:
        raise RuntimeError("boom")

    timers.call_at(0.1, bad)
    timers.call_at(0.1, lambda due: good.append(due) or due + 0.1)  # type: ignore[func-returns-value]
    try:
        clock.advance(0.35)
        assert len(good) == 3 and good[0] == 0.1
        assert timers.pending == 1
    finally:
        timers.close()


def test_cancel_waits_for_a_callback_running_in_another_thread() -> None:
    timers = Timers(timers_of().clock)
    inside, release, finished = threading.Event(), threading.Event(), threading.Event()

    def slow(due: float) -> None:
        inside.set()
        release.wait(5)
        finished.set()

    handle = timers.call_at(time.monotonic(), slow)
    assert inside.wait(5)
    threading.Timer(0.2, release.set).start()
    handle.cancel()  # returns once the callback has returned: nothing runs after a publisher is closed
    assert finished.is_set()
    timers.close()


def test_a_hundred_rate_publishers_share_one_thread() -> None:
    """Issue 31: a publisher with a rate is a deadline, not a thread: 100 of them add one thread at most."""
    network = MemoryNetwork()
    node = Node("many", MemoryTransport(network))
    before = threading.active_count()
    try:
        attrs = [Attribute(f"a{i}", float(i), codec="float32") for i in range(100)]
        for attr in attrs:
            node.register(attr)
            attr.publish(rate=20)
        assert threading.active_count() - before <= 1
        assert wait_until(lambda: all(node.registry.by_name(a.name).publisher.published >= 2 for a in attrs),  # type: ignore[union-attr]
                          timeout=10)  # fmt: skip
    finally:
        node.close()
    assert wait_until(lambda: not _timer_threads(), timeout=5)
