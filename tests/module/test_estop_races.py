"""An e-stop racing a module's gait start, its release and its own value (found by the third adversarial review of
stop 52's fixes; each failed before its fix). On a SimClock: the races are forced with hooks, not timing."""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest

from asm_module import FakeDriver, ModuleRuntime
from asm_module.wire import encode_table
from asm_py import Event
from asm_py.automaton import PhaseState
from asm_py.clock import SimClock
from asm_py.errors import EstopLatched

pytestmark = pytest.mark.timeout(60)
TABLE = encode_table([PhaseState(40.0, 0.5, "step"), PhaseState(-40.0, 0.5, "step")])
SWAYS = {40.0, -40.0}


class _HoldFails(FakeDriver):
    """A servo that does not answer a hold, once for each failure queued."""

    def __init__(self, clock: SimClock) -> None:
        super().__init__(clock=clock)
        self.failures: list[Exception] = []

    def hold(self) -> float:
        if self.failures:
            raise self.failures.pop()
        return super().hold()


def _runtime(
    inline: bool, driver: FakeDriver | None = None, clock: SimClock | None = None
) -> tuple[SimClock, Event, ModuleRuntime]:
    clock = clock if clock is not None else SimClock()
    tick = Event("gait.tick", codec="float64", clock=clock)
    driver = driver if driver is not None else FakeDriver(clock=clock)
    return clock, tick, ModuleRuntime(driver, clock=clock, tick=tick, inline=inline, ramp=0.0)


def _goals(runtime: ModuleRuntime, clock: SimClock, tick: Event, ticks: int = 12) -> set[float]:
    """The joint goals the next ``ticks`` ticks leave."""
    seen = set()
    for _ in range(ticks):
        tick.set(clock.now())
        clock.advance(0.1)
        clock.settle()
        seen.add(runtime.goal.peek())
    return seen


def _on_a_thread(call: Any, *args: Any) -> threading.Thread:
    thread = threading.Thread(target=lambda: _quietly(call, *args))
    thread.start()
    return thread


def _quietly(call: Any, *args: Any) -> None:
    try:
        call(*args)
    except Exception:  # a start refused as "already started": what the test looks at is the goal
        pass


@pytest.mark.parametrize("inline", [False, True], ids=["threaded", "inline"])
def test_a_start_refused_during_another_start_does_not_make_that_one_move_the_joint(inline: bool) -> None:
    """Start A begins; an e-stop and its release land; start B comes and is refused or waits. B had written the
    latch count A's gait is judged by, so A, begun before the e-stop, commanded its first state after the release."""
    clock, tick, runtime = _runtime(inline)
    gait = runtime.gait
    initialize = gait.initialize
    seen: dict[str, Any] = {}

    def racing_initialize(phase: float) -> None:
        if not seen:
            _on_a_thread(runtime.emergency_stop, "operator").join(5)
            seen["held"] = runtime.goal.peek()
            _on_a_thread(runtime.estop.set, False).join(5)
            seen["b"] = _on_a_thread(gait.start)
            seen["b"].join(0.3)
        initialize(phase)

    gait.initialize = racing_initialize  # type: ignore[method-assign]
    try:
        runtime.table.set(TABLE)
        with pytest.raises(EstopLatched):
            gait.start()
        assert runtime.goal.peek() == seen["held"], "start A, begun before the e-stop, moved the joint after it"
        seen["b"].join(5)
    finally:
        runtime.close()


def test_a_tick_in_flight_when_an_estop_and_its_release_land_commands_nothing_and_a_start_after_starts() -> None:
    """A running gait's tick was being handled when the e-stop and its release landed, and a start came: the tick's
    goal reached the joint after the release, and the start was refused as "already started" while the stopped
    gait's thread was still ending."""
    clock, tick, runtime = _runtime(False)
    gait = runtime.gait
    output = gait._output
    seen: dict[str, Any] = {}

    def racing_output(now: float) -> None:
        if "armed" in seen and "held" not in seen:
            _on_a_thread(runtime.emergency_stop, "operator").join(5)
            seen["held"] = runtime.goal.peek()
            _on_a_thread(runtime.estop.set, False).join(5)
            seen["b"] = threading.Thread(target=gait.start)
            seen["b"].start()
            seen["b"].join(0.2)
        output(now)
        if "held" in seen and "after" not in seen:
            seen["after"] = runtime.goal.peek()

    gait._output = racing_output  # type: ignore[method-assign]
    try:
        runtime.table.set(TABLE)
        gait.start()
        _goals(runtime, clock, tick, 3)
        seen["armed"] = True
        tick.set(clock.now())
        clock.advance(0.1)
        clock.settle()
        ends = time.monotonic() + 5
        while "after" not in seen and time.monotonic() < ends:
            time.sleep(0.01)
        seen["b"].join(5)
        assert seen["after"] == seen["held"], "the tick in flight moved the joint after the release"
        assert gait.started and _goals(runtime, clock, tick) == SWAYS, "the start after the release runs"
    finally:
        runtime.close()


@pytest.mark.parametrize("inline", [False, True], ids=["threaded", "inline"])
def test_an_estop_whose_hold_fails_still_stops_the_gait(inline: bool) -> None:
    """A hold that raised (a servo that did not answer) skipped the gait's stop: after the release the gait said it
    ran, never moved, and refused a start as "already started"."""
    clock = SimClock()
    driver = _HoldFails(clock)
    clock, tick, runtime = _runtime(inline, driver, clock)
    try:
        runtime.table.set(TABLE)
        runtime.gait.start()
        assert _goals(runtime, clock, tick) == SWAYS
        driver.failures.append(OSError("no answer from the servo"))
        _on_a_thread(runtime.emergency_stop, "bus").join(5)
        assert runtime.latched
        ends = time.monotonic() + 5
        while runtime.gait.started and time.monotonic() < ends:
            time.sleep(0.01)
        assert not runtime.gait.started
        runtime.estop.set(False)
        runtime.gait.start()
        assert _goals(runtime, clock, tick) == SWAYS
    finally:
        runtime.close()


def test_a_release_that_stores_its_value_last_leaves_the_latch_and_the_value_agreeing() -> None:
    """emergency_stop latched, a release checked (unlatched) but had not stored false yet, emergency_stop stored
    true and latched again, then the release stored false: latched, with estop reading false."""
    _, _, runtime = _runtime(True)
    unlatch = runtime._unlatch
    unlatched, go = threading.Event(), threading.Event()

    def slow_unlatch() -> None:
        unlatch()
        unlatched.set()
        go.wait(5)

    latch = runtime._latch
    releases: list[threading.Thread] = []

    def latch_then_release() -> None:
        latch()
        if not releases:
            releases.append(_on_a_thread(runtime.estop.set, False))
            unlatched.wait(5)

    runtime._unlatch = slow_unlatch  # type: ignore[method-assign]
    runtime._latch = latch_then_release  # type: ignore[method-assign]
    try:
        timer = threading.Timer(0.5, go.set)  # the release's store, held until emergency_stop is done or stuck
        timer.start()
        runtime.emergency_stop("bus")
        go.set()
        releases[0].join(5)
        assert runtime.latched == runtime.estop.peek()
    finally:
        go.set()
        runtime.close()


def test_a_latch_whose_hold_fails_does_not_refuse_every_later_start() -> None:
    """Found by the second review: a hold that raised left the count of a latch in flight for good, and no start was
    ever taken again, e-stop released or not."""
    clock = SimClock()
    driver = _HoldFails(clock)
    driver.failures.append(OSError("no answer from the servo"))
    runtime = ModuleRuntime(driver, clock=clock)
    try:
        runtime.table.set(encode_table([PhaseState(40.0, 0.5, "step")]))
        with pytest.raises(OSError):
            runtime.estop.set(True)
        assert runtime.latched
        runtime.estop.set(False)
        runtime.gait.start()
        assert runtime.gait.started
    finally:
        runtime.close()
