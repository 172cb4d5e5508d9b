"""What CAN users expect around the transport: python-can log files that replay, a DBC that cantools decodes
recorded traffic with, and a bus-load calculator (function and CLI)."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import can
import cantools
import pytest

from asm_py import Attribute
from asm_py.canbus import busload, dbc
from asm_py.canbus.ids import CanId, Dest, Priority
from asm_py.node import Node
from asm_py.transport.can import CanTransport

from .helpers import wait_until
from .transports import fresh_name


def record_session(path: Path) -> list[float]:
    """A module (ID 1) publishing its angle, a tool (ID 2) setting and reading it; the tool records the bus."""
    channel = fresh_name("asm-rec")
    module = Node("m1", CanTransport(1, interface="virtual", channel=channel, heartbeat_period=0.05))
    tool = Node("tool", CanTransport(2, interface="virtual", channel=channel, heartbeat_period=0.05, record=path))
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


def test_cantools_decodes_a_recorded_log_with_the_generated_dbc(tmp_path: Path) -> None:
    path = tmp_path / "session.asc"
    values = record_session(path)
    db = cantools.database.load_string(dbc.generate([1], tool=2), "dbc")
    seen: list[float] = []
    for frame in can.LogReader(path):
        cid = CanId.unpack(frame.arbitration_id)
        if cid.source == 1 and cid.priority == Priority.PUBLICATION and cid.dest_kind == Dest.BROADCAST:
            decoded = db.decode_message(frame.arbitration_id, bytes(frame.data), allow_truncated=True)
            assert decoded["class_id"] == 0x11 and decoded["kind"] == 3
            seen.append(decoded["joint_angle"])
    assert seen[: len(values) - 1] == values[:-1]
    request = next(f for f in can.LogReader(path) if bytes(f.data[4:8]) == struct.pack("<f", 1.5))
    assert db.decode_message(request.arbitration_id, bytes(request.data))["joint_angle"] == 1.5


def test_dbc_cli_writes_a_file_cantools_loads(tmp_path: Path) -> None:
    out = tmp_path / "asm.dbc"
    assert dbc.main(["--nodes", "1-3,7", "--tool", "254", "-o", str(out)]) == 0
    db = cantools.database.load_file(out)
    names = {m.name for m in db.messages}
    assert {"ASM_PUB_N1", "ASM_PUB_N7", "ASM_REQ_N254_TO_N3", "ASM_REP_N2_TO_N254", "ASM_ESTOP_N254"} <= names


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
