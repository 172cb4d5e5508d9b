"""joint.calibration and module.info on the Python module runtime (issue 28 parts 1 and 3): the calibration maps the
joint's raw angle both ways, its soft limits bound joint.limits and the goal, hostile values are refused (never
clamped) and leave nothing stored, and it survives a restart (a calibration file, a commissioned module's power
cycle)."""

from __future__ import annotations

import json
import math
import struct

import can
import pytest

from asm_module import FakeDriver, ModuleRuntime
from asm_module.calibration import VERSION, Calibration, CalibrationFile, build_id, check_calibration
from asm_module.commissioning import Fleet, calibration_path
from asm_py import Node
from asm_py.errors import EstopLatched, MessageTooLarge, ReadOnlyError, RemoteError
from asm_py.protocol import Method, Status
from asm_py.remote import RemoteAttribute
from asm_py.transport import MemoryNetwork, MemoryTransport
from asm_py.transport.can import CanTransport
from tests.helpers import wait_until
from tests.transports import fresh_name

pytestmark = pytest.mark.timeout(120)
TURNED = {"zero": 10.0, "direction": -1, "min": -60.0, "max": 70.0}
"""A joint mounted the other way round, its zero 10° off: raw = 10 - angle, so the soft limits -60..70 are the raw
angles 70..-60, within the hardware's -90..90."""


@pytest.fixture
def pair(tmp_path):
    """A module runtime keeping its calibration in a file, on a memory network, and a client node next to it."""
    network = MemoryNetwork()
    module_node = Node("m1", MemoryTransport(network))
    store = CalibrationFile(tmp_path / "calibration.json")
    runtime = ModuleRuntime(FakeDriver(tau=0.01), node=module_node, calibration_store=store)
    client = Node("tool", MemoryTransport(network))
    yield runtime, client, store
    runtime.close()
    client.close()
    module_node.close()


def test_module_info_says_version_build_and_limits_and_is_read_only(pair) -> None:
    runtime, client, _ = pair
    info = client.lookup("m1", "module.info", timeout=2)
    value = info.get(timeout=2)
    assert value == {"version": VERSION, "build": build_id(), "language": 0, "max_states": 1024, "max_modes": 16,
                     "max_message": 4096, "tick_cycles": 0, "stack_bytes": 0}  # fmt: skip
    assert value["build"] != 0
    with pytest.raises(ReadOnlyError):
        info.set(dict(value, version=0x020000), wait=True)
    assert runtime.info.peek()["version"] == VERSION


def test_a_calibration_maps_the_joint_both_ways_and_its_limits_bound_the_goal(pair) -> None:
    runtime, client, store = pair
    driver = runtime.driver
    calibration = client.lookup("m1", "joint.calibration", timeout=2)
    assert calibration.get(timeout=2) == {"zero": 0.0, "direction": 1, "min": -90.0, "max": 90.0}
    calibration.set(TURNED, wait=True)
    assert calibration.get(timeout=2) == TURNED
    assert json.loads(store.path.read_text()) == TURNED, "stored before it was answered"
    limits = client.lookup("m1", "joint.limits", timeout=2)
    assert tuple(limits.get(timeout=2)) == (-60.0, 70.0), "the soft limits are the joint's limits"
    goal = client.lookup("m1", "joint.goal", timeout=2)
    goal.set(20.0, wait=True)
    assert wait_until(lambda: abs(driver.read().angle + 10.0) < 0.1, timeout=5), "raw = zero + direction * goal"
    assert wait_until(lambda: abs(runtime.angle.peek() - 20.0) < 0.1, timeout=5), "read back: direction*(raw-zero)"
    goal.set(100.0, wait=True)
    assert goal.peek() == 70.0, "a goal beyond the soft limits is clamped as joint.limits clamps it"
    goal.set(-1e9, wait=True)
    assert goal.peek() == -60.0
    for wider in ((-70.0, 0.0), (0.0, 80.0)):
        with pytest.raises(ValueError, match="soft limits"):
            limits.set(wider, wait=True)
    limits.set((-30.0, 30.0), wait=True)  # narrower: as before
    assert goal.peek() == -30.0
    limits.reset(wait=True)  # back to the soft limits, as the C runtime does
    assert tuple(limits.get(timeout=2)) == (-60.0, 70.0)


def test_a_new_zero_keeps_the_joint_where_it_is_commanded(pair) -> None:
    """What "set the current pose as zero" does: the joint does not move, its angle reads 0 there."""
    runtime, client, _ = pair
    goal = client.lookup("m1", "joint.goal", timeout=2)
    goal.set(30.0, wait=True)
    assert wait_until(lambda: abs(runtime.angle.peek() - 30.0) < 0.1, timeout=5)
    client.lookup("m1", "joint.calibration", timeout=2).set({"zero": 30.0, "direction": 1, "min": -90.0,
                                                             "max": 60.0}, wait=True)  # fmt: skip
    assert goal.get(timeout=2) == 0.0
    assert runtime.driver.read().angle == pytest.approx(30.0, abs=0.1), "the raw joint stays"
    assert wait_until(lambda: abs(runtime.angle.peek()) < 0.1, timeout=5)
    client.lookup("m1", "joint.calibration", timeout=2).reset(wait=True)  # none again: the raw angle, read as is
    assert goal.get(timeout=2) == pytest.approx(30.0)
    assert tuple(client.lookup("m1", "joint.limits", timeout=2).get(timeout=2)) == (-90.0, 90.0)


HOSTILE = [
    {"zero": math.nan, "direction": 1, "min": -10.0, "max": 10.0},
    {"zero": 0.0, "direction": 1, "min": -math.inf, "max": 10.0},
    {"zero": 0.0, "direction": 1, "min": -10.0, "max": math.inf},
    {"zero": 0.0, "direction": 0, "min": -10.0, "max": 10.0},
    {"zero": 0.0, "direction": 2, "min": -10.0, "max": 10.0},
    {"zero": 0.0, "direction": -128, "min": -10.0, "max": 10.0},
    {"zero": 0.0, "direction": 1, "min": 10.0, "max": 10.0},
    {"zero": 0.0, "direction": 1, "min": 20.0, "max": -20.0},
    {"zero": 50.0, "direction": 1, "min": -10.0, "max": 60.0},  # raw 110: beyond the hardware's 90
    {"zero": 1e30, "direction": 1, "min": -1e30, "max": 1e30},
    {"zero": 0.0, "direction": 1, "min": -3.4e38, "max": 3.4e38},
]


@pytest.mark.parametrize("value", [*HOSTILE, "zero", 12, None, [0, 1, -1, 1]])
def test_hostile_calibrations_are_refused_never_clamped_and_nothing_is_stored(pair, value) -> None:
    runtime, client, store = pair
    calibration = client.lookup("m1", "joint.calibration", timeout=2)
    calibration.set({"zero": 5.0, "direction": 1, "min": -80.0, "max": 80.0}, wait=True)
    before = store.path.read_bytes()
    with pytest.raises((ValueError, TypeError)):
        calibration.set(value, wait=True)
    with pytest.raises((ValueError, TypeError)):
        runtime.calibration.set(value)  # the module's own path too
    assert calibration.get(timeout=2) == {"zero": 5.0, "direction": 1, "min": -80.0, "max": 80.0}
    assert store.path.read_bytes() == before


def test_calibration_bytes_of_the_wrong_length_are_refused(pair) -> None:
    """What a broken tool might send: a record cut short, one byte too many, a huge payload."""
    runtime, client, _ = pair
    info = client.lookup("m1", "joint.calibration", timeout=2).info
    good = struct.pack("<fbff", 1.0, 1, -10.0, 10.0)
    for data in (good[:12], good + b"\0", good * 300):
        with pytest.raises((ValueError, TypeError, RemoteError, MessageTooLarge)):
            client.port("m1").call(Method.SET, info.class_id, info.object_id, data, timeout=5)
    assert runtime.joint.calibration == Calibration(0.0, 1, -90.0, 90.0)
    reply = client.port("m1").call(Method.SET, info.class_id, info.object_id, good, timeout=5)
    assert reply.status == Status.OK and runtime.joint.calibration == Calibration(1.0, 1, -10.0, 10.0)


def test_mapped_limits_are_checked_in_the_raw_frame() -> None:
    hardware = (-90.0, 90.0)
    turned = check_calibration({"zero": -50.0, "direction": -1, "min": -40.0, "max": 40.0}, hardware)
    assert (turned.raw(turned.min), turned.raw(turned.max)) == (-10.0, -90.0)
    with pytest.raises(ValueError, match="hardware"):
        check_calibration({"zero": -50.0, "direction": -1, "min": -40.0, "max": 41.0}, hardware)
    with pytest.raises(ValueError):
        check_calibration({"zero": 0.0, "direction": True, "min": -40.0, "max": 40.0}, hardware)
    with pytest.raises(ValueError):
        check_calibration({"zero": 0.0, "direction": 1, "min": -40.0, "max": 40.0, "extra": 1}, hardware)


def test_the_estop_refuses_a_calibration(pair) -> None:
    runtime, client, _ = pair
    runtime.emergency_stop("test")
    with pytest.raises(EstopLatched):
        client.lookup("m1", "joint.calibration", timeout=2).set(TURNED, wait=True)
    assert runtime.joint.calibration == Calibration(0.0, 1, -90.0, 90.0)


def test_the_calibration_file_survives_a_restart_and_a_damaged_one_is_refused(tmp_path) -> None:
    store = CalibrationFile(tmp_path / "c.json")
    runtime = ModuleRuntime(FakeDriver(), calibration_store=store, limits=(-90.0, 90.0))
    try:
        runtime.calibration.set(TURNED)
    finally:
        runtime.close()
    driver = FakeDriver(tau=0.01)
    runtime = ModuleRuntime(driver, calibration_store=store)  # restarted
    try:
        assert runtime.calibration.peek() == TURNED and tuple(runtime.limits.peek()) == (-60.0, 70.0)
        runtime.goal.set(20.0)
        assert wait_until(lambda: abs(driver.read().angle + 10.0) < 0.1, timeout=5)
    finally:
        runtime.close()
    for damage in ("{not json", json.dumps({**TURNED, "direction": 3}), json.dumps({**TURNED, "zero": "NaN"})):
        store.path.write_text(damage)
        with pytest.raises(ValueError):
            ModuleRuntime(FakeDriver(), calibration_store=store)


def test_a_commissioned_module_keeps_its_calibration_across_a_power_cycle(tmp_path) -> None:
    channel = fresh_name("calibration")
    (tmp_path / "module0.json").write_text(json.dumps({"serial": "00" * 11 + "01", "node_id": 4}))
    fleet = Fleet(tmp_path, 1, channel)
    bus = can.Bus(interface="asm_sim", channel=channel)
    tool = Node("tool", CanTransport(250, bus=bus, heartbeat_period=0.2))
    try:
        assert wait_until(lambda: "m4" in tool.transport.peers(), timeout=10)
        remote = tool.lookup("m4", "joint.calibration", timeout=2)
        assert isinstance(remote, RemoteAttribute)
        remote.set(TURNED, wait=True)
        assert json.loads(calibration_path(tmp_path / "module0.json").read_text()) == TURNED
        fleet.reset()  # a power cycle: the module boots again from its files
        runtime = fleet.modules[0].runtime
        assert runtime is not None and runtime.calibration.peek() == TURNED
        again = tool.lookup("m4", "joint.calibration", timeout=5)  # the rebooted module, looked up anew
        assert isinstance(again, RemoteAttribute) and again.get(timeout=5) == TURNED
    finally:
        tool.close()
        bus.shutdown()
        fleet.close()


@pytest.mark.parametrize("flag", ["--calibration-file", "--id-file"])
def test_asm_module_refuses_a_damaged_calibration_file_before_opening_the_bus(tmp_path, capsys, flag) -> None:
    """``asm-module --calibration-file`` reads the file it names, and with ``--id-file`` the one next to it."""
    from server import module

    identity = tmp_path / "m.json"
    target = tmp_path / "c.json" if flag == "--calibration-file" else calibration_path(identity)
    target.write_text(json.dumps({**TURNED, "direction": 7}))
    argv = ["--can", f"virtual:{fresh_name('cli')}", *(["--node-id", "7", flag, str(target)]
            if flag == "--calibration-file" else [flag, str(identity)])]  # fmt: skip
    assert module.main(argv) == 1
    assert "direction is +1 or -1" in capsys.readouterr().err
