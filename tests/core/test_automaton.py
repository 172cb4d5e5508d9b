"""Phase automata: initialization from the phase delay, direction, and the shifted-reference property."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from asm_py import Attribute, Event, PeriodicAutomaton, PhaseAutomaton, PhaseState, SimClock, TimerTrigger, Trigger


def make_generic(clock: SimClock, states: list[str], **kwargs) -> tuple[PhaseAutomaton, Trigger, list]:
    event = Event("step", clock=clock)
    trigger = Trigger()
    event.add_trigger(trigger)
    actions: list[tuple[str, object]] = []
    automaton = PhaseAutomaton(
        "walker", event, states, action=lambda a, s, v: actions.append((a.states[s], v)), clock=clock, **kwargs
    )
    return automaton, trigger, actions


def test_initialization_sets_state_and_first_action_from_the_phase(services) -> None:
    clock = SimClock()
    automaton, trigger, actions = make_generic(clock, ["lift", "swing", "place", "push"])
    services.append(automaton)
    automaton.start(0.6)
    assert automaton.started and automaton.phase == 0.6
    assert automaton.state.peek() == 2 and actions == [("place", None)]
    for value in range(5):
        trigger.fire(value)
    clock.settle()
    assert [a[0] for a in actions] == ["place", "push", "lift", "swing", "place", "push"]
    assert [a[1] for a in actions[1:]] == [0, 1, 2, 3, 4]


def test_backward_visits_the_states_in_reverse(services) -> None:
    clock = SimClock()
    automaton, trigger, actions = make_generic(clock, ["a", "b", "c"])
    services.append(automaton)
    automaton.start(0.0, -1)
    assert automaton.direction.peek() == -1
    for _ in range(4):
        trigger.fire()
    clock.settle()
    assert [a[0] for a in actions] == ["a", "c", "b", "a", "c"]
    automaton.direction.set(1)  # direction is an attribute: flip it live
    trigger.fire()
    clock.settle()
    assert actions[-1][0] == "a"


def test_custom_next_state_and_initialize(services) -> None:
    clock = SimClock()
    event = Event("contact", clock=clock)
    visited: list[int] = []

    def next_state(automaton: PhaseAutomaton, state: int, touched: bool) -> int:
        return 0 if touched else min(state + 1, len(automaton.states) - 1)  # sensor-driven, not periodic

    def initialize(automaton: PhaseAutomaton, phase: float) -> None:
        automaton.state.set(1)

    automaton = PhaseAutomaton(
        "reflex", event, ["rest", "reach", "grasp"], next_state=next_state, initialize=initialize,
        action=lambda a, s, v: visited.append(s), clock=clock,
    )  # fmt: skip
    services.append(automaton)
    automaton.start(0.5)
    for touched in (False, False, True, False):
        event.set(touched)
    clock.settle()
    assert automaton.state.peek() == 1
    assert visited == [2, 2, 0, 1]


@pytest.mark.parametrize("phase", [-0.1, 1.0, float("nan")])
def test_phase_must_be_in_unit_interval(phase: float) -> None:
    automaton, _, _ = make_generic(SimClock(), ["a"])
    with pytest.raises(ValueError):
        automaton.start(phase)
    assert not automaton.started


def test_direction_must_be_plus_or_minus_one() -> None:
    with pytest.raises(ValueError):
        make_generic(SimClock(), ["a"], direction=0)
    automaton, _, _ = make_generic(SimClock(), ["a"])
    with pytest.raises(ValueError):
        automaton.start(0.0, 2)


def test_states_are_needed() -> None:
    with pytest.raises(ValueError):
        PhaseAutomaton("empty", Event("e"), [])


STATES = [PhaseState(10.0, 0.25), PhaseState(-20.0, 0.25), PhaseState(30.0, 0.5)]


def run_periodic(phase: float, direction: int, states: list[PhaseState], tick: float, seconds: float, services):
    clock = SimClock(start=3.0)
    event = Event("tick", clock=clock)
    timer = TimerTrigger(tick, clock=clock)
    event.add_trigger(timer)
    automaton = PeriodicAutomaton("gait", event, states, direction=direction, clock=clock)
    samples: list[tuple[float, object]] = []
    automaton.output.on_change(lambda v: samples.append((clock.now(), v)))
    services.extend([automaton, timer])
    automaton.start(phase)
    timer.start()
    clock.advance(seconds)
    timer.stop()
    automaton.stop()
    return automaton, samples


def assert_matches_reference(automaton: PeriodicAutomaton, samples, phase: float, direction: int, tick: float):
    period = automaton.period
    t0 = samples[0][0]
    for t, value in samples:
        tau = phase * period + direction * (t - t0)
        candidates = [automaton.reference(tau + k * tick) for k in (-1, 0, 1)]
        assert any(value == pytest.approx(c, abs=1e-9) for c in candidates), (t, value, candidates)


@pytest.mark.parametrize("direction", [1, -1])
@pytest.mark.parametrize("phase", [0.0, 0.3, 0.75])
def test_output_is_the_reference_shifted_by_phase(services, phase: float, direction: int) -> None:
    tick = 0.01
    automaton, samples = run_periodic(phase, direction, STATES, tick, 3.0, services)
    assert automaton.period == 1.0
    assert len(samples) == 301  # the initial action, then one per tick
    assert_matches_reference(automaton, samples, phase, direction, tick)
    exact = sum(v == automaton.reference(phase + direction * (t - 3.0)) for t, v in samples)
    assert exact >= len(samples) - 12, "off by a tick only next to state boundaries"


def test_reference_itself() -> None:
    automaton = PeriodicAutomaton("r", Event("e"), STATES)
    assert [automaton.reference(t) for t in (0.0, 0.2, 0.25, 0.49, 0.5, 0.99, 1.0, -0.01)] == [
        10.0, 10.0, -20.0, -20.0, 30.0, 30.0, 10.0, 30.0,
    ]  # fmt: skip
    assert automaton.state_at(0.6) == 2


@settings(max_examples=15, deadline=None)
@given(
    phase=st.floats(0, 1, exclude_max=True),
    direction=st.sampled_from([1, -1]),
    durations=st.lists(st.floats(0.05, 0.5), min_size=2, max_size=6),
)
def test_shift_property_for_random_automata(phase: float, direction: int, durations: list[float]) -> None:
    states = [PhaseState(float(i * 10), d) for i, d in enumerate(durations)]
    started: list = []
    try:
        automaton, samples = run_periodic(phase, direction, states, 0.02, 2.0, started)
    finally:
        for service in started:
            service.stop()
    assert_matches_reference(automaton, samples, phase, direction, 0.02)


def test_linear_interpolation_and_array_targets(services) -> None:
    states = [PhaseState((0.0, 1.0), 0.5, "linear"), PhaseState((10.0, -1.0), 0.5, "linear")]
    automaton, samples = run_periodic(0.0, 1, states, 0.05, 1.0, services)
    assert automaton.reference(0.25) == (5.0, 0.0)
    assert automaton.reference(0.75) == (5.0, 0.0)
    assert samples[0][1] == (10.0, -1.0)  # τ = 0 is the start of state 0: the previous state's target
    assert_matches_reference(automaton, samples, 0.0, 1, 0.05)
    assert automaton.output.codec is not None and automaton.output.codec.spec == "float64[2]"


def test_suspension_freezes_the_phase(services) -> None:
    clock = SimClock()
    event = Event("tick", clock=clock)
    timer = TimerTrigger(0.01, clock=clock)
    event.add_trigger(timer)
    output = Attribute("joint.goal", 0.0, codec="float32", clock=clock)
    automaton = PeriodicAutomaton("gait", event, STATES, output=output, clock=clock)
    assert automaton.output is output
    services.extend([automaton, timer])
    automaton.start(0.0)
    timer.start()
    clock.advance(0.4)
    automaton.suspend()
    tau = automaton.tau
    clock.advance(5.0)
    assert automaton.tau == tau and output.peek() == -20.0
    automaton.resume()
    clock.advance(0.2)
    assert automaton.tau == pytest.approx(0.6, abs=0.011)
    assert output.peek() == 30.0


def test_direction_change_mid_run_retraces(services) -> None:
    clock = SimClock()
    event = Event("tick", clock=clock)
    timer = TimerTrigger(0.01, clock=clock)
    event.add_trigger(timer)
    automaton = PeriodicAutomaton("gait", event, STATES, clock=clock)
    services.extend([automaton, timer])
    automaton.start(0.0)
    timer.start()
    clock.advance(0.3)
    assert automaton.tau == pytest.approx(0.3)
    automaton.direction.set(-1)
    clock.advance(0.1)
    assert automaton.tau == pytest.approx(0.2)
    assert automaton.state.peek() == 0
