"""The C runtime's program (firmware/src/program.c) against the Python module's (asm_module/gait_service.py),
differentially: the same random programs — modes, sequences, one-shot modes, states ended by time, contact made
and lost, at goal, torque and signals, with timeouts that stop — on a C module and a Python module ticked by one
simulated clock, each on an identical simulated joint, give the same joint goal at every tick (within the one-tick
window a state boundary tie allows: single precision against double), and end the same way."""

from __future__ import annotations

import random
import shutil

import pytest

from asm_module import LocalNeighbours, ModuleRuntime
from asm_module.c_module import CModule
from asm_module.drivers import FakeDriver, JointReading
from asm_module.wire import encode_program
from asm_py import Event
from asm_py.clock import SimClock
from asm_py.codec import FLOAT32, INT8
from asm_py.protocol import Method
from tests.transports import fresh_name

from .programs import random_program

pytestmark = [pytest.mark.timeout(300), pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")]
TICK = 1 / 50


class ContactJoint(FakeDriver):
    """A first-order servo whose foot touches the ground below 0° (so contact is made and lost as it moves)."""

    def read(self) -> JointReading:
        reading = super().read()
        return JointReading(reading.angle, reading.torque, reading.angle < 0.0)


def _programs(count: int, seed: int) -> list:
    rng = random.Random(seed)
    programs = []
    while len(programs) < count:
        program = random_program(rng)
        if not program.neighbours() and not program.simple:  # neighbours need a second module; see test_program_sim
            programs.append(program)
    return programs


def _run(program, phase: float, direction: int, seconds: float) -> tuple[list[float], list[float], int, int]:
    """(C goals, Python goals, C gait.done, Python gait.done) at every tick of ``seconds``."""
    clock = SimClock()
    tick = Event("gait.tick", codec="float64", clock=clock)
    table = encode_program(program)
    runtime = ModuleRuntime(ContactJoint(clock=clock, tau=0.1), clock=clock, tick=tick, inline=True, module_id=5,
                            neighbours=LocalNeighbours())  # fmt: skip
    done: list[int] = []
    runtime.gait.done.on_change(done.append)
    c_module = CModule("c5", 5, driver=ContactJoint(clock=clock, tau=0.1), clock=clock, tick=tick,
                       interface="virtual", channel=fresh_name("c-program"))  # fmt: skip
    c_goals: list[float] = []
    p_goals: list[float] = []
    try:
        runtime.table.set(table)
        runtime.phase.set(phase)
        runtime.gait.direction.set(direction)
        c_module.local(Method.SET, "gait.table", table)
        c_module.local(Method.SET, "gait.phase", FLOAT32.encode(phase))
        c_module.local(Method.SET, "gait.direction", INT8.encode(direction))
        runtime.gait.start()
        c_module.local(Method.START, "gait.service")
        for k in range(1, round(seconds / TICK) + 1):
            clock.advance_to(k * TICK)
            tick.set(k * TICK)
            c_goals.append(c_module.goal)
            p_goals.append(float(runtime.goal.peek()))
        return c_goals, p_goals, c_module.done(), done[-1] if done else 0
    finally:
        c_module.close()
        runtime.close()


@pytest.mark.parametrize("seed", range(6))
def test_random_programs_run_in_c_as_in_python(seed: int) -> None:
    rng = random.Random(1000 + seed)
    for program in _programs(8, seed):
        phase, direction = round(rng.random() * 0.99, 3), rng.choice([1, -1])
        c_goals, p_goals, c_done, p_done = _run(program, phase, direction, 4.0)
        for k in range(1, len(p_goals) - 1):
            window = p_goals[k - 1 : k + 2]
            assert min(window) - 1e-3 <= c_goals[k] <= max(window) + 1e-3, (program, phase, direction, k * TICK,
                                                                            c_goals[k], window)  # fmt: skip
        assert c_done == p_done, (program, c_done, p_done)


@pytest.mark.parametrize("how", ["sequence", "switch"])
def test_after_a_long_gap_in_ticks_c_crosses_the_boundaries_as_python_does(how: str) -> None:
    """A 47.7 ms period (states of 21.3 and 26.4 ms, no tick on a boundary) and ticks that stop for 5 s (a stalled
    host): the boundaries crossed in one tick still count, and the one where the sequence's next step or a
    commanded switch is due still switches — C and Python alike cross the boundaries that only count a cycle
    together, and stop at the one where something is due."""
    from asm_module.gait_service import SWITCH
    from asm_module.program import Mode, ModeState, Program

    fast = Mode((ModeState(10.0, 0.0213), ModeState(-10.0, 0.0264)))
    other = Mode((ModeState(40.0, 0.5), ModeState(35.0, 0.5)))
    program = Program((fast, other), ((0, 60), (1, 0)) if how == "sequence" else ())
    clock = SimClock()
    tick = Event("gait.tick", codec="float64", clock=clock)
    runtime = ModuleRuntime(ContactJoint(clock=clock), clock=clock, tick=tick, inline=True, module_id=5,
                            neighbours=LocalNeighbours())  # fmt: skip
    c_module = CModule("c5", 5, driver=ContactJoint(clock=clock), clock=clock, tick=tick, interface="virtual",
                       channel=fresh_name("c-gap"))  # fmt: skip
    try:
        table = encode_program(program)
        runtime.table.set(table)
        c_module.local(Method.SET, "gait.table", table)
        runtime.gait.start()
        c_module.local(Method.START, "gait.service")
        if how == "switch":
            switch = {"mode": 1, "direction": 1, "after": 3.0}
            runtime.gait.switch.set(switch)
            c_module.local(Method.SET, "gait.switch", SWITCH.encode(switch))
        times = [k * TICK for k in range(1, 51)] + [6.0 + k * TICK for k in range(50)]  # nothing from 1 s to 6 s
        for t in times:
            clock.advance_to(t)
            tick.set(t)
            assert c_module.goal == pytest.approx(float(runtime.goal.peek()), abs=1e-3), t
        assert 35.0 <= c_module.goal <= 40.0, "both switched to the other mode during the gap"
        assert int(runtime.gait.cycle.peek()) > 60, "tens of boundaries crossed in one tick"
    finally:
        c_module.close()
        runtime.close()


def test_an_hour_without_ticks_over_the_shortest_period_costs_a_module_no_time() -> None:
    """90,000 boundaries of a 40 ms period (two states of one control tick each) in one tick: crossed together, not
    one by one — on a C module and on a Python module alike (a Python module crossed one boundary per loop: with
    durations of 1e-9 s its tick never returned and its e-stop could not be heard); the Python one counts every
    cycle."""
    import time

    from asm_module import FakeDriver, ModuleRuntime
    from asm_module.program import MIN_DURATION, Mode, ModeState, Program

    program = Program((Mode((ModeState(10.0, MIN_DURATION), ModeState(-10.0, MIN_DURATION))),
                       Mode((ModeState(5.0, 1.0),))))  # fmt: skip
    clock = SimClock()
    tick = Event("gait.tick", codec="float64", clock=clock)
    c_module = CModule("c5", 5, clock=clock, tick=tick, interface="virtual", channel=fresh_name("c-hour"))
    runtime = ModuleRuntime(FakeDriver(clock=clock), clock=clock, tick=tick, inline=True, module_id=6)
    try:
        c_module.local(Method.SET, "gait.table", encode_program(program))
        c_module.local(Method.START, "gait.service")
        runtime.table.set(encode_program(program))
        runtime.gait.start()
        clock.advance_to(TICK)
        tick.set(TICK)
        began = time.monotonic()
        clock.advance_to(3600.0)
        tick.set(3600.0)
        assert time.monotonic() - began < 5.0
        assert c_module.gait_running() and runtime.gait.running
        assert int(runtime.gait.cycle.peek()) == int(3600.0 / (2 * MIN_DURATION))
        month = 30 * 86_400.0  # 65 million boundaries more (one by one, minutes): the Python module alone (the C
        began = time.monotonic()  # module's millisecond clock wraps at 49 days)
        clock.advance_to(month)
        tick.set(month)
        assert time.monotonic() - began < 1.0
        assert int(runtime.gait.cycle.peek()) == round(month / (2 * MIN_DURATION))
    finally:
        runtime.close()
        c_module.close()
