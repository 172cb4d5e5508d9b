"""The module runtime (asm_module/): what a module exposes, and how it protects its joint whatever it is sent."""

from __future__ import annotations

import math
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from typing import Any

import pytest

from asm_module import FakeDriver, ModuleRuntime
from asm_module.wire import checksum, decode_table, encode_table
from asm_py import Event, Node
from asm_py.automaton import PhaseState
from asm_py.clock import SimClock
from asm_py.errors import EstopLatched, RemoteError, ServiceError
from asm_py.transport import MemoryNetwork, MemoryTransport
from asm_py.transport.can import CanTransport
from gaits.deploy import DeployError, activate, deploy, stop_all
from gaits.model import load
from tests.helpers import wait_until
from tests.transports import FAST_BEATS, fresh_name

pytestmark = pytest.mark.timeout(60)
LIBRARY = "gaits/library"
WAVE = [PhaseState(float(a), 0.25, "linear") for a in (30, 60, 30, 0)]


@pytest.fixture
def pair():
    """A module runtime on a memory network and a client node next to it."""
    network = MemoryNetwork()
    module_node = Node("m1", MemoryTransport(network))
    runtime = ModuleRuntime(FakeDriver(), node=module_node, limits=(-45.0, 45.0))
    client = Node("tool", MemoryTransport(network))
    yield runtime, client
    runtime.close()
    client.close()
    module_node.close()


def test_goal_is_clamped_to_the_limits_however_it_arrives(pair):
    runtime, client = pair
    goal = client.lookup("m1", "joint.goal", timeout=2)
    goal.set(80.0, wait=True)
    assert goal.peek() == 45.0
    goal.set(-1e9, wait=True)
    assert goal.peek() == -45.0
    with pytest.raises((RemoteError, ValueError)):
        goal.set(math.nan, wait=True)
    assert runtime.goal.peek() == -45.0
    runtime.goal.set(12.5)
    assert runtime.goal.peek() == 12.5


def test_limits_can_only_narrow_within_the_hardware_range_and_reclamp_the_goal(pair):
    runtime, client = pair
    limits = client.lookup("m1", "joint.limits", timeout=2)
    client.lookup("m1", "joint.goal", timeout=2).set(40.0, wait=True)
    limits.set((-20.0, 20.0), wait=True)
    assert tuple(limits.peek()) == (-20.0, 20.0)
    assert runtime.goal.peek() == 20.0
    for bad in ((-120.0, 0.0), (10.0, -10.0), (5.0, 5.0)):
        with pytest.raises((RemoteError, ValueError)):
            limits.set(bad, wait=True)
    assert tuple(runtime.limits.peek()) == (-20.0, 20.0)


def test_table_checksum_phase_and_refusals(pair):
    runtime, client = pair
    table = client.lookup("m1", "gait.table", timeout=2)
    data = encode_table([*WAVE[:1], PhaseState(40.0, 0.5, "step")])
    table.set(data, wait=True)
    assert client.lookup("m1", "gait.checksum", timeout=2).peek() == checksum(data)
    assert [s.target for s in runtime.gait.states] == [30.0, 40.0]
    with pytest.raises((RemoteError, ValueError)):  # 60° is outside the module's ±45° limits
        table.set(encode_table(WAVE), wait=True)
    with pytest.raises((RemoteError, ValueError)):
        table.set(b"GT\x01garbage", wait=True)
    with pytest.raises((RemoteError, ValueError)):
        client.lookup("m1", "gait.phase", timeout=2).set(1.0, wait=True)
    assert client.lookup("m1", "gait.checksum", timeout=2).peek() == checksum(data)  # nothing half applied
    client.lookup("m1", "gait.service", timeout=2).start(wait=True)
    with pytest.raises((RemoteError, ServiceError)):  # never a new table under a running gait
        table.set(encode_table([PhaseState(0.0, 1.0)]), wait=True)
    client.lookup("m1", "gait.service", timeout=2).stop(wait=True)


def test_estop_stops_the_gait_holds_the_joint_and_latches(pair):
    runtime, client = pair
    runtime.table.set(encode_table([PhaseState(40.0, 0.5, "linear"), PhaseState(-40.0, 0.5, "linear")]))
    gait = client.lookup("m1", "gait.service", timeout=2)
    gait.start(wait=True)
    assert wait_until(lambda: runtime.gait.state.peek() == 1 or runtime.goal.peek() != 0.0)
    client.estop("test")
    assert wait_until(lambda: not runtime.gait.started)
    held = runtime.goal.peek()
    assert runtime.estop.peek() is True
    with pytest.raises(EstopLatched):
        gait.start(wait=True)
    assert runtime.goal.peek() == held
    client.lookup("m1", "estop", timeout=2).set(False, wait=True)
    gait.start(wait=True)
    assert wait_until(lambda: runtime.goal.peek() != held)
    gait.stop(wait=True)


def test_servo_follows_publishes_the_angle_and_goes_limp_when_stopped(pair):
    runtime, client = pair
    seen: list[float] = []
    client.lookup("m1", "joint.angle", timeout=2).on_change(seen.append)
    client.lookup("m1", "joint.goal", timeout=2).set(30.0, wait=True)
    assert wait_until(lambda: seen and abs(seen[-1] - 30.0) < 0.5)
    client.lookup("m1", "servo.service", timeout=2).stop(wait=True)
    assert runtime.driver.read().torque == 0.0
    client.lookup("m1", "joint.goal", timeout=2).set(-30.0, wait=True)
    assert abs(runtime.driver.read().angle - 30.0) < 0.5  # limp: a goal does not move the joint
    client.lookup("m1", "servo.service", timeout=2).start(wait=True)
    runtime.goal.set(-30.0)
    assert wait_until(lambda: abs(runtime.angle.peek() + 30.0) < 0.5)


def test_gait_ramps_in_and_then_follows_the_table_on_a_sim_clock():
    clock = SimClock()
    runtime = ModuleRuntime(FakeDriver(clock=clock), clock=clock, ramp=1.0)
    try:
        runtime.table.set(encode_table([PhaseState(60.0, 1.0, "step")]))
        runtime.gait.start()
        clock.advance(0.5)
        clock.settle()
        assert runtime.goal.peek() == pytest.approx(30.0, abs=1.0)  # half way through the ramp
        clock.advance(1.0)
        clock.settle()
        assert runtime.goal.peek() == 60.0
    finally:
        runtime.close()


def test_a_tick_racing_a_gait_start_waits_for_the_start_to_finish():
    """A simulated robot's physics thread ticks the modules inline while an activation starts a gait on the bus's
    thread: a tick landing between the start's subscription and its initialisation must not run the automaton
    half-initialised (it did: AttributeError on the anchor, and the gait stopped)."""
    import threading

    from asm_py import Event

    clock = SimClock()
    tick = Event("gait.tick", codec="float64", clock=clock)
    runtime = ModuleRuntime(FakeDriver(clock=clock), clock=clock, tick=tick, inline=True)
    gait = runtime.gait
    original = gait.initialize
    racer: list[threading.Thread] = []

    def initialize(phase: float) -> None:
        thread = threading.Thread(target=tick.set, args=(0.0,))  # the physics thread's tick, mid-start
        racer.append(thread)
        thread.start()
        thread.join(0.3)  # with the fix it waits for the start to finish, so it is still blocked here
        original(phase)

    gait.initialize = initialize  # type: ignore[method-assign]
    try:
        runtime.table.set(encode_table([PhaseState(60.0, 1.0, "step")]))
        gait.start()
        racer[0].join(5)
        assert not racer[0].is_alive()
        assert gait.last_error is None
        assert gait.running
    finally:
        runtime.close()


@pytest.mark.parametrize("inline", [False, True], ids=["threaded", "inline"])
@pytest.mark.parametrize("at", ["before_marked_started", "while_initialising"])
def test_an_estop_arriving_while_a_gait_starts_leaves_it_stopped(inline: bool, at: str) -> None:
    """An activation starts the gait on the bus's thread while the e-stop latches on another: a latch between the
    start's own latched check and the service counting as started found nothing to stop, and the gait ran again
    the moment the e-stop was released (test_faults' release-after-an-estop-during-a-start, once in CI)."""
    import threading

    from asm_py import Event

    clock = SimClock()
    tick = Event("gait.tick", codec="float64", clock=clock)
    runtime = ModuleRuntime(FakeDriver(clock=clock), clock=clock, tick=tick, inline=inline, ramp=0.0)
    gait = runtime.gait
    latched = threading.Event()

    def estop_on_another_thread() -> None:
        stopper = threading.Thread(target=runtime.emergency_stop, args=("stop",))
        stopper.start()
        stopper.join(5)
        latched.set()

    if at == "before_marked_started":
        original_ramp = runtime._begin_ramp

        def begin_ramp() -> None:
            estop_on_another_thread()
            original_ramp()

        runtime._begin_ramp = begin_ramp  # type: ignore[method-assign]
    else:
        original_initialize = gait.initialize

        def initialize(phase: float) -> None:
            estop_on_another_thread()
            original_initialize(phase)

        gait.initialize = initialize  # type: ignore[method-assign]
    try:
        runtime.table.set(encode_table([PhaseState(40.0, 0.5, "step"), PhaseState(-40.0, 0.5, "step")]))
        with pytest.raises(EstopLatched):
            gait.start()
        assert latched.is_set() and runtime.latched
        assert wait_until(lambda: not gait.started, timeout=5), "the e-stop that came during the start stops it"
        runtime.estop.set(False)  # released
        goal = runtime.goal.peek()
        for _ in range(10):
            tick.set(clock.now())
            clock.advance(0.1)
            clock.settle()
        assert not gait.started and runtime.goal.peek() == goal, "nothing moves until someone starts it again"
    finally:
        runtime.close()


def _on_another_thread(call: Any, *args: Any) -> None:
    thread = threading.Thread(target=call, args=args)
    thread.start()
    thread.join(5)


def _estop_and_release_once(runtime: ModuleRuntime) -> Callable[[], bool]:
    """An operator's e-stop and release, each on a thread of its own, the first time it is called (then nothing);
    returns whether this call made them."""
    fired: list[bool] = []

    def stop_and_release() -> bool:
        if fired:
            return False
        fired.append(True)
        _on_another_thread(runtime.emergency_stop, "operator")
        _on_another_thread(runtime.estop.set, False)
        return True

    return stop_and_release


@pytest.mark.parametrize("inline", [False, True], ids=["threaded", "inline"])
@pytest.mark.parametrize("at", ["start", "switch_gait", "activation"])
def test_an_estop_and_its_release_both_during_a_start_leave_the_gait_stopped(inline: bool, at: str) -> None:
    """Found by an adversarial review of the fix above: an e-stop and its release both landing while a start is on
    its way (before the service counts as started, or in an activation between its stop and its start). The
    latch's stop found nothing started, the release cleared the flag, and the start's second look saw nothing
    latched: a gait started before the e-stop ran after its release, an activation with what the e-stop
    discarded."""
    from asm_module.wire import Staged, encode_staged
    from asm_py import Event

    clock = SimClock()
    tick = Event("gait.tick", codec="float64", clock=clock)
    runtime = ModuleRuntime(FakeDriver(clock=clock), clock=clock, tick=tick, inline=inline, ramp=0.0)
    table = encode_table([PhaseState(40.0, 0.5, "step"), PhaseState(-40.0, 0.5, "step")])
    stop_and_release = _estop_and_release_once(runtime)
    try:
        if at == "start":
            runtime.table.set(table)
            ramp = runtime._begin_ramp
            runtime._begin_ramp = lambda: (stop_and_release(), ramp())[1]  # type: ignore[method-assign]
            with pytest.raises(EstopLatched):
                runtime.gait.start()
        else:
            check = runtime.gait.direction._check
            runtime.gait.direction._check = lambda v: (stop_and_release(), check(v))[1]  # type: ignore[attr-defined]
            if at == "switch_gait":
                with pytest.raises(EstopLatched):
                    runtime.switch_gait(table, 0.0, 1)
            else:
                runtime.staging.staged.set(encode_staged(Staged(7, 0.0, 1, table)))
                with pytest.raises(EstopLatched):
                    runtime.staging.activate.set(7)
                assert runtime.staging.activate.peek() != 7 and runtime.staging.staged.peek() == b""
        assert not stop_and_release() and not runtime.latched  # it fired during the start
        goal = runtime.goal.peek()
        for _ in range(10):
            tick.set(clock.now())
            clock.advance(0.1)
            clock.settle()
        assert wait_until(lambda: not runtime.gait.started, timeout=5)
        assert runtime.goal.peek() == goal, "nothing moves until someone starts it after the release"
        runtime.table.set(table)
        runtime.gait.start()  # and a start after the release starts
        assert runtime.gait.started
    finally:
        runtime.close()


class _Latching:
    """Stands in for a runtime's ``_counting`` lock: holds each e-stop's thread inside its latch (after its first
    use of the lock) until ``go``, to put two latches in flight at once."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.go = threading.Event()
        self._uses: dict[int, int] = {}

    def __enter__(self) -> None:
        self._lock.acquire()

    def __exit__(self, *_: object) -> None:
        self._lock.release()
        me = threading.get_ident()
        self._uses[me] = self._uses.get(me, 0) + 1
        if self._uses[me] == 1:
            self.go.wait(10)


@pytest.mark.parametrize("inline", [False, True], ids=["threaded", "inline"])
def test_a_start_while_two_estops_latch_at_once_is_refused(inline: bool) -> None:
    """Found by a second review: latches counted at their start and end, two at once made the count even, and a
    start begun then ran after the release. The count of latches in flight says so now."""
    clock = SimClock()
    tick = Event("gait.tick", codec="float64", clock=clock)
    runtime = ModuleRuntime(FakeDriver(clock=clock), clock=clock, tick=tick, inline=inline, ramp=0.0)
    latching = _Latching()
    runtime._counting = latching  # type: ignore[assignment]
    stops = [threading.Thread(target=runtime.emergency_stop, args=(why,)) for why in ("bus", "remote")]
    try:
        runtime.table.set(encode_table([PhaseState(40.0, 0.5, "step"), PhaseState(-40.0, 0.5, "step")]))
        for stop in stops:
            stop.start()
        assert wait_until(lambda: runtime.latches == 2, timeout=5)
        with pytest.raises(EstopLatched):
            runtime.gait.start()
        latching.go.set()
        for stop in stops:
            stop.join(5)
        runtime.estop.set(False)
        assert not runtime.gait.started and not runtime.latched
    finally:
        latching.go.set()
        runtime.close()


@pytest.mark.parametrize("inline", [False, True], ids=["threaded", "inline"])
def test_a_start_refused_by_an_estop_during_it_commands_nothing_and_a_start_after_it_starts(inline: bool) -> None:
    """Found by a second review: the refused start had already set the joint's goal to its first state (it set it
    before looking again), and a start right after it was refused as "already started" while the first one's
    thread was still ending."""
    clock = SimClock()
    tick = Event("gait.tick", codec="float64", clock=clock)
    runtime = ModuleRuntime(FakeDriver(clock=clock), clock=clock, tick=tick, inline=inline, ramp=0.0)
    commanded: list[float] = []
    command = runtime.joint.command
    runtime.joint.command = lambda goal: (commanded.append(goal), command(goal))[1]  # type: ignore[method-assign]
    ramp = runtime._begin_ramp
    stop_and_release = _estop_and_release_once(runtime)

    def estop_and_release_then_ramp() -> None:
        if stop_and_release():
            commanded.clear()
        ramp()

    runtime._begin_ramp = estop_and_release_then_ramp  # type: ignore[method-assign]
    try:
        runtime.table.set(encode_table([PhaseState(40.0, 0.5, "step"), PhaseState(-40.0, 0.5, "step")]))
        goal = runtime.goal.peek()
        with pytest.raises(EstopLatched):
            runtime.gait.start()
        assert runtime.goal.peek() == goal and commanded == []
        runtime.gait.start()
        assert runtime.gait.started and runtime.goal.peek() == 40.0
    finally:
        runtime.close()


def test_a_release_between_an_estops_latch_and_its_value_leaves_them_agreeing() -> None:
    """Found by a second review: a release landing between emergency_stop's latch and its set of ``estop`` left
    the value true and the module unlatched, and a gait then started while estop read true."""
    clock = SimClock()
    runtime = ModuleRuntime(FakeDriver(clock=clock), clock=clock)
    latch = runtime._latch
    releases = [True]

    def latch_then_release() -> None:
        latch()
        if releases:
            releases.pop()
            runtime.estop.set(False)

    runtime._latch = latch_then_release  # type: ignore[method-assign]
    try:
        runtime.emergency_stop("bus")
        assert runtime.estop.peek() is True and runtime.latched
        with pytest.raises(EstopLatched):
            runtime.gait.start()
    finally:
        runtime.close()


def test_table_wire_format_round_trips_and_rejects_damage():
    data = encode_table(WAVE)
    assert decode_table(data) == WAVE
    # the example in docs/protocol.md §9
    assert encode_table([PhaseState(30.0, 1.0, "linear")]).hex(" ") == "47 54 01 01 00 00 00 f0 41 00 00 80 3f 01"
    assert len(data) == 5 + 9 * len(WAVE)
    for bad in (data[:-1], b"XX" + data[2:], data[:2] + b"\x02" + data[3:], data + b"\x00"):
        with pytest.raises(ValueError):
            decode_table(bad)


def test_deploy_over_can_verifies_checksums_and_starts_all_with_one_broadcast():
    gait = load(f"{LIBRARY}/caterpillar.toml")
    channel = fresh_name("asm-deploy")
    runtimes, nodes = [], []
    try:
        for a in gait.modules:
            node = Node(f"m{a.id}", CanTransport(a.id, interface="virtual", channel=channel, **FAST_BEATS))
            nodes.append(node)
            runtimes.append(ModuleRuntime(FakeDriver(), node=node))
        tool = Node("tool", CanTransport(200, interface="virtual", channel=channel, **FAST_BEATS))
        nodes.append(tool)
        steps: list[tuple[int, int]] = []
        report = deploy(tool, gait, start=False, progress=lambda done, total, _: steps.append((done, total)))
        assert steps[-1] == (8, 8) and len(report.checksums) == 8 and report.running == []
        assert not any(runtime.gait.started for runtime in runtimes)  # staged only
        activate(tool, report)
        assert report.running == list(range(1, 9)) and all(r.gait.started for r in runtimes)
        for runtime, a in zip(runtimes, gait.modules, strict=True):
            assert runtime.phase.peek() == pytest.approx(a.phase, abs=1e-6)
        stop_all(tool)
        assert wait_until(lambda: not any(r.gait.started for r in runtimes))
        runtimes[3].limits.set((-10.0, 10.0))  # module 4 can no longer take ±50°: nothing may start
        with pytest.raises(DeployError, match="module 4"):
            deploy(tool, gait)
    finally:
        for runtime in runtimes:
            runtime.close()
        for node in nodes:
            node.close()


def test_asm_module_command_starts_and_stops_cleanly_on_sigterm():
    channel = fresh_name("asm-cli")
    # python-can's virtual bus is per process: the command runs in this process's interpreter via runpy.
    code = (
        "import sys; from server import module; "
        f"sys.exit(module.main(['--can', 'virtual:{channel}', '--node-id', '7']))"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "READY m7"
        proc.send_signal(signal.SIGTERM)  # once ready (the command once sent it to itself 8 s after its start)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
