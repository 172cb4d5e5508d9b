"""Events and triggers: waiting semantics, timers on the simulation clock, thresholds and polling."""

from __future__ import annotations

import threading
import time

import pytest

from asm_py import (
    Attribute,
    ConditionTrigger,
    Event,
    EventDrivenService,
    Service,
    SimClock,
    ThresholdTrigger,
    TimerTrigger,
    Trigger,
)

from ..helpers import run_in_thread, wait_until


def test_event_is_a_sync_get_attribute() -> None:
    event = Event("contact")
    assert event.sync_get and not event.sync_set
    assert isinstance(event, Attribute)
    with pytest.raises(TimeoutError, match="contact"):
        event.get(timeout=0.02)


def test_waiting_blocks_until_a_trigger_fires() -> None:
    event = Event("contact")
    trigger = Trigger("bumper")
    event.add_trigger(trigger)
    assert event.triggers == (trigger,) and trigger.events == (event,)
    thread, box = run_in_thread(event.waiting, 5.0)
    time.sleep(0.05)
    assert thread.is_alive()
    trigger.fire("left")
    thread.join(5)
    assert box == {"result": "left"}
    assert trigger.fired == 1
    assert event.valid, "waiting does not consume the value; get still can"
    assert event.get(timeout=1) == "left"


def test_waiting_only_sees_firings_after_it_began() -> None:
    event = Event("e")
    event.set(1)
    with pytest.raises(TimeoutError):
        event.waiting(timeout=0.02)


def test_every_waiter_blocked_at_a_firing_wakes_once() -> None:
    event = Event("go")
    trigger = Trigger()
    event.add_trigger(trigger)
    wakeups: list[object] = []
    lock = threading.Lock()
    ready = threading.Barrier(6)

    def waiter() -> None:
        ready.wait()
        value = event.waiting(timeout=5)
        with lock:
            wakeups.append(value)

    threads = [threading.Thread(target=waiter) for _ in range(5)]
    for t in threads:
        t.start()
    ready.wait()
    assert wait_until(lambda: event._mon._waiters == 5)
    trigger.fire("now")
    for t in threads:
        t.join(5)
    assert wakeups == ["now"] * 5


def test_one_trigger_feeds_several_events_and_events_have_several_triggers() -> None:
    left, right = Event("left"), Event("right")
    both = Trigger("both")
    only_left = Trigger("only-left")
    left.add_trigger(both)
    right.add_trigger(both)
    left.add_trigger(only_left)
    both.fire(1)
    assert left.get(timeout=1) == 1 and right.get(timeout=1) == 1
    only_left.fire(2)
    assert left.get(timeout=1) == 2 and not right.valid
    left.remove_trigger(both)
    both.fire(3)
    assert not left.valid and right.get(timeout=1) == 3


def test_timer_fires_exactly_at_the_simulated_times(services) -> None:
    clock = SimClock(start=5.0)
    event = Event("tick", clock=clock)
    timer = TimerTrigger(0.25, clock=clock)
    event.add_trigger(timer)
    seen: list[tuple[float, float]] = []
    event.on_change(lambda due: seen.append((due, clock.now())))
    services.append(timer)
    timer.start()
    clock.advance(1.0)
    assert seen == [(5.25, 5.25), (5.5, 5.5), (5.75, 5.75), (6.0, 6.0)]
    clock.advance(0.1)
    assert len(seen) == 4
    timer.stop()
    clock.advance(1.0)
    assert len(seen) == 4 and timer.fired == 4


def test_one_shot_timer_fires_once(services) -> None:
    clock = SimClock()
    timer = TimerTrigger(0.3, one_shot=True, clock=clock)
    event = Event("alarm", clock=clock)
    event.add_trigger(timer)
    services.append(timer)
    timer.start()
    clock.advance(0.29)
    assert timer.fired == 0
    clock.advance(0.02)
    assert timer.fired == 1 and event.peek() == pytest.approx(0.3)
    clock.advance(5)
    assert timer.fired == 1 and not timer.started


def test_suspended_timer_holds_then_fires_the_overdue_tick_once(services) -> None:
    clock = SimClock()
    timer = TimerTrigger(0.1, clock=clock)
    times: list[float] = []
    event = Event("tick", clock=clock)
    event.add_trigger(timer)
    event.on_change(lambda due: times.append(round(due, 9)))
    services.append(timer)
    timer.start()
    clock.advance(0.2)
    timer.suspend()
    clock.advance(0.55)
    assert times == [0.1, 0.2]
    timer.resume()
    clock.advance(0.0)
    assert times == [0.1, 0.2, 0.3]
    clock.advance(0.1)
    assert times == [0.1, 0.2, 0.3, 0.8], "missed ticks are skipped; the grid start + k·period is kept"


def test_timer_period_must_be_positive() -> None:
    for period in (0, -1, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            TimerTrigger(period)


def test_wall_clock_timer_fires_repeatedly() -> None:
    timer = TimerTrigger(0.01)
    event = Event("tick")
    event.add_trigger(timer)
    timer.start()
    try:
        first = event.waiting(timeout=5)
        second = event.waiting(timeout=5)
        assert second > first
    finally:
        timer.stop(timeout=5)


def test_threshold_trigger_fires_on_crossings_with_hysteresis() -> None:
    temperature = Attribute("temperature", 20.0, codec="float32")
    before = threading.active_count()
    hot = ThresholdTrigger(temperature, above=30.0, hysteresis=2.0)
    cold = ThresholdTrigger(temperature, below=10.0)
    assert threading.active_count() == before, "a threshold trigger must not poll"
    alarms, chills = Event("alarm"), Event("chill")
    alarms.add_trigger(hot)
    chills.add_trigger(cold)
    fired: list[float] = []
    alarms.on_change(fired.append)
    for value in (25, 31, 35, 29, 31, 27.5, 32, 5, 9, 11, 9):
        temperature.set(value)
    assert fired == [31.0, 32.0]
    assert cold.fired == 2
    hot.close()
    temperature.set(20)
    temperature.set(40)
    assert hot.fired == 2


def test_threshold_already_crossed_at_creation_waits_for_rearm() -> None:
    level = Attribute("level", 50)
    trigger = ThresholdTrigger(level, above=40)
    level.set(60)
    assert trigger.fired == 0
    level.set(30)
    level.set(45)
    assert trigger.fired == 1


def test_threshold_needs_a_bound() -> None:
    with pytest.raises(ValueError):
        ThresholdTrigger(Attribute("x"))
    with pytest.raises(ValueError):
        ThresholdTrigger(Attribute("x"), above=1, hysteresis=-1)


def test_condition_trigger_polls_and_fires_on_rising_edges(services) -> None:
    clock = SimClock()
    switch = {"closed": False}
    trigger = ConditionTrigger(lambda: switch["closed"], 0.05, clock=clock)
    event = Event("switch", clock=clock)
    event.add_trigger(trigger)
    fire_times: list[float] = []
    event.on_change(lambda _: fire_times.append(round(clock.now(), 9)))
    services.append(trigger)
    trigger.start()
    clock.advance(0.12)
    switch["closed"] = True
    clock.advance(0.2)
    assert fire_times == [0.15], "fires at the first poll that sees the condition, once while it stays true"
    switch["closed"] = False
    clock.advance(0.05)
    switch["closed"] = True
    clock.advance(0.05)
    assert fire_times == [0.15, 0.4]


def test_condition_trigger_failure_stops_it() -> None:
    def broken() -> bool:
        raise OSError("sensor unplugged")

    trigger = ConditionTrigger(broken, 0.01)
    trigger.start()
    assert trigger.join(timeout=5)
    assert isinstance(trigger.last_error, OSError)


def test_timer_drives_an_event_driven_service_across_threads(services) -> None:
    clock = SimClock()
    event = Event("tick", clock=clock)
    timer = TimerTrigger(0.1, clock=clock)
    event.add_trigger(timer)
    handled: list[tuple[float, str]] = []
    service = EventDrivenService(
        "logger", event, handler=lambda due: handled.append((round(due, 9), threading.current_thread().name))
    )
    services.extend([service, timer])
    service.start()
    timer.start()
    clock.advance(0.3)
    assert handled == [(0.1, "asm:logger"), (0.2, "asm:logger"), (0.3, "asm:logger")]
    assert isinstance(timer, Service) and isinstance(service, Service)
