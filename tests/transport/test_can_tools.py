"""What CAN users expect around the transport: python-can log files that replay, a DBC that cantools decodes
recorded traffic with, and a bus-load calculator (function and CLI)."""

from __future__ import annotations

import struct
import subprocess
import sys
import time
from pathlib import Path

import can
import cantools
import pytest

from asm_module import FakeDriver, ModuleRuntime
from asm_module.wire import encode_table
from asm_py import Attribute, PhaseState
from asm_py.canbus import busload, dbc
from asm_py.canbus.ids import CanId, Dest, Priority
from asm_py.node import Node
from asm_py.transport.can import CanTransport

from ..helpers import wait_until
from ..transports import FAST_BEATS, fresh_name


def record_session(path: Path) -> list[float]:
    """A module (ID 1) publishing its angle, a tool (ID 2) setting and reading it; the tool records the bus."""
    channel = fresh_name("asm-rec")
    module = Node("m1", CanTransport(1, interface="virtual", channel=channel, **FAST_BEATS))
    tool = Node("tool", CanTransport(254, interface="virtual", channel=channel, **FAST_BEATS, record=path))
    values = [0.25, 0.5, 1.0]
    try:
        angle = Attribute("joint.angle", 0.0, codec="float32")
        module.register(angle)
        angle.publish()
        remote = tool.lookup("m1", "joint.angle", timeout=5)
        copy = Attribute("copy", codec="float32")
        copy.subscribe(remote)
        for value in values:
            angle.set(value)
            assert wait_until(lambda v=value: copy.peek() == v, timeout=5)
        remote.set(1.5, wait=True)
        assert remote.get() == 1.5
        copy.unsubscribe()
    finally:
        tool.close()
        module.close()
    return [*values, 1.5]


@pytest.mark.parametrize("suffix", [".blf", ".asc", ".log"])
def test_traffic_is_recorded_in_python_can_formats_and_replays(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"session{suffix}"
    record_session(path)
    frames = list(can.LogReader(path))
    assert len(frames) > 10 and all(f.is_extended_id for f in frames)
    assert any(bytes(f.data[4:8]) == struct.pack("<f", 1.5) for f in frames)
    player = subprocess.run([sys.executable, "-m", "can.player", "-i", "virtual", "-c", "replay", "--ignore-timestamps",
                             str(path)], capture_output=True, text=True, timeout=60)  # fmt: skip
    assert player.returncode == 0, player.stderr


def test_a_replayed_log_drives_a_fresh_module(tmp_path: Path) -> None:
    path = tmp_path / "session.log"
    record_session(path)
    channel = fresh_name("asm-replay")
    module = Node("m1", CanTransport(1, interface="virtual", channel=channel))
    try:
        angle = Attribute("joint.angle", 0.0, codec="float32")
        module.register(angle)
        for frame in can.LogReader(path):
            if frame.is_rx is False:  # what the tool sent: its requests
                module.transport.on_frame(frame)  # type: ignore[attr-defined]
        assert angle.peek() == 1.5
    finally:
        module.close()


pytestmark = pytest.mark.xdist_group("test_can_tools")  # one worker builds the module's DBC, once


@pytest.fixture(scope="module")
def module_dbc() -> cantools.database.can.Database:
    """The DBC of module 1 and tool 254, loaded strictly (no overlaps): generating and loading it takes seconds, so
    the tests of this module share it."""
    return cantools.database.load_string(dbc.generate([1], tool=254), "dbc")


def test_cantools_decodes_a_recorded_log_with_the_generated_dbc(tmp_path: Path, module_dbc) -> None:
    path = tmp_path / "session.asc"
    values = record_session(path)
    db = module_dbc
    seen: list[float] = []
    for frame in can.LogReader(path):
        cid = CanId.unpack(frame.arbitration_id)
        if cid.source == 1 and cid.priority == Priority.PUBLICATION and cid.dest_kind == Dest.BROADCAST:
            decoded = db.decode_message(frame.arbitration_id, bytes(frame.data), allow_truncated=True)
            assert decoded["class_id"] == 0x11 and decoded["kind"] == "PUBLICATION"
            seen.append(decoded["joint_angle"])
    assert seen[: len(values) - 1] == values[:-1]
    request = next(f for f in can.LogReader(path) if bytes(f.data[4:8]) == struct.pack("<f", 1.5))
    assert db.decode_message(request.arbitration_id, bytes(request.data))["joint_angle"] == 1.5


def record_module_session(path: Path) -> None:
    """A module runtime (ID 1) and a tool with a long name (ID 254, so its heartbeats are fragmented) on one bus,
    recorded by the tool: lookups, gets and sets, a gait table (a fragmented request), publications of the angle and
    the gait state, an e-stop, then both leave."""
    channel = fresh_name("asm-dbc")
    module = Node("m1", CanTransport(1, interface="virtual", channel=channel, **FAST_BEATS))
    runtime = ModuleRuntime(FakeDriver(), node=module)
    tool = Node("a-long-tool-name", CanTransport(254, interface="virtual", channel=channel, **FAST_BEATS,
                                                 record=path))  # fmt: skip
    try:
        goal = tool.lookup("m1", "joint.goal", timeout=5)
        goal.set(12.5, wait=True)
        assert goal.get() == 12.5
        tool.lookup("m1", "gait.state", timeout=5).get()
        tool.lookup("m1", "gait.table", timeout=5).set(encode_table([PhaseState(10.0, 0.5), PhaseState(-10.0, 0.5)]),
                                                       wait=True)  # fmt: skip
        tool.lookup("m1", "gait.service", timeout=5).start()
        time.sleep(0.6)
        tool.estop("test")
        assert wait_until(lambda: runtime.latched, timeout=5)
    finally:
        runtime.close()
        module.close()
        tool.close()


def test_every_frame_of_a_recorded_log_decodes_with_the_dbc(tmp_path: Path, module_dbc) -> None:
    path = tmp_path / "module.asc"
    record_module_session(path)
    db = module_dbc
    names: dict[str, list[dict]] = {}
    for frame in can.LogReader(path):
        message = db.get_message_by_frame_id(frame.arbitration_id)  # KeyError if the DBC lacks the frame
        names.setdefault(message.name, []).append(db.decode_message(frame.arbitration_id, bytes(frame.data),
                                                                    allow_truncated=True))  # fmt: skip
    for expected in ("ASM_HEARTBEAT_N1", "ASM_FIRST_HEARTBEAT_N254", "ASM_LAST_HEARTBEAT_N254_C2", "ASM_LEAVE_N1",
                     "ASM_LEAVE_N254", "ASM_ESTOP_N254", "ASM_REQ_N254_TO_N1", "ASM_REP_N1_TO_N254", "ASM_PUB_N1",
                     "ASM_FIRST_N254_TO_N1"):  # fmt: skip
        assert expected in names, sorted(names)
    heartbeat = names["ASM_HEARTBEAT_N1"][0]
    assert bytes(heartbeat[f"name_{k}"] for k in range(8) if f"name_{k}" in heartbeat) == b"m1"
    estop = names["ASM_ESTOP_N254"][0]
    assert bytes(estop[f"reason_{k}"] for k in range(8) if f"reason_{k}" in estop) == b"test"
    angles = [d["joint_angle"] for d in names["ASM_PUB_N1"] if d["class_id"] == 0x11]
    assert angles and all(isinstance(a, float) for a in angles) and max(angles) > 5.0  # float32, decoded as float
    states = [d["gait_state"] for d in names["ASM_PUB_N1"] if d["class_id"] == 0x23]
    assert states and set(states) <= {0, 1}  # uint16, the automaton's two states
    sets = [d for d in names["ASM_REQ_N254_TO_N1"] if d["method"] == "SET" and d["class_id"] == 0x10]
    assert sets and sets[0]["joint_goal"] == 12.5
    assert all(d["status"] == "OK" for d in names["ASM_REP_N1_TO_N254"])
    lengths = {first["message_length"] for first in names["ASM_FIRST_N254_TO_N1"]}
    assert 4 + 5 + 2 * 9 in lengths  # the gait table's set: header, table header, two states


def test_the_dbc_value_types_are_the_module_objects_codecs() -> None:
    """CLASS_CODECS is what a module runtime registers, class by class (so the DBC cannot drift from the modules)."""
    node = Node("m1", CanTransport(1, interface="virtual", channel=fresh_name("asm-dbc-codecs")))
    runtime = ModuleRuntime(FakeDriver(), node=node)
    try:
        for class_name, spec in dbc.CLASS_CODECS.items():
            assert node.entry(class_name).codec.spec == spec, class_name
    finally:
        runtime.close()
        node.close()


def test_dbc_cli_writes_a_file_cantools_loads(tmp_path: Path) -> None:
    out = tmp_path / "asm.dbc"
    assert dbc.main(["--nodes", "1", "--tool", "254", "-o", str(out)]) == 0  # the text the fixture loaded: cached
    db = cantools.database.load_file(out)
    names = {m.name for m in db.messages}
    assert {"ASM_PUB_N1", "ASM_REQ_N254_TO_N1", "ASM_REP_N1_TO_N254", "ASM_ESTOP_N254", "ASM_FIRST_N254_TO_N1"} <= names
    assert {"ASM_HEARTBEAT_N200", "ASM_LEAVE_N200", "ASM_ESTOP_N0", "ASM_GROUP17_N254"} <= names


def test_dbc_cli_node_lists() -> None:
    assert dbc._ids("1-3,7") == [1, 2, 3, 7] and dbc._ids("4,1-2") == [1, 2, 4]


def test_worst_case_frame_lengths_and_bus_load() -> None:
    assert busload.classic_frame_bits(8, extended=False) == 135  # the textbook figures
    assert busload.classic_frame_bits(8) == 160 and busload.classic_frame_bits(0) == 80
    load = busload.bus_load([(8, 100 * 50)], 1_000_000)  # 100 modules publishing a float32 (8-byte frame) at 50 Hz
    assert load == pytest.approx(0.8)
    fd = busload.bus_load([(64, 1000)], 1_000_000, fd=True, data_bitrate=5_000_000)
    assert 0.15 < fd < busload.bus_load([(8, 8000)], 1_000_000)  # 512 bytes/ms: FD beats eight classic frames
    with pytest.raises(ValueError):
        busload.classic_frame_bits(9)


def test_busload_cli() -> None:
    out = subprocess.run([sys.executable, "-m", "asm_py.canbus.busload", "--bitrate", "1000000", "8x5000"],
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert out.returncode == 0 and "bus load 80.0%" in out.stdout
    over = subprocess.run([sys.executable, "-m", "asm_py.canbus.busload", "--bitrate", "125000", "8x5000"],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert over.returncode == 1 and "640.0%" in over.stdout
