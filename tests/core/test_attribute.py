"""Attributes: the paper's monitor, in its four synchronization modes."""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter

import pytest

from asm_py import AsmError, Attribute, Service, SimClock

from ..helpers import run_in_thread, wait_until


def test_plain_shared_variable_never_blocks() -> None:
    attr = Attribute("temperature.goal", 20.0)
    assert attr.name == "temperature.goal"
    assert not attr.sync_get and not attr.sync_set
    assert attr.get() == 20.0 and not attr.valid
    attr.set(21.5)
    assert attr.valid
    attr.set(22.0)  # overwrites without waiting
    assert attr.get() == 22.0 and not attr.valid
    assert attr.get() == 22.0  # still readable: a plain variable


def test_flags_are_read_only() -> None:
    attr = Attribute("a", sync_get=True)
    with pytest.raises(AttributeError):
        attr.valid = True  # type: ignore[misc]
    with pytest.raises(AttributeError):
        attr.sync_get = False  # type: ignore[misc]


def test_sync_get_waits_for_a_fresh_value() -> None:
    attr = Attribute("reading", sync_get=True)
    thread, box = run_in_thread(attr.get, 5.0)
    time.sleep(0.05)
    assert thread.is_alive(), "get returned before any set"
    attr.set(42)
    thread.join(5)
    assert box == {"result": 42}
    assert not attr.valid


def test_sync_get_consumes_each_value_once() -> None:
    attr = Attribute("reading", sync_get=True)
    attr.set(1)
    assert attr.get(timeout=1) == 1
    with pytest.raises(TimeoutError):
        attr.get(timeout=0.05)


def test_timeout_names_the_attribute_and_changes_nothing() -> None:
    attr = Attribute("joint.angle", 3, sync_get=True)
    with pytest.raises(TimeoutError, match=r"joint\.angle") as info:
        attr.get(timeout=0.05)
    assert isinstance(info.value, AsmError)
    assert not attr.valid and attr.peek() == 3

    attr2 = Attribute("command", sync_set=True)
    attr2.set("first")
    with pytest.raises(TimeoutError, match="command"):
        attr2.set("second", timeout=0.05)
    assert attr2.valid and attr2.peek() == "first"


def test_sync_set_waits_until_the_last_value_was_used() -> None:
    attr = Attribute("command", sync_set=True)
    attr.set("move")
    thread, box = run_in_thread(attr.set, "stop", 5.0)
    time.sleep(0.05)
    assert thread.is_alive(), "set did not wait for the previous value to be consumed"
    assert attr.get() == "move"
    thread.join(5)
    assert box == {"result": None}
    assert attr.get() == "stop"
    assert attr.get() == "stop"  # without sync_get, get never blocks


def test_rendezvous_alternates_strictly() -> None:
    attr = Attribute("slot", sync_get=True, sync_set=True)
    received: list[int] = []
    consumer, box = run_in_thread(lambda: [received.append(attr.get(timeout=5)) for _ in range(200)])
    for i in range(200):
        attr.set(i, timeout=5)
    consumer.join(10)
    assert "error" not in box
    assert received == list(range(200))


def test_reset_restores_initial_and_releases_blocked_setters() -> None:
    attr = Attribute("slot", 7, sync_set=True)
    attr.set(1)
    thread, box = run_in_thread(attr.set, 2, 5.0)
    time.sleep(0.05)
    assert thread.is_alive()
    attr.reset()
    thread.join(5)
    assert box == {"result": None}, "reset did not release the blocked setter"
    assert attr.peek() == 2 and attr.valid

    attr.reset()
    assert attr.peek() == 7 and not attr.valid and attr.initial == 7


def test_on_change_reports_every_set_in_the_setters_thread(caplog) -> None:
    attr = Attribute("a", codec="int16")
    seen: list[tuple[int, str]] = []
    remove = attr.on_change(lambda v: seen.append((v, threading.current_thread().name)))

    def broken(value: int) -> None:
        raise RuntimeError("observer bug")

    attr.on_change(broken)
    with caplog.at_level(logging.ERROR, logger="asm_py.attribute"):
        attr.set(1)
    assert "observer bug" in caplog.text
    attr.set(2)
    attr.reset()
    remove()
    attr.set(3)
    assert seen == [(1, "MainThread"), (2, "MainThread")]
    assert attr.peek() == 3


def test_peek_does_not_consume() -> None:
    attr = Attribute("a", sync_get=True)
    attr.set(5)
    assert attr.peek() == 5 and attr.valid
    assert attr.get(timeout=1) == 5


def test_timeouts_are_measured_on_the_attributes_clock(services) -> None:
    clock = SimClock()
    attr = Attribute("sensor", sync_get=True, clock=clock)
    outcome: list = []

    class Reader(Service):
        def run(self) -> None:
            try:
                attr.get(timeout=0.5)
                outcome.append("value")
            except TimeoutError:
                outcome.append(("timeout", clock.now()))

    reader = Reader("reader", clock=clock)
    services.append(reader)
    reader.start()
    clock.advance(0.4)
    assert outcome == []
    clock.advance(0.2)
    assert outcome == [("timeout", 0.5)]


@pytest.mark.timeout(300)
def test_four_producers_four_consumers_every_item_exactly_once() -> None:
    attr = Attribute("conveyor", sync_get=True, sync_set=True)
    items_each = 10_000
    producers, consumers = 4, 4
    received: list[list[tuple[int, int]]] = [[] for _ in range(consumers)]
    errors: list[BaseException] = []

    def produce(p: int) -> None:
        try:
            for i in range(items_each):
                attr.set((p, i), timeout=60)
        except BaseException as exc:
            errors.append(exc)

    def consume(c: int) -> None:
        try:
            for _ in range(items_each):
                received[c].append(attr.get(timeout=60))
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=produce, args=(p,)) for p in range(producers)]
    threads += [threading.Thread(target=consume, args=(c,)) for c in range(consumers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(240)
    assert not any(t.is_alive() for t in threads)
    assert not errors
    everything = Counter(item for part in received for item in part)
    assert len(everything) == producers * items_each
    assert set(everything.values()) == {1}
    for part in received:  # each producer's items arrive in the order it made them
        for p in range(producers):
            sequence = [i for q, i in part if q == p]
            assert sequence == sorted(sequence)
    assert wait_until(lambda: not attr.valid)
