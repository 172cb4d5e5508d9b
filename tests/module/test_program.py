"""Programs on the module: sensor-driven, neighbour-driven, one-shot and hierarchical phase automata (issue 16),
the version-2 gait table that carries them, and the rules that make modules agree without talking."""

from __future__ import annotations

import itertools
import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from asm_module import (
    JointDriver,
    JointReading,
    LocalNeighbours,
    Mode,
    ModeState,
    ModuleRuntime,
    Program,
    Until,
    decode_program,
    encode_program,
    encode_table,
)
from asm_module.gait_service import FINISHED, SWITCH_BLEND, TIMED_OUT
from asm_module.wire import checksum
from asm_py import Event
from asm_py.automaton import PhaseState
from asm_py.clock import SimClock

from ..helpers import VECTORS

TICK = 0.02


class ScriptedJoint(JointDriver):
    """A joint whose readings the test sets."""

    def __init__(self) -> None:
        self.reading = JointReading(0.0)
        self.commanded: float | None = None

    def command(self, degrees: float) -> None:
        self.commanded = degrees

    def read(self) -> JointReading:
        return self.reading


class Bench:
    """Modules on one SimClock and one shared tick, as the simulated robot runs them."""

    def __init__(self, count: int = 1) -> None:
        self.clock = SimClock()
        self.tick = Event("gait.tick", codec="float64", clock=self.clock)
        self.hub = LocalNeighbours()
        self.joints = [ScriptedJoint() for _ in range(count)]
        self.modules = [ModuleRuntime(joint, clock=self.clock, tick=self.tick, inline=True, ramp=0.0,
                                      module_id=k + 1, neighbours=self.hub)
                        for k, joint in enumerate(self.joints)]  # fmt: skip
        self.t = 0.0

    def load(self, program: Program, *modules: int) -> None:
        for k in modules or range(len(self.modules)):
            self.modules[k].table.set(encode_program(program))

    def start(self) -> None:
        for module in self.modules:
            module.gait.start()

    def run(self, seconds: float, each=None) -> None:
        for _ in range(round(seconds / TICK)):
            self.t = round(self.t + TICK, 9)
            self.clock.advance_to(self.t)
            self.tick.set(self.t)
            if each is not None:
                each(self.t)

    def close(self) -> None:
        for module in self.modules:
            module.close()


@pytest.fixture
def bench():
    made: list[Bench] = []

    def make(count: int = 1) -> Bench:
        made.append(Bench(count))
        return made[-1]

    yield make
    for b in made:
        b.close()


def timed(*angles: float, duration: float = 0.5) -> tuple[ModeState, ...]:
    return tuple(ModeState(a, duration, "step") for a in angles)


# -- the wire ------------------------------------------------------------------------------------------------------


def test_a_simple_program_is_written_as_version_1_bytes() -> None:
    states = [PhaseState(30.0, 1.0, "linear")]
    program = Program((Mode((ModeState(30.0, 1.0, "linear"),)),))
    assert encode_program(program) == encode_table(states)  # old tables, old bytes, old checksums
    assert decode_program(encode_table(states)) == program


def test_version_2_round_trips_and_matches_its_golden_vector() -> None:
    program = Program(
        (Mode((ModeState(10.0, 0.5, "linear", Until("at_goal", 2.0, on_timeout="stop")),
               ModeState(-10.0, None, "step", Until("neighbour", neighbour=-1, state=3)))),
         Mode((ModeState(20.0, 0.5, "step", Until("signal", state=9), emit=7),), phase=0.5, direction=-1,
              one_shot=True)),
        sequence=((0, 5), (1, 1)),
    )  # fmt: skip
    data = encode_program(program)
    assert decode_program(data) == program
    assert data.hex(" ") == (
        "47 54 02 02 02 00 05 00 01 01 00 "
        "00 00 00 00 01 00 02 00 "
        "00 00 20 41 00 00 00 3f 01 03 01 00 00 00 40 00 00 00 00 "
        "00 00 20 c1 00 00 00 00 00 05 00 00 00 00 00 ff 03 00 00 "
        "00 00 00 3f ff 01 01 00 "
        "00 00 a0 41 00 00 00 3f 00 06 00 00 00 00 00 00 09 00 07"
    )
    vector = json.loads((VECTORS / "module_objects.json").read_text())["program"]
    assert vector["hex"] == data.hex() and vector["checksum"] == checksum(data) == 0x89F64A44


@pytest.mark.parametrize(
    "mutate",
    [
        lambda d: d[:-1],  # truncated state
        lambda d: d + b"\x00",  # trailing byte
        lambda d: d[:3] + b"\x00" + d[4:],  # no modes
        lambda d: d[:3] + b"\x11" + d[4:],  # 17 modes
        lambda d: d[:2] + b"\x03" + d[3:],  # unknown version
        lambda d: d[:13] + b"\x09" + d[14:],  # mode flags beyond bit 0
        lambda d: d[:25] + b"\x07" + d[26:],  # unknown event code
        lambda d: d[:26] + b"\x05" + d[27:],  # unknown timeout outcome
        lambda d: d[:16] + b"\x00\x00\xc0\x7f" + d[20:],  # NaN angle
        lambda d: d[:5],  # ends inside the sequence
        lambda d: d[:31] + b"\x01" + d[32:],  # a neighbour offset on an at_goal state (a field it does not use)
        lambda d: d[:4] + b"\x00" + d[8:25] + bytes(6) + d[31:],  # what version 1 says: no event, no sequence
    ],
)
def test_a_malformed_version_2_table_is_refused_with_a_reason(mutate) -> None:
    program = Program((Mode((ModeState(10.0, 0.5, "linear", Until("at_goal", 2.0, on_timeout="stop")),)),),
                      sequence=((0, 5),))  # fmt: skip
    data = encode_program(program)
    with pytest.raises(ValueError):
        decode_program(mutate(data))


@settings(max_examples=400, deadline=None)
@given(st.data())
def test_any_bytes_give_a_program_or_a_value_error(data: st.DataObject) -> None:
    """Random and mutated version-2 tables (what a raw client could SET): a program or ValueError, nothing else."""
    program = Program((Mode((ModeState(10.0, 0.5, "linear", Until("at_goal", 2.0)),
                             ModeState(-10.0, None, "step", Until("neighbour", neighbour=-1, state=3)))),
                       Mode(timed(20.0), one_shot=True)), sequence=((0, 5), (1, 1)))  # fmt: skip
    base = bytearray(encode_program(program))
    if data.draw(st.booleans()):
        raw = data.draw(st.binary(max_size=300))
        blob = b"GT\x02" + raw if data.draw(st.booleans()) else raw
    else:
        for _ in range(data.draw(st.integers(1, 6))):
            k = data.draw(st.integers(0, len(base) - 1))
            base[k] = data.draw(st.integers(0, 255))
        blob = bytes(base[: data.draw(st.integers(0, len(base) + 2))])
    try:
        decoded = decode_program(blob)
    except ValueError:
        return
    assert encode_program(decoded) == blob  # one program, one form: the same bytes (and checksum) back


def test_version_2_never_says_what_version_1_says() -> None:
    data = encode_program(Program((Mode(timed(10.0)),), sequence=((0, 2),)))  # v2 only for its sequence
    assert data[2] == 2
    with pytest.raises(ValueError, match="version-1 table"):
        decode_program(data[:4] + b"\x00" + data[8:])


def test_a_module_refuses_a_program_it_cannot_run_and_keeps_its_table(bench) -> None:
    b = bench(1)
    module = b.modules[0]
    before = module.table.peek()
    wide = Program((Mode(timed(0.0)), Mode(timed(120.0))))
    with pytest.raises(ValueError, match="outside the joint limits"):
        module.table.set(encode_program(wide))
    lonely = Program((Mode((ModeState(0.0, None, "step", Until("neighbour", neighbour=-1, state=0)),)),))
    with pytest.raises(ValueError, match="no neighbour"):
        module.table.set(encode_program(lonely))  # module 1 has no module 0
    assert module.table.peek() == before


# -- sensor-driven states --------------------------------------------------------------------------------------------


def test_an_at_goal_state_ends_when_the_joint_gets_there(bench) -> None:
    b = bench(1)
    joint, module = b.joints[0], b.modules[0]
    b.load(Program((Mode((ModeState(40.0, 5.0, "step", Until("at_goal", 2.0)), ModeState(0.0, 5.0, "step"))),)))
    b.start()
    b.run(0.2)
    assert module.gait.state.peek() == 0 and module.goal.peek() == pytest.approx(40.0)
    joint.reading = JointReading(39.0)
    b.run(0.04)
    assert module.gait.state.peek() == 1


def test_a_torque_state_ends_above_its_threshold(bench) -> None:
    b = bench(1)
    joint, module = b.joints[0], b.modules[0]
    b.load(Program((Mode((ModeState(40.0, 5.0, "step", Until("torque", 0.8)), ModeState(0.0, 5.0, "step"))),)))
    b.start()
    b.run(0.2)
    joint.reading = JointReading(10.0, torque=-0.5)
    b.run(0.1)
    assert module.gait.state.peek() == 0
    joint.reading = JointReading(10.0, torque=-0.9)
    b.run(0.04)
    assert module.gait.state.peek() == 1


def test_contact_states_end_on_contact_made_and_lost_within_one_tick(bench) -> None:
    b = bench(1)
    joint, module = b.joints[0], b.modules[0]
    states = (ModeState(20.0, 3.0, "step", Until("no_contact")), ModeState(-20.0, 3.0, "step", Until("contact")))
    b.load(Program((Mode(states),)))
    joint.reading = JointReading(0.0, contact=True)
    b.start()
    changes: list[tuple[float, int]] = []
    b.run(0.5, each=lambda t: changes.append((t, module.gait.state.peek())))
    assert {s for _, s in changes} == {0}  # touching all along: no loss, no transition
    joint.reading = JointReading(0.0, contact=False)
    lifted = b.t
    b.run(0.1, each=lambda t: changes.append((t, module.gait.state.peek())))
    left = next(t for t, s in changes if s == 1)
    assert left - lifted <= 2 * TICK + 1e-9  # sensed at the next tick, acted on at the one after at worst
    joint.reading = JointReading(0.0, contact=True)
    touched = b.t
    b.run(0.1, each=lambda t: changes.append((t, module.gait.state.peek())))
    back = next(t for t, s in changes if t > touched and s == 0)
    assert back - touched <= 2 * TICK + 1e-9


def test_a_timeout_moves_on_or_ends_the_gait_as_declared(bench) -> None:
    b = bench(2)
    joint_next, joint_stop = b.joints
    go_on = Program((Mode((ModeState(30.0, 0.3, "step", Until("at_goal", 1.0)), ModeState(5.0, 1.0, "step"))),))
    give_up = Program((Mode((ModeState(30.0, 0.3, "step", Until("at_goal", 1.0, on_timeout="stop")),
                             ModeState(5.0, 1.0, "step"))),))  # fmt: skip
    b.load(go_on, 0)
    b.load(give_up, 1)
    b.start()
    b.run(0.36)  # the joints never get there
    first, second = b.modules
    assert first.gait.state.peek() == 1 and first.goal.peek() == pytest.approx(5.0)
    assert second.gait.done.peek() == TIMED_OUT
    assert _eventually(lambda: not second.gait.started)
    assert second.goal.peek() == pytest.approx(30.0)  # it holds where it was told last


def test_a_one_shot_mode_ends_in_its_final_state_and_says_so(bench) -> None:
    b = bench(1)
    module = b.modules[0]
    done: list[int] = []
    module.gait.done.on_change(done.append)
    b.load(Program((Mode((ModeState(10.0, 0.2, "linear"), ModeState(45.0, 0.4, "linear")), one_shot=True),)))
    b.start()
    b.run(1.0)
    assert done == [FINISHED]
    assert _eventually(lambda: not module.gait.started)
    assert module.goal.peek() == pytest.approx(45.0)  # the final pose holds


# -- switching -----------------------------------------------------------------------------------------------------


def test_a_switch_happens_at_the_same_boundary_on_every_module_without_a_jump(bench) -> None:
    b = bench(3)
    wave = tuple(ModeState(a, 0.25, "linear") for a in (30.0, 0.0, -30.0, 0.0))
    program = Program((Mode(wave), Mode(timed(20.0, duration=1.0))))
    for k, module in enumerate(b.modules):
        module.table.set(encode_program(program))
        module.phase.set(k / 3)
    b.start()
    b.run(0.53)
    for module in b.modules:  # arriving at slightly different moments, with the same ``after``
        module.gait.switch.set({"mode": 1, "direction": 1, "after": 0.6})
        b.run(0.02)
    goals: list[list[float]] = []
    b.run(2.0, each=lambda t: goals.append([m.goal.peek() for m in b.modules]))
    assert [m.gait.switched_at for m in b.modules] == [pytest.approx(1.0)] * 3  # first boundary at/after 0.6 s
    assert all(m.gait.mode.peek() == 1 for m in b.modules)
    steps = [abs(now[k] - before[k]) for before, now in itertools.pairwise(goals) for k in range(3)]
    assert max(steps) < 30.0 / 0.25 * TICK + 1.0  # never faster than the wave itself moves: no jump
    assert all(g == pytest.approx(20.0) for g in goals[-1])  # the blend is over after SWITCH_BLEND
    assert SWITCH_BLEND < 1.0


def test_a_sequence_runs_its_gaits_for_their_cycles_and_keeps_the_last(bench) -> None:
    b = bench(1)
    module = b.modules[0]
    program = Program((Mode(timed(10.0, 20.0)), Mode(timed(-10.0, -20.0))), sequence=((0, 2), (1, 3), (0, 1)))
    b.load(program)
    b.start()
    modes: list[tuple[float, int]] = []
    b.run(8.0, each=lambda t: modes.append((t, module.gait.mode.peek())))
    switches = [(t, m) for (t, m), (_, before) in zip(modes[1:], modes, strict=False) if m != before]
    assert [m for _, m in switches] == [1, 0]
    assert [t for t, _ in switches] == [pytest.approx(2.0), pytest.approx(5.0)]
    assert module.gait.cycle.peek() == 8


def test_a_group_switch_matches_its_golden_vector() -> None:
    from asm_module.gait_service import SWITCH
    from asm_py.protocol import Kind, Message, Method, encode

    vector = json.loads((VECTORS / "module_objects.json").read_text())["switch"]
    value = SWITCH.encode({"mode": 1, "direction": -1, "after": 12.5})
    message = encode(Message(Kind.REQUEST, Method.SET, class_id=0x2B, object_id=0, data=value))
    assert message.hex() == vector["hex"] and len(message) == 10  # two classic CAN frames, one FD frame


def test_a_switch_to_a_mode_the_module_lacks_or_in_estop_is_refused(bench) -> None:
    b = bench(1)
    module = b.modules[0]
    b.load(Program((Mode(timed(0.0)), Mode(timed(10.0)))))
    with pytest.raises(ValueError):
        module.gait.switch.set({"mode": 2, "direction": 1, "after": 0.0})
    with pytest.raises(ValueError):
        module.gait.switch.set({"mode": 1, "direction": 0, "after": 0.0})
    module.estop.set(True)
    with pytest.raises(Exception, match="emergency stop"):
        module.gait.switch.set({"mode": 1, "direction": 1, "after": 0.0})


# -- neighbours ----------------------------------------------------------------------------------------------------


def test_a_module_starts_its_stroke_the_tick_after_its_neighbour_enters_a_state(bench) -> None:
    b = bench(3)
    lead = Program((Mode(timed(0.0, 30.0, 60.0, duration=0.2)),))
    follow = Program((Mode((ModeState(0.0, None, "step", Until("neighbour", neighbour=-1, state=2)),
                            *timed(30.0, 60.0, duration=0.1))),))  # fmt: skip
    b.load(lead, 0)
    b.load(follow, 1, 2)
    b.start()
    entered: dict[int, list[float]] = {1: [], 2: [], 3: []}
    last = [0, 0, 0]

    def watch(t: float) -> None:
        for k, m in enumerate(b.modules):
            state = m.gait.state.peek()
            if state != last[k]:
                entered[k + 1].append((t, state))  # type: ignore[arg-type]
                last[k] = state

    b.run(2.0, each=watch)
    lead_in_2 = [t for t, s in entered[1] if s == 2]  # type: ignore[misc]
    second_go = [t for t, s in entered[2] if s == 1]  # type: ignore[misc]
    second_in_2 = [t for t, s in entered[2] if s == 2]  # type: ignore[misc]
    third_go = [t for t, s in entered[3] if s == 1]  # type: ignore[misc]
    assert second_go and third_go
    assert second_go[0] == pytest.approx(lead_in_2[0] + TICK)
    assert third_go[0] == pytest.approx(second_in_2[0] + TICK)  # a wave, one link at a time
    assert all(math.isfinite(m.goal.peek()) for m in b.modules)


def _eventually(condition, seconds: float = 5.0) -> bool:
    import time

    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return condition()


def test_a_sequence_switches_on_the_event_of_a_one_shot_mode_ending(bench) -> None:
    """Hierarchical: 'stand up' (one-shot), then walk (periodic): the switch happens when the first mode ends."""
    b = bench(1)
    module = b.modules[0]
    stand = Mode((ModeState(30.0, 0.3, "linear"), ModeState(60.0, 0.3, "linear")), one_shot=True)
    walk = Mode(timed(10.0, -10.0, duration=0.25))
    b.load(Program((stand, walk), sequence=((0, 0), (1, 0))))
    b.start()
    modes: list[tuple[float, int]] = []
    b.run(1.5, each=lambda t: modes.append((t, module.gait.mode.peek())))
    assert module.gait.switched_at == pytest.approx(0.6) and module.gait.started
    assert [m for _, m in modes][-1] == 1 and not module.gait.done.valid


def test_a_switch_asked_for_during_a_one_shot_mode_happens_when_it_ends(bench) -> None:
    b = bench(1)
    module = b.modules[0]
    b.load(Program((Mode((ModeState(30.0, 0.5, "linear"),), one_shot=True), Mode(timed(-10.0)))))
    b.start()
    b.run(0.1)
    module.gait.switch.set({"mode": 1, "direction": 1, "after": 0.0})
    b.run(1.0)
    assert module.gait.switched_at == pytest.approx(0.5) and module.gait.mode.peek() == 1 and module.gait.started


def test_a_broadcast_signal_ends_waiting_states_on_every_module_the_tick_after(bench) -> None:
    """A global event: module 1 emits signal 5 on entering its state 2 (at 0.5 s); the others wait for it, then go
    at the next tick."""
    b = bench(3)
    lead = Program((Mode((ModeState(0.0, 0.5, "step"), ModeState(30.0, 0.5, "step", emit=5))),))  # float32-exact
    wait = Program((Mode((ModeState(0.0, None, "step", Until("signal", state=5)), ModeState(45.0, 0.2, "step"))),))
    b.load(lead, 0)
    b.load(wait, 1, 2)
    b.start()
    went: list[float] = []
    b.run(0.7, each=lambda t: went.append(t) if b.modules[2].gait.state.peek() == 1 and not went else None)
    assert went == [pytest.approx(0.5 + TICK)]
    assert b.modules[1].gait.state.peek() == 1
    # a tool's group SET of gait.signal is the same event
    follower = b.modules[1]
    follower.gait.stop(timeout=5)
    follower.table.set(encode_program(wait))
    follower.gait.start()
    b.run(0.1)
    assert follower.gait.state.peek() == 0
    follower.gait.signal.set(5)
    b.run(0.04)
    assert follower.gait.state.peek() == 1
    with pytest.raises(ValueError):
        follower.gait.signal.set(0)
