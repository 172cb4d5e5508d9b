"""Preview equals deployment for every kind of automaton: the same gait on modules that hear each other over a CAN
bus (``asm_sim``, handed their frames by the channel's dispatch thread, as in the robot process) commands, tick for
tick, what the preview's modules command in-process — with every module in Python, and with the odd modules running
the C runtime (firmware/) on the same bus.

Between two ticks the deployment waits until nothing is in flight on the bus (``Simulation.settle``), as a robot
whose frames take less than a tick does. Paced on the wall clock instead (a tick every 20 ms, hoping the frames had
arrived), a frame came a tick late under the suite's load: contact_inchworm's module 2 a tick behind (stop 48's
fresh-clone run), and under four workers these tests failed more than any other."""

from __future__ import annotations

import time

import pytest

from asm_py import Node
from asm_py.transport.can import CanTransport
from gaits.model import LIBRARY, load
from gaits.sim import Simulation
from tests.transports import FAST_BEATS, fresh_name

from .preview import SIGNALLED

pytestmark = pytest.mark.timeout(180)
TICK = 1 / 50


def _trace(gait, seconds: float, *, bus: bool, drive_at: float | None = None,
           c_modules: bool = False) -> tuple[list[float], list[list[float]]]:  # fmt: skip
    nodes: list[Node] = []
    channel = fresh_name("asm-program")

    def node_of(module_id: int) -> Node:
        transport = CanTransport(module_id, interface="asm_sim", channel=channel, **FAST_BEATS, watch_bus=False,
                                 receive_thread=False)  # fmt: skip
        nodes.append(Node(f"m{module_id}", transport))
        return nodes[-1]

    try:
        odd = [a.id for a in gait.modules if a.id % 2] if c_modules else []
        options = {"interface": "asm_sim", "channel": channel} if bus else None  # no bus: the preview's hub
        with Simulation(gait, trace=True, node_of=node_of if bus else None, c_modules=odd, bus_options=options) as sim:
            sim.start()
            while sim.data.time < seconds - 1e-9:
                if drive_at is not None and abs(sim.data.time - drive_at) < TICK / 2:
                    sim.drive("left")
                sim.step_tick()
                sim.settle()  # what the bus carries arrives between ticks
            return sim.trace.times, sim.trace.goals
    finally:
        for node in nodes:
            node.close()


def _assert_within_one_tick(preview, deployed) -> None:
    times, goals = preview
    times2, goals2 = deployed
    assert times == pytest.approx(times2)
    for k in range(1, len(times) - 1):
        for column, value in enumerate(goals2[k]):
            window = [goals[j][column] for j in (k - 1, k, k + 1)]
            assert min(window) - 1e-3 <= value <= max(window) + 1e-3, (times[k], column + 1, value, window)


def _assert_in_lockstep(gait, seconds: float, deployed, *, c_modules: bool, drive_at: float | None = None) -> None:
    """Stepped in lockstep, a deployment commands exactly what the preview of the same modules (C ones on the
    preview's hub) commands at every tick: not merely within a tick, so a frame handled a tick late shows."""
    same = _trace(gait, seconds, bus=False, c_modules=c_modules, drive_at=drive_at)
    assert deployed[0] == same[0]
    late = [(t, k + 1) for t, a, b in zip(same[0], same[1], deployed[1], strict=True) for k in range(len(a))
            if a[k] != b[k]]  # fmt: skip
    assert not late, f"(time, module) where the deployment differs from its preview: {late[:10]}"


MIXED = pytest.mark.parametrize("c_modules", [False, True], ids=["python", "half-c"])


@MIXED
@pytest.mark.parametrize("name", ["neighbour_caterpillar", "curl_into_loop", "contact_inchworm", "caterpillar_tour"])
def test_preview_equals_deployment_for_neighbour_contact_one_shot_and_sequenced_gaits(name, c_modules) -> None:
    gait = load(LIBRARY / f"{name}.toml")
    seconds = 6.5 if name == "caterpillar_tour" else 3.0  # the tour switches to left after 5 cycles
    preview = _trace(gait, seconds, bus=False)
    deployed = _trace(gait, seconds, bus=True, c_modules=c_modules)
    _assert_within_one_tick(preview, deployed)
    _assert_in_lockstep(gait, seconds, deployed, c_modules=c_modules)
    if name == "neighbour_caterpillar":  # it really is a wave: the modules are in different places
        last = preview[1][-1]
        assert max(last) - min(last) > 20.0
    if name == "caterpillar_tour":  # its own sequence switched it to left after 5 cycles: the yaw joints bend
        assert preview[1][-1][1] == pytest.approx(20.0) and preview[1][int(4.5 * 50)][1] == pytest.approx(0.0)


@pytest.mark.parametrize("name", ["neighbour_caterpillar", "contact_inchworm", "curl_into_loop"])
def test_a_preview_with_c_modules_equals_the_all_python_preview(name) -> None:
    """The studio's preview with --c-modules: the odd modules run the C runtime on the preview's in-process hub
    (no bus), hearing and telling neighbours' states as the Python modules do."""
    gait = load(LIBRARY / f"{name}.toml")
    _assert_within_one_tick(_trace(gait, 3.0, bus=False), _trace(gait, 3.0, bus=False, c_modules=True))


def test_a_preview_with_c_modules_hears_a_broadcast_signal() -> None:
    from gaits.model import loads

    gait = loads(SIGNALLED)
    preview = _trace(gait, 3.0, bus=False, c_modules=True)
    _assert_within_one_tick(_trace(gait, 3.0, bus=False), preview)
    assert max(row[2] for row in preview[1]) > 35.0  # module 3, in C, heard module 1's signal (in C too) and moved


@MIXED
def test_preview_equals_deployment_across_a_switch(c_modules) -> None:
    gait = load(LIBRARY / "steerable_caterpillar.toml")
    preview = _trace(gait, 3.0, bus=False, drive_at=0.5)
    deployed = _trace(gait, 3.0, bus=True, drive_at=0.5, c_modules=c_modules)
    _assert_within_one_tick(preview, deployed)
    _assert_in_lockstep(gait, 3.0, deployed, c_modules=c_modules, drive_at=0.5)
    yaw = [row[1] for row in preview[1]]
    assert yaw[0] == pytest.approx(0.0) and yaw[-1] == pytest.approx(20.0)  # the yaw joints bent to turn


@MIXED
def test_preview_equals_deployment_with_a_broadcast_signal(c_modules) -> None:
    """A group/broadcast event: module 1 emits signal 7 each cycle (a group SET on the bus); the others wait for it.
    Over CAN they go at the same ticks as in the preview."""
    from gaits.model import loads

    gait = loads(SIGNALLED)
    preview = _trace(gait, 3.0, bus=False)
    deployed = _trace(gait, 3.0, bus=True, c_modules=c_modules)
    _assert_within_one_tick(preview, deployed)
    _assert_in_lockstep(gait, 3.0, deployed, c_modules=c_modules)
    followers = [row[1] for row in preview[1]]
    assert max(followers) > 35.0  # the signal arrived: the followers moved


def _relay(channel: str, hops: int, forever: list[bool], pause: float = 0.0) -> tuple[list[int], list[object]]:
    """Two pushed buses on ``channel`` that pass a frame back and forth, one hop more each time, up to ``hops``
    (while ``forever[0]``: without end), each hop handled in ``pause`` seconds; what arrived, and the two buses."""
    import can

    from asm_py.canbus.simbus import SimBus

    heard: list[int] = []
    a, b = SimBus(channel=channel), SimBus(channel=channel)
    a.set_filters([{"can_id": 0xA00, "can_mask": 0xF00, "extended": True}])
    b.set_filters([{"can_id": 0xB00, "can_mask": 0xF00, "extended": True}])

    def passer(sender, to: int):
        def on_frame(frame: can.Message) -> None:
            time.sleep(pause)  # a handler slower than a look at the list: the next hop is in flight meanwhile
            hop = frame.data[0]
            heard.append(hop)
            if hop < hops or forever[0]:
                sender.send(can.Message(arbitration_id=0x10000000 | to, data=[(hop + 1) & 0xFF], is_extended_id=True))

        return on_frame

    a.push_to(passer(a, 0xB00))
    b.push_to(passer(b, 0xA00))
    return heard, [a, b]


@pytest.mark.parametrize("channel", ["given", None], ids=["channel-given", "default-channel"])
def test_settle_waits_for_what_the_frames_it_handed_on_sent_in_turn(channel) -> None:
    """A frame answered by a frame answered by a frame…: one flush of the bus sees only the first hop; settle goes
    on until the bus stays quiet. Without a channel in the options, the modules' buses open SimBus's own default,
    and settle flushes that one (it once flushed a channel named "" and returned at once)."""
    import can

    gait = load(LIBRARY / "caterpillar.toml")
    name = fresh_name("asm-settle") if channel else "asm_sim"
    options = {"interface": "asm_sim", **({"channel": name} if channel else {})}
    heard, buses = _relay(name, 6, [False], pause=0.02)
    try:
        with Simulation(gait, bus_options=options) as sim:
            buses[0].send(can.Message(arbitration_id=0x10000B00, data=[0], is_extended_id=True))
            sim.settle()
            assert heard == [0, 1, 2, 3, 4, 5, 6]
    finally:
        for bus in buses:
            bus.shutdown()


def test_settle_says_so_when_the_bus_never_goes_quiet() -> None:
    import can

    from asm_py import SimulationStalled

    gait = load(LIBRARY / "caterpillar.toml")
    channel = fresh_name("asm-settle")
    forever = [True]
    heard, buses = _relay(channel, 0, forever)
    try:
        with Simulation(gait, bus_options={"interface": "asm_sim", "channel": channel}) as sim:
            sim.clock.settle_timeout = 0.5
            buses[0].send(can.Message(arbitration_id=0x10000B00, data=[0], is_extended_id=True))
            with pytest.raises(SimulationStalled, match="not quiet"):
                sim.settle()
            forever[0] = False
            sim.settle()  # the relay stopped: quiet again
            assert len(heard) > 10
    finally:
        for bus in buses:
            bus.shutdown()
