"""The board image in the loop (issue 28): the STM32F4 port's ELF, built with arm-none-eabi-gcc, run instruction by
instruction in Unicorn with models of its bxCAN, SysTick, PWM and encoder (asm_module/emulated.py), on a python-can
bus: it boots, answers lookups as the Python module does, runs a deployed gait, latches an e-stop; and the bxCAN
model's acceptance filters pass what RM0090 says they pass."""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterator

import pytest

from asm_module.bxcan import BxCan, register_image, register_image16
from asm_py import EstopLatched
from asm_py.node import Node
from asm_py.transport.can import CanTransport

from ..helpers import wait_until
from ..transports import FAST_BEATS, fresh_name

needs_arm_gcc = pytest.mark.skipif(
    shutil.which("arm-none-eabi-gcc") is None, reason="the board image needs arm-none-eabi-gcc (make test installs it)"
)
pytestmark = [pytest.mark.timeout(180)]
BUDGET = 336_000
"""10% of one 20 ms control period at 168 MHz, in cycles."""


# -- the bxCAN model --------------------------------------------------------------------------------------------


def _filters(can: BxCan, banks: dict[int, tuple[int, int]], *, listed: int = 0, wide: int = 0, fifo1: int = 0,
             active: int | None = None) -> None:  # fmt: skip
    can.write(0x200, 1)  # FINIT
    can.write(0x204, listed)
    can.write(0x20C, wide)
    can.write(0x214, fifo1)
    for bank, (r1, r2) in banks.items():
        can.write(0x240 + 8 * bank, r1)
        can.write(0x244 + 8 * bank, r2)
    can.write(0x21C, active if active is not None else sum(1 << b for b in banks))
    can.write(0x200, 0)


def test_bxcan_filters_pass_what_rm0090_says() -> None:
    can = BxCan(lambda *_: None)
    can.write(0x00, 0)  # awake, out of initialisation: receiving
    # bank 0: 32-bit mask (extended IDs 0x0305xxxx); bank 1: 32-bit list (two exact IDs); bank 2: 16-bit mask
    # (standard IDs 0x120-0x12F, and any extended ID whose STID is 0x7FF); bank 3: 16-bit list (four standard IDs)
    _filters(can, {0: (register_image(0x03050000, True), (0x03FF0000 << 3) | 4),
                   1: (register_image(0x1ABCDEF, True), register_image(0x42, False)),
                   2: (register_image16(0x120, False) | (0xFF0 << 5 | 1 << 3) << 16,
                       register_image16(0x7FF << 18, True) | (0x7FF << 5 | 1 << 3) << 16),
                   3: (register_image16(0x10, False) | register_image16(0x11, False) << 16,
                       register_image16(0x12, False) | register_image16(0x13, False) << 16)},
             listed=0b1010, wide=0b0011)  # fmt: skip
    assert can.match(0x0305ABCD, True) == (0, 0), "32-bit mask: filter number 0"
    assert can.match(0x0306ABCD, True) is None
    assert can.match(0x0305ABCD, False) is None, "the IDE bit is under the mask"
    assert can.match(0x1ABCDEF, True) == (0, 1) and can.match(0x42, False) == (0, 2), "32-bit list: numbers 1, 2"
    assert can.match(0x1ABCDEE, True) is None and can.match(0x43, False) is None
    assert can.match(0x12A, False) == (0, 3) and can.match(0x13A, False) is None, "16-bit mask: number 3"
    assert can.match(0x7FF << 18 | 0x1234, True) == (0, 4), "16-bit mask on an extended ID's STID: number 4"
    assert [can.match(i, False) for i in (0x10, 0x11, 0x12, 0x13, 0x14)] == [(0, 5), (0, 6), (0, 7), (0, 8), None]
    _filters(can, {0: (register_image(5, False), 0xFFFFFFFE), 1: (register_image(6, False), 0xFFFFFFFE)},
             wide=0b11, fifo1=0b01)  # fmt: skip
    assert can.match(6, False) == (0, 0) and can.match(5, False) == (1, 0), "each FIFO numbers its own filters"
    _filters(can, {0: (register_image(5, False), 0xFFFFFFFE)}, wide=1, fifo1=1)
    can.deliver(5, False, b"x")
    assert can.read(0x0C) & 3 == 0 and can.to_fifo1 == 1, "a frame for FIFO 1 is not in FIFO 0"
    _filters(can, {0: (0, 0)}, wide=1, active=0)
    can.deliver(7, False, b"y")
    assert can.read(0x0C) & 3 == 0 and can.filtered == 1, "no active bank: nothing passes"


def test_bxcan_fifo_and_mailboxes_work_as_the_port_uses_them() -> None:
    sent: list[tuple[int, bool, bytes]] = []
    can = BxCan(lambda *frame: sent.append(frame))
    _filters(can, {0: (0, 0)}, wide=1)  # one 32-bit mask bank that passes everything
    for k in range(5):
        can.deliver(0x100 + k, True, bytes([k]) * (k + 1))
    assert can.read(0x0C) & 3 == 0, "asleep (the reset state) nothing is received"
    can.write(0x00, 0)  # leave initialisation and sleep
    assert can.read(0x0C) == 3 | 1 << 3, "three frames, FIFO full"
    received = []
    while can.read(0x0C) & 3:
        ident, dlc, low, high = (can.read(0x1B0 + 4 * k) for k in range(4))
        received.append((ident >> 3, dlc & 15, (low | high << 32).to_bytes(8, "little")[: dlc & 15]))
        can.write(0x0C, 1 << 5)
    assert received == [(0x100 + k, k + 1, bytes([k]) * (k + 1)) for k in range(5)], "in order, none lost"
    assert can.read(0x08) >> 26 & 7 == 7, "every mailbox empty"
    can.write(0x184, 3)
    can.write(0x188, 0x04030201)
    can.write(0x180, 0x1234567 << 3 | 4 | 1)
    assert sent == [(0x1234567, True, b"\x01\x02\x03")]


# -- the board image ----------------------------------------------------------------------------------------------


@pytest.fixture
def board() -> Iterator[tuple[object, Node, str]]:
    from asm_module.emulated import EmulatedModule

    channel = fresh_name("emulated")
    module = EmulatedModule("m5", 5, interface="virtual", channel=channel)
    tool = Node(
        "tool", CanTransport(100, interface="virtual", channel=channel, heartbeat_period=0.1, missed_heartbeats=10)
    )  # the board beats every 0.5 s
    try:
        assert wait_until(lambda: "m5" in tool.discover(), timeout=20), "the board's heartbeat names it"
        yield module, tool, channel
    finally:
        tool.close()
        module.close()


@needs_arm_gcc
def test_the_board_image_boots_and_answers_lookups_as_the_python_module(board) -> None:
    from asm_module.module import Module
    from asm_py.lookup import describe_entry
    from asm_py.protocol import Method

    from .test_c_module import _python_module_entries

    module, tool, _ = board
    assert isinstance(module, Module) and module.module_id == 5
    port = tool.port("m5")
    for entry in _python_module_entries():
        assert port.call(Method.LOOKUP, 0, 0, entry.name.encode(), timeout=5).data == describe_entry(entry), entry.name
    goal = tool.lookup("m5", "joint.goal", timeout=5)
    goal.set(30.0, wait=True)
    assert module.goal_now() == 30.0
    angle = tool.lookup("m5", "joint.angle", timeout=5)
    assert wait_until(lambda: abs(angle.peek() - 30.0) < 0.5, timeout=10), "the encoder follows the servo's PWM"
    assert abs(module.angle_now() - module.driver.read().angle) < 1.0
    goal.set(500.0, wait=True)
    assert goal.peek() == 90.0, "clamped to the hardware range the board was flashed with"
    assert module.fault is None and module.milliseconds() > 100
    stats = module.tick_cycles()
    assert stats.ticks > 5 and 0 < stats.worst < BUDGET, stats
    used = module.stack_used()
    assert 64 < used < 64 * 1024, used


@needs_arm_gcc
def test_an_estop_latches_the_board_until_released(board) -> None:
    module, tool, _ = board
    goal = tool.lookup("m5", "joint.goal", timeout=5)
    goal.set(40.0, wait=True)
    tool.estop("test")
    assert wait_until(lambda: module.latched, timeout=5), "the e-stop frame passed the filter bank for it"
    with pytest.raises(EstopLatched):
        goal.set(-40.0, wait=True)
    estop = tool.lookup("m5", "estop", timeout=5)
    assert estop.peek() is True
    estop.set(False, wait=True)
    assert not module.latched
    goal.set(-40.0, wait=True)
    assert goal.peek() == -40.0


@needs_arm_gcc
def test_a_deployed_gait_runs_on_the_board_and_stops_at_the_estop() -> None:
    """A 2-module caterpillar: m1 the emulated board, m2 a Python module, one bus; the studio's deploy, then the
    e-stop."""
    from asm_module.drivers import FakeDriver
    from asm_module.emulated import EmulatedModule
    from asm_module.runtime import ModuleRuntime
    from asm_module.wire import checksum
    from gaits.deploy import DeployError, deploy, module_tables
    from gaits.model import LIBRARY, load
    from web.document import GaitDocument

    doc = GaitDocument(load(LIBRARY / "caterpillar.toml"))
    doc.set_robot("modules", 2)
    gait = doc.gait()
    channel = fresh_name("emulated-deploy")
    board = EmulatedModule("m1", 1, interface="virtual", channel=channel)
    python_node = Node("m2", CanTransport(2, interface="virtual", channel=channel, watch_bus=False))
    runtime = ModuleRuntime(FakeDriver(), node=python_node, module_id=2)
    tool = Node("studio", CanTransport(100, interface="virtual", channel=channel, heartbeat_period=0.1))
    try:
        assert wait_until(lambda: {"m1", "m2"} <= set(tool.discover()), timeout=20)
        report = deploy(tool, gait, timeout=3.0)
        assert set(report.running) == {1, 2}
        assert tool.lookup("m1", "gait.checksum", timeout=5).peek() == checksum(module_tables(gait)[1])
        state = tool.lookup("m1", "gait.state", timeout=5)
        states: list[int] = []
        unsubscribe = state.on_change(states.append)
        goals = set()
        for _ in range(40):
            goals.add(round(board.goal, 1))
            time.sleep(0.05)
        unsubscribe()
        assert len(goals) > 10 and len(set(states)) > 1, "the board's gait moves its joint through its states"
        assert board.fault is None and board.tick_cycles().worst < BUDGET
        assert abs(board.gait_started() - runtime._ramp_start) < 0.1, "one activation started both"
        tool.estop("test")
        assert wait_until(lambda: board.latched and runtime.latched, timeout=5)
        assert not tool.lookup("m1", "gait.service", timeout=5).running
        held = board.goal
        time.sleep(0.3)
        assert board.goal == held, "it holds"
        with pytest.raises(DeployError, match="emergency stop is latched on module 1"):
            deploy(tool, gait, timeout=3.0)
    finally:
        tool.close()
        runtime.close()
        python_node.close()
        board.close()


@needs_arm_gcc
@pytest.mark.parametrize("seed", range(2))
def test_random_programs_run_on_the_board_as_in_the_host_build(seed: int) -> None:
    """The Module interface in-process (load, start) on a board image and on the host build of the same sources
    (asm_module.c_module), ticked by one simulated clock, each on an identical simulated joint: the same joint goal
    at every tick. What differs is only what the board adds: its encoder's 4,096 counts a turn, so a state that ends
    at a contact or at goal may end a tick apart — the goals must stay within the neighbouring ticks' range."""
    import random

    from asm_module.c_module import CModule
    from asm_module.emulated import EmulatedModule
    from asm_module.wire import encode_program
    from asm_py.clock import SimClock
    from asm_py.event import Event

    from .programs import random_program
    from .test_c_program import ContactJoint

    rng = random.Random(2800 + seed)
    programs = []
    while len(programs) < 4:
        program = random_program(rng)
        if not program.neighbours() and not program.simple and len(encode_program(program)) <= 581:
            programs.append(program)
    for program in programs:
        clock = SimClock()
        tick = Event("gait.tick", codec="float64", clock=clock)
        host = CModule("c5", 5, driver=ContactJoint(clock=clock, tau=0.1), clock=clock, tick=tick,
                       interface="virtual", channel=fresh_name("host"))  # fmt: skip
        board = EmulatedModule("m5", 5, driver=ContactJoint(clock=clock, tau=0.1), clock=clock, tick=tick,
                               interface="virtual", channel=fresh_name("board"))  # fmt: skip
        phase, direction = round(rng.random() * 0.99, 3), rng.choice([1, -1])
        host_goals, board_goals = [], []
        try:
            for module in (host, board):
                module.load_gait(encode_program(program), phase, direction)
                module.start_gait()
            for k in range(1, 151):
                clock.advance_to(k / 50)
                tick.set(k / 50)
                host_goals.append(host.goal_now())
                board_goals.append(board.goal_now())
            assert board.fault is None and board.tick_cycles().worst < BUDGET
            assert board.done() == host.done(), "gait.done fired alike"
        finally:
            host.close()
            board.close()
        exact = sum(h == b for h, b in zip(host_goals, board_goals, strict=True))
        for k in range(1, len(host_goals) - 1):
            window = host_goals[k - 1 : k + 2]
            assert min(window) - 1e-3 <= board_goals[k] <= max(window) + 1e-3, (program, k, board_goals[k], window)
        assert exact > len(host_goals) // 2, (program, exact)


@needs_arm_gcc
def test_the_emulator_stops_an_image_that_would_fail_on_the_board(tmp_path) -> None:
    """Two faults the example port had before it ran here, put back one at a time: an image that uses the FPU
    without enabling it faults at boot; one that writes SysTick's reload to the wrong register never ticks."""
    from pathlib import Path

    from asm_module.elf import read_image
    from asm_module.emulator import Cortex, FirmwareFault, Joint
    from asm_module.firmware_build import FIRMWARE, build_cortex_m4

    port = (FIRMWARE / "port" / "stm32f4_bxcan.c").read_text()
    enable_fpu = "    SCB_CPACR |= 0xFu << 20;"
    reload = "#define SYST_RVR REG(0xE000E014u)"
    assert enable_fpu in port and reload in port

    def image(source: str) -> Path:
        c_file, elf = tmp_path / "port.c", tmp_path / "port.elf"
        c_file.write_text(source)
        build_cortex_m4(elf, replace={"stm32f4_bxcan.c": c_file})
        return elf

    joint = Joint(lambda _: None, lambda: None, lambda: (0.0, False))
    with pytest.raises(FirmwareFault, match="CPACR"):
        Cortex(read_image(image(port.replace(enable_fpu, ""))), BxCan(lambda *_: None), joint)
    core = Cortex(read_image(image(port.replace(reload, "#define SYST_RVR REG(0xE000E018u)"))), BxCan(lambda *_: None),
                  joint)  # fmt: skip
    core.run(200)
    assert core.systicks == 0 and core.ticks.ticks == 1, "no SysTick: the first control tick is the only one"
    healthy = Cortex(read_image(image(port)), BxCan(lambda *_: None), joint)
    healthy.run(200)
    assert healthy.systicks == 10 and healthy.ticks.ticks == 11, "SysTick every 20 ms: ticks at 0, 20, ..., 200 ms"
    assert healthy._fp_free_vectors == {healthy.vectors[15]: True}, "SysTick_Handler never touches the FPU"
    healthy._fp_free_vectors = {healthy.vectors[15]: False}  # as for a handler that might: the FP state kept aside
    healthy.run(400)
    assert healthy.systicks == 20 and healthy.ticks.ticks == 21


def test_a_handler_is_fp_free_only_if_every_instruction_is_16_bit_and_stays_inside() -> None:
    from asm_module.thumb import local_16bit as _local_16bit

    def free(*halfwords: int) -> bool:
        return all(_local_16bit(h, 0x100 + 2 * k, 0x100, 0x100 + 2 * len(halfwords)) for k, h in enumerate(halfwords))

    assert free(0x4A02, 0x6813, 0x3301, 0x6013, 0x4770), "SysTick_Handler: ldr, ldr, adds, str, bx lr"
    assert not free(0xEE07, 0x0A90), "vmov s15, r0: a 32-bit (FP) instruction"
    assert not free(0xF7FF, 0xFFFE), "bl: a call"
    assert not free(0x4798, 0x4770), "blx r3: a call through a register"
    assert not free(0x4687), "mov pc, r0"
    assert free(0xD000, 0x4770, 0x4770) and not free(0xD07F, 0x4770), "b<cond> inside, outside"
    assert free(0xE7FE) and not free(0xE000), "b . ; b past the end"
    assert free(0xB100, 0x4770, 0x4770) and not free(0xB1F8, 0x4770), "cbz inside, outside"


@needs_arm_gcc
def test_a_simulated_robot_with_emulated_boards_moves_as_the_all_python_preview() -> None:
    """The caterpillar with modules 1, 3, 5, 7 as emulated boards (gaits.sim, as ``asm-robot --emulated-modules
    odd``), the rest Python modules on the same bus: every module's goal at every tick within one tick of the
    all-Python preview's."""
    from gaits.model import LIBRARY, load
    from gaits.sim import Simulation

    gait = load(LIBRARY / "caterpillar.toml")
    with Simulation(gait, trace=True) as preview:
        preview.start()
        preview.advance(3.0)
        times, goals = preview.trace.times, preview.trace.goals
    channel = fresh_name("emulated-robot")
    nodes: list[Node] = []

    def node_of(module_id: int) -> Node:
        transport = CanTransport(module_id, interface="virtual", channel=channel, **FAST_BEATS,
                                 watch_bus=False)  # fmt: skip
        nodes.append(Node(f"m{module_id}", transport))
        return nodes[-1]

    odd = [a.id for a in gait.modules if a.id % 2]
    try:
        with Simulation(gait, trace=True, node_of=node_of, emulated_modules=odd,
                        bus_options={"interface": "virtual", "channel": channel}) as sim:  # fmt: skip
            assert {type(sim.modules[i]).__name__ for i in odd} == {"EmulatedModule"}
            sim.start()
            sim.advance(3.0)
            times2, goals2 = sim.trace.times, sim.trace.goals
            assert all(sim.modules[i].fault is None for i in odd)  # type: ignore[attr-defined]
            worst = max(sim.modules[i].tick_cycles().worst for i in odd)  # type: ignore[attr-defined]
    finally:
        for node in nodes:
            node.close()
    assert times2 == pytest.approx(times) and worst < BUDGET
    moving = 0
    for k in range(1, len(times) - 1):
        for column in [i - 1 for i in odd]:
            window = [goals[j][column] for j in (k - 1, k, k + 1)]
            assert min(window) - 1e-3 <= goals2[k][column] <= max(window) + 1e-3, (times[k], column + 1, window)
            moving += goals2[k][column] != goals2[k - 1][column]
    assert moving > len(times), "the boards' goals move"


def test_emulated_modules_are_simulated_modules_on_a_bus() -> None:
    """A preview has no bus for a board to sit on, and a real bus has no simulated modules to emulate: both refused
    before anything starts."""
    from gaits.model import LIBRARY, load
    from gaits.sim import Simulation
    from server.robot import main

    with pytest.raises(ValueError, match="need a bus"):
        Simulation(load(LIBRARY / "caterpillar.toml"), emulated_modules=[1])
    with pytest.raises(SystemExit) as exit_:
        main(["--can", "virtual:nowhere", "--emulated-modules", "odd"])
    assert exit_.value.code == 2


@needs_arm_gcc
def test_the_board_reproduces_the_module_object_vectors(board) -> None:
    """tests/vectors/module_objects.json on the bus, byte for byte, as the host build does (test_c_module)."""
    from asm_module.golden import reproduce_module_object_vectors

    module, _, channel = board
    done = reproduce_module_object_vectors(module, channel)
    assert all(done.values()) and len(done) == 11, done
