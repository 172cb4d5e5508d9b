"""Under faults the stop still stops and the page tells the truth (issue 26): each defect a tester found, reproduced.

- a valid-looking gait of nanosecond states froze the robot and made a module deaf to its e-stop;
- the studio confirmed an E-STOP that reached nobody, and never noticed its robot was gone;
- one lost frame kept a module's object table unread, its publications off Zenoh for good;
- two deployers interleaving stage and Start: one reported success, the other's cleanup stopped it;
- values the protocol calls invalid were accepted: infinite goals, start parameters, a lease-less clear.
"""

from __future__ import annotations

import contextlib
import signal
import struct
import threading
import time

import can
import pytest

from asm_module import FakeDriver, ModuleRuntime
from asm_module.bus_robot import BusRobot as Robot
from asm_module.c_module import CModule
from asm_module.names import module_name
from asm_module.wire import encode_program
from asm_py import Event, Node
from asm_py.canbus.ids import CanId, Dest, FrameType
from asm_py.codec import FLOAT64
from asm_py.errors import EstopLatched, Locked
from asm_py.protocol import Kind, Method
from asm_py.transport.can import CanTransport
from asm_py.transport.zenoh import ZenohTransport
from gaits.deploy import DeployError, activate, deploy
from gaits.model import LIBRARY, load
from gaits.programs import module_program
from server.bridge import CanZenohBridge
from server.zenoh_args import ZenohOptions

from ..helpers import wait_until
from ..processes import Process, run
from ..transports import FAST_BEATS, free_port, fresh_name

CATERPILLAR_FILE = LIBRARY / "caterpillar.toml"
CATERPILLAR = load(CATERPILLAR_FILE)


# -- 1. a gait of nanosecond states ----------------------------------------------------------------------------


@pytest.mark.parametrize("duration", ["1e-9", "1e-45", "0.019"])
def test_states_shorter_than_a_control_tick_are_refused_by_the_loader_naming_the_field(tmp_path, duration) -> None:
    path = tmp_path / "runaway.toml"
    path.write_text(CATERPILLAR_FILE.read_text().replace("duration = 0.0625", f"duration = {duration}"))
    checked = run("-m", "gaits.cli", "validate", str(path), timeout=60)
    assert checked.returncode == 1, checked.stdout + checked.stderr
    assert "automata.wave.states[0].duration" in checked.stdout + checked.stderr
    simulated = run("-m", "gaits.cli", "simulate", str(path), "--seconds", "1", timeout=60)  # returns, refusing
    assert simulated.returncode == 1 and "duration" in simulated.stderr, simulated.stderr


def test_a_module_refuses_a_table_of_states_shorter_than_a_tick_python_and_c_alike() -> None:
    gait = load(CATERPILLAR_FILE)
    table = bytearray(encode_program(module_program(gait, 1)))
    struct.pack_into("<f", table, 5 + 4, 1e-9)  # the first state's duration (version 1: header 5, angle 4)
    runtime = ModuleRuntime(FakeDriver())
    c_module = CModule("c1", 1, interface="virtual", channel=fresh_name("short"))
    try:
        with pytest.raises(ValueError, match="at least one control tick"):
            runtime.table.set(bytes(table))
        with pytest.raises(ValueError, match="VALUE_ERROR"):
            c_module.local(Method.SET, "gait.table", bytes(table))
        struct.pack_into("<f", table, 5 + 4, 0.02)  # one tick: taken by both
        runtime.table.set(bytes(table))
        c_module.local(Method.SET, "gait.table", bytes(table))
    finally:
        runtime.close()
        c_module.close()


def test_a_module_whose_gait_handler_is_wedged_still_latches_its_estop_at_once() -> None:
    """The e-stop owns nothing else: it latches, holds the joint and answers while the gait's tick handler is stuck
    (before, the e-stop handler waited for that very handler to return, on the bus's receive thread: the module
    answered nothing, not even its e-stop)."""
    channel = fresh_name("wedged")
    options = {"interface": "virtual", "channel": channel, **FAST_BEATS}
    clock_tick = Event("gait.tick", codec=FLOAT64)
    node = Node("m1", CanTransport(1, watch_bus=False, **options))
    tool = Node("tool", CanTransport(200, **options))
    driver = FakeDriver()
    runtime = ModuleRuntime(driver, node=node, tick=clock_tick, inline=True)
    release = threading.Event()
    ticker = None
    try:
        gait = load(CATERPILLAR_FILE)
        runtime.table.set(encode_program(module_program(gait, 1)))
        runtime.gait.start()
        wedged = threading.Event()
        original = runtime.gait._output

        def stuck(now: float) -> None:  # a handler that does not return for seconds
            wedged.set()
            release.wait(10)
            original(now)

        runtime.gait._output = stuck  # type: ignore[method-assign]
        ticker = threading.Thread(target=lambda: clock_tick.set(1.0), daemon=True)
        ticker.start()
        assert wedged.wait(5)
        estop = tool.lookup("m1", "estop", timeout=5)
        began = time.monotonic()
        tool.estop("wedged")
        assert wait_until(lambda: runtime.latched and runtime.estop.peek(), timeout=5)
        assert time.monotonic() - began < 0.5, "latched at once, whatever the gait does"
        assert estop.peek(timeout=2) is True, "and the module still answers"
        held = driver.read().angle
        driver.command(held + 40.0)  # what a racing tick would command: ignored while held
        assert abs(driver.read().angle - held) < 1.0
    finally:
        release.set()
        if ticker is not None:
            ticker.join(10)
        runtime.close()
        tool.close()
        node.close()


# -- 2. the studio tells the truth about its robot --------------------------------------------------------------


def test_the_studio_says_at_once_that_its_robot_is_lost_refuses_to_deploy_and_restarts_it(studio) -> None:
    from web.link import RobotLost

    app = studio.app
    notices: list[str] = []
    studio.on_notice(lambda title, text, error: notices.append(f"{title}: {text}"))
    assert wait_until(lambda: len(app.link.alive_modules()) == 8, timeout=20)
    # the studio's restart waits until the lost robot's refusals are checked: under a fresh-clone run's load the
    # restarted robot was back before the deploy was tried, the deploy went ahead, and its lease outlived the studio
    with studio._child_lock:
        killed = time.monotonic()
        studio.child.popen.send_signal(signal.SIGKILL)
        assert wait_until(lambda: app.link.lost() is not None, timeout=5)
        assert time.monotonic() - killed < 2.0, "the page knows within a second or so"
        app.bar.tick()
        assert "ROBOT LOST" in app.bar.source_md.content and app.bar.estop.label == "E-STOP — robot LOST"
        report = app.link.estop()
        assert report.lost and not report.confirmed and "LOST" in report.text()
        with pytest.raises(RobotLost, match="deploy refused"):
            app.link.stage(app.doc.gait(), lambda *_: None)
    assert wait_until(lambda: any(n.startswith("Robot lost") for n in notices), timeout=5)
    assert wait_until(lambda: any(n.startswith("Robot restarted") for n in notices), timeout=60)
    assert wait_until(lambda: app.link.lost() is None and len(app.link.alive_modules()) == 8, timeout=30)
    assert app.link.estop().confirmed  # and the E-STOP is read back again


# -- 3. lost frames do not silence a module -----------------------------------------------------------------------


class _LosesFirstReplies(can.BusABC):
    """A bus that loses the first ``count`` LOOKUP replies each module sends the bridge (its node ID 254)."""

    def __init__(self, inner: can.BusABC, count: int) -> None:
        self.inner = inner
        self.lost: dict[int, int] = {}
        self.count = count
        super().__init__(channel=None)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.inner.send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        frame = self.inner.recv(timeout)
        if frame is None:
            return None, False
        cid = CanId.unpack(frame.arbitration_id)
        data = bytes(frame.data)
        head = data[4:8] if cid.frame == FrameType.FIRST else data[:4] if cid.frame == FrameType.SINGLE else b""
        reply = cid.dest_kind == Dest.NODE and cid.dest == 254 and len(head) == 4 and head[0] == 0x60 | Method.LOOKUP
        if reply and head[3] != 0 and self.lost.get(cid.source, 0) < self.count:
            self.lost[cid.source] = self.lost.get(cid.source, 0) + 1
            return None, False
        return frame, False

    def shutdown(self) -> None:
        super().shutdown()
        self.inner.shutdown()


def test_a_lost_lookup_reply_delays_a_modules_publications_but_never_silences_them(robot: Robot) -> None:
    bus = _LosesFirstReplies(can.Bus(interface="asm_sim", channel=robot.channel), count=2)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bridge = CanZenohBridge({"bus": bus, **robot.options}, network=ZenohOptions(listen=(endpoint,)))
    client = Node("watcher", ZenohTransport(connect=[endpoint]))
    try:
        assert wait_until(lambda: len(bridge.bridged) == 8, timeout=15)
        assert wait_until(lambda: not bridge.unread_tables, timeout=10), bridge.unread_tables
        assert sum(bus.lost.values()) == 16, "two replies of each module were lost on the way"
        seen: dict[str, int] = {}
        removers = []
        for k in range(1, 9):
            name = module_name(k)
            angle = client.lookup(name, "joint.angle", timeout=5)
            removers.append(angle.on_change(lambda value, name=name: seen.__setitem__(name, seen.get(name, 0) + 1)))
        assert wait_until(lambda: len(seen) == 8, timeout=10), seen  # every module's publications reach Zenoh
        for remove in removers:
            remove()
    finally:
        client.close()
        bridge.close()
        bus.shutdown()


# -- 4. one deployer at a time, end to end ------------------------------------------------------------------------


def test_a_staged_deployment_keeps_the_robot_until_start_and_no_one_else_can_stage_or_be_stopped(robot: Robot) -> None:
    alice, bob = robot.tool("alice", 201), robot.tool("bob", 202)
    staged = deploy(alice, CATERPILLAR, start=False)  # Alice's "Start it now?" is waiting for her click
    with pytest.raises(DeployError, match=r"being deployed by 'alice@"):
        deploy(bob, CATERPILLAR)  # Bob is told who holds the robot, and changes nothing
    assert robot.running() == [0] * 8
    time.sleep(6.0)  # longer than one grant of the lease: Alice's renewals keep it
    with pytest.raises(DeployError, match=r"being deployed by 'alice@"):
        deploy(bob, CATERPILLAR)
    activate(alice, staged)  # Alice says Start
    assert robot.running() == [staged.deploy_id] * 8
    report = deploy(bob, CATERPILLAR)  # now Bob may deploy, and Alice's deployment is over
    assert robot.running() == [report.deploy_id] * 8
    with pytest.raises(DeployError, match="holds no lease"):
        activate(alice, staged)  # a second Start of an old deployment stops nothing


def test_a_dead_deployers_lease_frees_the_robot_within_seconds(robot: Robot) -> None:
    alice, bob = robot.tool("alice", 201), robot.tool("bob", 202)
    staged = deploy(alice, CATERPILLAR, start=False)
    assert staged.lease is not None
    staged.lease._stop.set()  # Alice's process dies: nobody renews, nobody releases
    began = time.monotonic()
    while True:
        try:
            deploy(bob, CATERPILLAR)
            break
        except DeployError as exc:
            assert "alice" in str(exc)
            assert time.monotonic() - began < 8.0, "a dead deployer locked the robot for long"
            time.sleep(0.25)
    with pytest.raises(DeployError, match="lease was lost"):
        activate(alice, staged)  # and Alice, back, starts nothing


def test_a_start_whose_lease_was_lost_stops_nobody_elses_gait(robot: Robot) -> None:
    alice, bob = robot.tool("alice", 201), robot.tool("bob", 202)
    staged = deploy(alice, CATERPILLAR, start=False)
    staged.lease._stop.set()  # Alice's renewals stop (a hung laptop)
    time.sleep(5.5)
    report = deploy(bob, CATERPILLAR)  # Bob deploys meanwhile
    with pytest.raises(DeployError):
        activate(alice, staged)
    time.sleep(0.5)
    assert robot.running() == [report.deploy_id] * 8, "Bob's gait still runs"


# -- 5. what the protocol calls invalid is refused ----------------------------------------------------------------


def test_infinite_goals_start_parameters_and_a_clear_under_anothers_lease_are_refused(robot: Robot) -> None:
    tool = robot.tool()
    goal = tool.lookup("m1", "joint.goal")
    for bad in (float("inf"), float("-inf"), float("nan")):
        with pytest.raises(ValueError):
            goal.set(bad, wait=True)
    assert robot.runtimes[0].goal.peek() == 0.0
    service = tool.lookup("m1", "gait.service")
    for params in ((0.1, True), (0.1,), ("x",), ({"phase": 0.1},)):
        with pytest.raises(ValueError, match="without parameters"):
            service.start(*params, wait=True)
    assert not robot.runtimes[0].gait.started
    staged = deploy(tool, CATERPILLAR, start=False)
    other = robot.tool("other", 203)
    with pytest.raises(Locked, match="being deployed by"):
        other.lookup("m1", "gait.staged").set(b"", wait=True)
    assert robot.runtimes[0].staging.staged.peek() != b""
    staged.cancel()
    other.lookup("m1", "gait.staged").set(b"", wait=True)  # free: anyone may clear


def test_a_c_module_refuses_the_same_invalid_input() -> None:
    channel = fresh_name("c-invalid")
    c_module = CModule("m1", 1, interface="virtual", channel=channel)
    tool = Node("tool", CanTransport(200, interface="virtual", channel=channel, **FAST_BEATS))
    try:
        goal = tool.lookup("m1", "joint.goal", timeout=5)
        for bad in (float("inf"), float("-inf"), float("nan")):
            with pytest.raises(ValueError):
                goal.set(bad, wait=True)
        with pytest.raises(ValueError):
            tool.lookup("m1", "gait.service", timeout=5).start(0.1, True, wait=True)
        gait = load(CATERPILLAR_FILE)
        staged = deploy(tool, gait.__class__(**{**gait.__dict__, "modules": gait.modules[:1]}), start=False)
        other = Node("other", CanTransport(201, interface="virtual", channel=channel, **FAST_BEATS))
        try:
            with pytest.raises(Locked):
                other.lookup("m1", "gait.staged", timeout=5).set(b"", wait=True)
        finally:
            staged.cancel()
            other.close()
    finally:
        tool.close()
        c_module.close()


# -- 6. SIGTERM ends everything within 5 s, under any load --------------------------------------------------------


def test_sigterm_ends_the_studio_and_its_robot_within_five_seconds_during_a_flood() -> None:
    import zenoh

    from asm_py.protocol import Message, encode

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    studio = Process("-m", "server.studio", "--port", "0", "--zenoh-listen", endpoint)
    stop = threading.Event()
    try:
        studio.wait_for_line("READY studio", timeout=60)
        session = ZenohOptions(connect=(endpoint,)).open()
        request = encode(Message(Kind.REQUEST_REPLY, Method.GET, 0, 0x11, 2))

        def flood() -> None:
            while not stop.is_set():
                for k in range(1, 9):
                    with contextlib.suppress(zenoh.ZError):
                        session.get(f"asm/robot/m{k}/req/flooder", lambda _: None, payload=request, timeout=5.0)

        flooders = [threading.Thread(target=flood, daemon=True) for _ in range(2)]
        for thread in flooders:
            thread.start()
        time.sleep(2.0)
        began = time.monotonic()
        studio.popen.send_signal(signal.SIGTERM)
        studio.popen.wait(15)
        assert time.monotonic() - began < 6.0, f"{time.monotonic() - began:.1f} s"
        stop.set()
        for thread in flooders:
            thread.join(10)
        session.close()
    finally:
        stop.set()
        studio.stop()


# -- found by an adversarial run: each reproduced ---------------------------------------------------------------


def test_a_release_after_an_estop_during_a_start_restarts_nothing(robot: Robot) -> None:
    """Alice's Start keeps resending the activation to m8, which never confirms; an operator's e-stop, then a release:
    no module may run again (before, the next activation restarted m1-m7 at once)."""
    alice = robot.tool("alice", 201)
    operator = robot.tool("operator", 202)
    staged = deploy(alice, CATERPILLAR, start=False)
    deaf = robot.runtimes[7].staging

    def never(deploy_id: int) -> int:
        raise ValueError("m8 missed it")

    deaf._activate = never  # type: ignore[method-assign]  # m8 never hears the activation
    deaf.activate._check = never
    result: list[object] = []
    starting = threading.Thread(target=lambda: result.append(_try(lambda: activate(alice, staged, deadline=6.0))))
    starting.start()
    assert wait_until(lambda: any(r.gait.running for r in robot.runtimes[:7]), timeout=5)
    operator.estop("stop")
    assert wait_until(lambda: all(r.latched for r in robot.runtimes), timeout=5)
    time.sleep(0.5)
    for runtime in robot.runtimes:
        runtime.estop.set(False)  # released, module by module
    time.sleep(1.5)  # Alice's loop would have resent the activation several times by now
    assert not any(r.gait.running for r in robot.runtimes), "nothing moves until someone starts it again"
    starting.join(10)
    assert isinstance(result[0], DeployError) and "emergency stop" in str(result[0])
    assert all(r.staging.staged.peek() == b"" for r in robot.runtimes), "the e-stop dropped what was staged"


def _try(call):  # type: ignore[no-untyped-def]
    try:
        return call()
    except Exception as exc:
        return exc


def test_lease_and_staged_resets_and_a_nan_lease_are_refused_python_and_c(robot: Robot) -> None:
    from asm_py.errors import Locked as LockedError

    channel = fresh_name("c-resets")
    c_module = CModule("m1", 1, interface="virtual", channel=channel)
    c_tool = Node("holder", CanTransport(200, interface="virtual", channel=channel, **FAST_BEATS))
    c_other = Node("other", CanTransport(201, interface="virtual", channel=channel, **FAST_BEATS))
    try:
        for holder, other, module in ((robot.tool("holder", 201), robot.tool("other", 202), "m1"),
                                      (c_tool, c_other, "m1")):  # fmt: skip
            lease = holder.lookup(module, "gait.lease", timeout=5)
            lease.set({"holder": "holder", "token": 7, "seconds": 30.0}, timeout=5)
            with pytest.raises(LockedError):
                other.lookup(module, "gait.lease", timeout=5).reset(wait=True)  # names no token: frees nothing
            with pytest.raises(LockedError):
                other.lookup(module, "gait.staged", timeout=5).reset(wait=True)
            assert lease.peek(timeout=5)["holder"] == "holder"
            with pytest.raises(ValueError):
                other.lookup(module, "gait.lease", timeout=5).set({"holder": "x", "token": 9,
                                                                  "seconds": float("nan")}, timeout=5)  # fmt: skip
            lease.set({"holder": "holder", "token": 7, "seconds": 0.0}, timeout=5)  # released by its holder
            with pytest.raises(ValueError):
                other.lookup(module, "gait.lease", timeout=5).set({"holder": "x", "token": 9,
                                                                  "seconds": float("nan")}, timeout=5)  # fmt: skip
    finally:
        c_other.close()
        c_tool.close()
        c_module.close()


def test_a_reset_of_estop_is_refused_and_the_module_stays_latched_python_and_c(robot: Robot) -> None:
    channel = fresh_name("c-estop-reset")
    c_module = CModule("m1", 1, interface="virtual", channel=channel)
    c_tool = Node("tool", CanTransport(200, interface="virtual", channel=channel, **FAST_BEATS))
    try:
        for tool in (robot.tool(), c_tool):
            estop = tool.lookup("m1", "estop", timeout=5)
            estop.set(True, timeout=5)
            with pytest.raises(ValueError):  # VALUE_ERROR, from either
                estop.reset(wait=True)
            assert estop.peek(timeout=5) is True
            with pytest.raises(EstopLatched):
                tool.lookup("m1", "joint.goal", timeout=5).set(20.0, timeout=5)
            estop.set(False, timeout=5)
            tool.lookup("m1", "joint.goal", timeout=5).set(20.0, timeout=5)
    finally:
        c_tool.close()
        c_module.close()


def test_a_refused_stage_leaves_what_was_staged_on_a_c_module() -> None:
    channel = fresh_name("c-refused-stage")
    c_module = CModule("m1", 1, interface="virtual", channel=channel)
    tool = Node("tool", CanTransport(200, interface="virtual", channel=channel, **FAST_BEATS))
    try:
        one = load(CATERPILLAR_FILE)
        one = one.__class__(**{**one.__dict__, "modules": one.modules[:1]})
        staged = deploy(tool, one, start=False)
        record = bytearray(tool.lookup("m1", "gait.staged", timeout=5).peek(timeout=5))
        struct.pack_into("<f", record, 12 + 5 + 4, float("nan"))  # the table's first duration
        with pytest.raises(ValueError):
            tool.lookup("m1", "gait.staged", timeout=5).set(bytes(record), timeout=5)
        activate(tool, staged)  # what was staged stays staged, and starts
        assert c_module.gait_running()
    finally:
        tool.close()
        c_module.close()
