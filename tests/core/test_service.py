"""Services: the start/stop/suspend/resume/reset state machine, threads, hooks and failures."""

from __future__ import annotations

import logging
import threading
import time

import pytest

from asm_py import Attribute, Event, Service, ServiceError, SimClock

from ..helpers import wait_until


class Counter(Service):
    """Counts ticks of its clock: one every 0.1 s."""

    def __init__(self, name: str = "counter", **kwargs) -> None:
        super().__init__(name, **kwargs)
        self.count = 0
        self.params: tuple = ()

    def run(self, *params) -> None:
        self.params = params
        while self.sleep(0.1):
            self.count += 1


def test_start_returns_at_once_and_sets_flags(services) -> None:
    gate = threading.Event()

    class Blocked(Service):
        def run(self) -> None:
            gate.wait(10)

    service = Blocked("blocked")
    services.append(service)
    assert not service.started and not service.running
    started_at = time.monotonic()
    service.start()
    assert time.monotonic() - started_at < 1.0
    assert service.started and service.running
    gate.set()
    assert service.join(timeout=5)
    assert not service.started and not service.running


def test_start_twice_raises_and_restart_after_stop_works(services) -> None:
    clock = SimClock()
    service = Counter(clock=clock)
    services.append(service)
    service.start("gait", 0.25)
    with pytest.raises(ServiceError, match="already started"):
        service.start()
    clock.advance(0.35)
    assert service.count == 3 and service.params == ("gait", 0.25)
    service.stop()
    assert not service.started
    service.start("again")
    clock.advance(0.1)
    assert service.params == ("again",) and service.count == 4


def test_suspend_holds_and_resume_continues(services) -> None:
    clock = SimClock()
    service = Counter(clock=clock)
    services.append(service)
    service.start()
    clock.advance(1.0)
    assert service.count == 10
    service.suspend()
    assert service.started and not service.running
    clock.advance(1.0)
    assert service.count == 10, "a suspended service kept running"
    service.continue_()  # the paper's name
    assert service.running
    clock.advance(0.05)  # the sleep that fell due while suspended completes on resume
    assert service.count == 11
    clock.advance(0.1)
    assert service.count == 12
    service.suspend()
    service.resume()
    assert service.running


def test_suspend_and_resume_need_a_started_service() -> None:
    service = Counter()
    with pytest.raises(ServiceError):
        service.suspend()
    with pytest.raises(ServiceError):
        service.resume()
    service.stop()  # stopping a stopped service does nothing


def test_reset_only_when_not_running(services) -> None:
    resets: list[str] = []

    class Resettable(Counter):
        def on_reset(self) -> None:
            resets.append("reset")
            self.count = 0

    clock = SimClock()
    service = Resettable(clock=clock)
    services.append(service)
    service.reset()
    service.start()
    clock.advance(0.3)
    with pytest.raises(ServiceError, match="running"):
        service.reset()
    service.suspend()
    service.reset()
    assert service.count == 0
    service.stop()
    service.reset()
    assert resets == ["reset"] * 3


def test_exception_in_run_stops_the_service_and_is_kept(caplog) -> None:
    class Faulty(Service):
        def run(self) -> None:
            raise RuntimeError("sensor on fire")

    service = Faulty("faulty")
    with caplog.at_level(logging.ERROR, logger="asm_py.service"):
        service.start()
        assert service.join(timeout=5)
    assert isinstance(service.last_error, RuntimeError)
    assert "faulty" in caplog.text and "sensor on fire" in caplog.text
    assert not service.started
    service.reset()
    assert service.last_error is None


def test_stop_interrupts_a_blocking_call_inside_run() -> None:
    attr = Attribute("never.set", sync_get=True)
    event = Event("never.fired")
    ended: list[str] = []

    class Waiter(Service):
        def run(self) -> None:
            try:
                attr.get()
                event.waiting()
            finally:
                ended.append("finally ran")

    service = Waiter("waiter")
    service.start()
    assert wait_until(lambda: service._blocked_on is not None)
    service.stop(timeout=5)
    assert not service.started
    assert ended == ["finally ran"]
    assert service.last_error is None, "an interrupted blocking call is a stop, not a failure"


def test_stop_with_timeout_raises_when_the_routine_ignores_it() -> None:
    release = threading.Event()

    class Stubborn(Service):
        def run(self) -> None:
            release.wait(10)  # not an ASM wait: stop cannot interrupt it

    service = Stubborn("stubborn")
    service.start()
    with pytest.raises(TimeoutError, match="stubborn"):
        service.stop(timeout=0.1)
    assert service.started
    release.set()
    assert service.join(timeout=5)


def test_stop_from_inside_run() -> None:
    class Quitter(Service):
        def run(self) -> None:
            self.stop()
            assert not self.checkpoint()

    service = Quitter("quitter")
    service.start()
    assert service.join(timeout=5)
    assert service.last_error is None


def test_hardware_service_hooks() -> None:
    calls: list[tuple] = []

    class PowerSwitch(Service):
        def on_start(self, *params) -> None:
            calls.append(("on", *params))

        def on_stop(self) -> None:
            calls.append(("off",))

        def on_suspend(self) -> None:
            calls.append(("hold",))

        def on_resume(self) -> None:
            calls.append(("release",))

        def on_reset(self) -> None:
            calls.append(("reset",))

    before = threading.active_count()
    switch = PowerSwitch("power")
    switch.start(12.0)
    assert threading.active_count() == before, "a hardware service must not start a thread"
    assert switch.started and switch.running
    switch.suspend()
    switch.reset()
    switch.resume()
    switch.stop()
    switch.stop()
    assert not switch.started
    assert calls == [("on", 12.0), ("hold",), ("reset",), ("release",), ("off",)]


def test_failing_on_start_cancels_the_start() -> None:
    class Refuses(Service):
        def on_start(self) -> None:
            raise ValueError("no power")

    service = Refuses("refuses")
    with pytest.raises(ValueError):
        service.start()
    assert not service.started


def test_on_stop_runs_once_however_the_service_ends(services) -> None:
    ends: list[str] = []

    class Finite(Service):
        def run(self, n: int) -> None:
            for _ in range(n):
                if not self.sleep(0.1):
                    return

        def on_stop(self) -> None:
            ends.append("end")

    clock = SimClock()
    service = Finite("finite", clock=clock)
    services.append(service)
    service.start(2)
    clock.advance(0.5)
    assert not service.started and ends == ["end"]
    service.start(100)
    clock.advance(0.15)
    service.stop()
    assert ends == ["end", "end"]


def test_sleep_wakes_on_stop_at_once() -> None:
    service = Counter()  # wall clock, 0.1 s sleeps; make it sleep long instead

    class Sleeper(Service):
        def run(self) -> None:
            self.sleep(3600)

    sleeper = Sleeper("sleeper")
    sleeper.start()
    begun = time.monotonic()
    sleeper.stop(timeout=5)
    assert time.monotonic() - begun < 2.0
    assert not service.started
