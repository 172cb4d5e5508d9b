"""Event-driven services: once per firing while running, bounded queue, and the suspension policies."""

from __future__ import annotations

import threading

import pytest

from asm_py import Event, EventDrivenService, SimClock, Trigger

from ..helpers import wait_until


class Recorder(EventDrivenService):
    def __init__(self, event: Event, **kwargs) -> None:
        super().__init__("recorder", event, **kwargs)
        self.values: list[object] = []

    def handle(self, value: object) -> None:
        self.values.append(value)


@pytest.mark.parametrize("inline", [False, True])
def test_handle_runs_once_per_firing_in_order(services, inline: bool) -> None:
    clock = SimClock()
    event = Event("e", clock=clock)
    service = Recorder(event, max_pending=128, inline=inline)
    services.append(service)
    event.set("before start")
    service.start()
    for i in range(100):
        event.set(i)
    clock.settle()
    assert service.values == list(range(100))
    assert service.handled == 100


def test_firings_during_a_slow_handler_are_queued_not_lost() -> None:
    event = Event("burst")
    gate = threading.Event()
    values: list[int] = []

    def slow(value: int) -> None:
        gate.wait(5)
        values.append(value)

    service = EventDrivenService("slow", event, handler=slow)
    service.start()
    try:
        for i in range(20):
            event.set(i)
        gate.set()
        assert wait_until(lambda: len(values) == 20)
        assert values == list(range(20))
        assert service.overruns == 0
    finally:
        service.stop(timeout=5)


def test_queue_is_bounded_and_overruns_are_counted() -> None:
    event = Event("flood")
    gate = threading.Event()
    values: list[int] = []
    service = EventDrivenService("bounded", event, handler=lambda v: (gate.wait(5), values.append(v)), max_pending=8)
    service.start()
    try:
        event.set(-1)
        assert wait_until(lambda: len(service._pending) == 0)  # -1 is being handled, blocked on the gate
        for i in range(100):
            event.set(i)
        assert len(service._pending) == 8
        assert service.overruns == 92
        gate.set()
        assert wait_until(lambda: len(values) == 9)
        assert values == [-1, *range(92, 100)]
    finally:
        service.stop(timeout=5)


@pytest.mark.parametrize("inline", [False, True])
@pytest.mark.parametrize(
    ("policy", "expected", "dropped"),
    [("drop", [1, 5], 3), ("coalesce", [1, 4, 5], 2), ("queue", [1, 2, 3, 4, 5], 0)],
)
def test_firings_while_suspended(services, policy: str, expected: list[int], dropped: int, inline: bool) -> None:
    clock = SimClock()
    event = Event("e", clock=clock)
    service = Recorder(event, while_suspended=policy, inline=inline)
    services.append(service)
    service.start()
    event.set(1)
    clock.settle()
    service.suspend()
    for value in (2, 3, 4):
        event.set(value)
    clock.settle()
    assert service.values == [1]
    service.resume()
    event.set(5)
    clock.settle()
    assert service.values == expected
    assert service.dropped == dropped


def test_coalesce_keeps_firings_queued_before_the_suspension() -> None:
    event = Event("e")
    gate = threading.Event()
    values: list[int] = []
    service = EventDrivenService(
        "c", event, handler=lambda v: (gate.wait(5), values.append(v)), while_suspended="coalesce"
    )
    service.start()
    try:
        event.set(0)
        assert wait_until(lambda: not service._pending)
        event.set(1)  # queued while running: must be handled
        service.suspend()
        event.set(2)
        event.set(3)
        service.resume()
        gate.set()
        assert wait_until(lambda: len(values) == 3)
        assert values == [0, 1, 3]
    finally:
        service.stop(timeout=5)


@pytest.mark.parametrize("inline", [False, True])
def test_firings_after_stop_are_not_handled(services, inline: bool) -> None:
    clock = SimClock()
    event = Event("e", clock=clock)
    trigger = Trigger()
    event.add_trigger(trigger)
    service = Recorder(event, inline=inline)
    services.append(service)
    service.start()
    trigger.fire(1)
    clock.settle()
    service.stop()
    trigger.fire(2)
    clock.settle()
    assert service.values == [1]


@pytest.mark.parametrize("inline", [False, True])
def test_a_stop_asked_from_another_thread_during_the_start_ends_it(services, inline: bool) -> None:
    """request_stop from another thread while on_start runs (a module's e-stop racing an activation): an inline
    service, whose start holds the handling lock, stayed started until a firing came to end it."""
    clock = SimClock()
    event = Event("e", clock=clock)

    class Interrupted(Recorder):
        def on_start(self, *params: object) -> None:
            stopper = threading.Thread(target=self.request_stop)
            stopper.start()
            stopper.join(5)

    service = Interrupted(event, inline=inline)
    services.append(service)
    service.start()
    assert wait_until(lambda: not service.started, timeout=5)
    event.set(1)
    clock.settle()
    assert service.values == [] and not service.started


@pytest.mark.parametrize("inline", [False, True])
def test_a_start_whose_on_start_fails_leaves_no_listener_behind(services, inline: bool) -> None:
    """Found by an adversarial review: a start whose on_start raised was undone but kept listening to its event, and
    after the next start every firing was handled twice."""
    clock = SimClock()
    event = Event("e", clock=clock)
    failures = [RuntimeError("on_start failed")]

    class FailsOnce(Recorder):
        def on_start(self, *params: object) -> None:
            if failures:
                raise failures.pop()

    service = FailsOnce(event, inline=inline)
    services.append(service)
    with pytest.raises(RuntimeError):
        service.start()
    assert not service.started
    service.start()
    event.set(1)
    clock.settle()
    assert wait_until(lambda: service.values == [1], timeout=5)
    service.stop(timeout=5)
    event.set(2)
    clock.settle()
    assert service.values == [1]


@pytest.mark.parametrize("inline", [False, True])
def test_a_failing_handler_stops_the_service(inline: bool) -> None:
    event = Event("e")

    def explode(value: object) -> None:
        raise KeyError(value)

    service = EventDrivenService("fragile", event, handler=explode, inline=inline)
    service.start()
    event.set("x")
    assert service.join(timeout=5)
    assert isinstance(service.last_error, KeyError)


def test_a_service_without_handler_fails_loudly() -> None:
    service = EventDrivenService("empty", Event("e"))
    service.start()
    service.event.set(1)
    assert service.join(timeout=5)
    assert isinstance(service.last_error, NotImplementedError)


def test_bad_options_are_refused() -> None:
    with pytest.raises(ValueError):
        EventDrivenService("x", Event("e"), while_suspended="later")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        EventDrivenService("x", Event("e"), max_pending=0)


def test_inline_handles_in_the_firing_thread_one_at_a_time() -> None:
    event = Event("e")
    threads: set[int] = set()
    active = [0]
    overlaps = [0]
    seen: list[int] = []

    def handle(value: int) -> None:
        active[0] += 1
        overlaps[0] += active[0] > 1
        threads.add(threading.get_ident())
        seen.append(value)
        active[0] -= 1

    service = EventDrivenService("inline", event, handler=handle, inline=True)
    service.start()
    try:
        event.set(-1)
        assert threads == {threading.get_ident()} and seen == [-1]  # handled before set() returned
        workers = [threading.Thread(target=lambda k=k: [event.set(k * 1000 + i) for i in range(500)]) for k in range(4)]
        for worker in workers:
            worker.start()
        for worker in workers:
            worker.join()
        assert len(seen) == 2001 and overlaps[0] == 0
        for k in range(4):  # each firing thread's values stay in its order
            mine = [v for v in seen if v // 1000 == k and v >= 0]
            assert mine == sorted(mine)
    finally:
        service.stop(timeout=5)
