"""Commissioning in C (firmware/src/commission.c) and on the board (firmware/port/stm32f4_bxcan.c in the emulator):
the golden vectors against the host build and the board image, boards found and numbered by their unique IDs, the
ID kept in the settings flash sector across a power cycle, a shared ID reported; and the flash interface model."""

from __future__ import annotations

import ctypes
import json
import os
import shutil
import time
from pathlib import Path

import can
import pytest

from asm_module.emulated import EmulatedModule
from asm_module.firmware_build import build_library
from asm_module.flash import (
    BASE,
    CR,
    KEYR,
    KEYS,
    OPTCR,
    OPTKEYR,
    OPTKEYS,
    PG,
    PGPERR,
    PGSERR,
    SECTOR_ADDRESS,
    SECTORS,
    SER,
    SR,
    STRT,
    WRPERR,
    FlashInterface,
    Settings,
)
from asm_py.canbus.commission import SERIAL_BYTES, Commissioner, CommissionScope, conflicts, parse_reply
from asm_py.node import Node
from asm_py.remote import RemoteAttribute
from asm_py.transport.can import CanTransport

from ..helpers import wait_until
from ..transports import fresh_name

needs_arm_gcc = pytest.mark.skipif(
    shutil.which("arm-none-eabi-gcc") is None, reason="the board image needs arm-none-eabi-gcc (make test installs it)"
)
pytestmark = [pytest.mark.timeout(180)]
CASES = json.loads((Path(__file__).resolve().parents[1] / "vectors" / "commissioning.json").read_text())["cases"]


class _Commission(ctypes.Structure):
    _fields_ = [("serial", ctypes.c_uint8 * SERIAL_BYTES), ("node_id", ctypes.c_uint8), ("position", ctypes.c_uint8),
                ("muted", ctypes.c_uint8)]  # fmt: skip


@pytest.mark.parametrize("case", CASES, ids=lambda c: c["name"])
def test_golden_vectors_against_the_c_runtime(case: dict) -> None:
    lib = ctypes.CDLL(str(build_library()))
    state = _Commission()
    lib.asm_commission_init(ctypes.byref(state), bytes.fromhex(case["serial"]), case["node_id"])
    stored: list[int] = []

    def keep(_: object, node_id: int) -> int:
        stored.append(node_id)
        return 0

    store = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_uint8)(keep)
    answer = ctypes.c_uint32()
    for step in case["steps"]:
        data = bytes.fromhex(step["command"]["data"])
        assert lib.asm_commission_is_command(int(step["command"]["id"], 16)) == 1
        answered = lib.asm_commission_command(ctypes.byref(state), data, len(data), store, None, ctypes.byref(answer))
        assert (f"{answer.value:08x}" if answered else None) == step["answer"], step
    assert stored == [int(s["command"]["data"][2:4], 16) for s in case["steps"]
                      if s["command"]["data"].startswith("03") and s["answer"]]  # fmt: skip


# -- the flash interface ---------------------------------------------------------------------------------------


def _unlocked(settings: Settings) -> FlashInterface:
    flash = FlashInterface(settings)
    for key in KEYS:
        flash.write_register(KEYR, key)
    return flash


def test_flash_programs_only_unlocked_with_pg_and_only_clears_bits(tmp_path) -> None:
    settings = Settings(tmp_path / "settings.bin")
    at = SECTOR_ADDRESS - BASE  # the settings sector, as the interface addresses it (from 0x08000000)
    locked = FlashInterface(settings)
    locked.write(at, 4, 0x12345678)
    assert locked.read(at, 4) == 0xFFFFFFFF and locked.read_register(SR) & PGSERR  # locked: nothing programmed
    flash = _unlocked(settings)
    flash.write(at, 4, 0x12345678)
    assert flash.read(at, 4) == 0xFFFFFFFF and flash.read_register(SR) & PGSERR  # unlocked but PG clear
    flash.write_register(SR, 0xF3)
    flash.write_register(CR, 2 << 8 | PG)  # PSIZE x32
    flash.write(at + 4, 2, 0)
    assert flash.read_register(SR) & PGPERR and flash.read(at + 4, 4) == 0xFFFFFFFF  # a half-word under PSIZE x32
    flash.write(at, 4, 0x12345678)
    flash.write(at, 4, 0xFFFF00FF)  # programming clears bits, never sets one
    assert flash.read(at, 4) == 0x12340078
    assert Settings(tmp_path / "settings.bin").data[:4] == (0x12340078).to_bytes(4, "little")  # kept in the file
    flash.write_register(CR, 2 << 8 | 11 << 3 | SER | STRT)
    assert flash.read(at, 4) == 0xFFFFFFFF and settings.erases == 1


def test_write_protected_sectors_refuse_erase_and_program(tmp_path) -> None:
    """The option bytes' nWRP (RM0090 §3.7.3), as the bootloader sets them over itself and the running image's slot:
    WRPERR and nothing changed; kept across power cycles (in the file too); other sectors still work."""
    settings = Settings(tmp_path / "flash.bin")
    flash = _unlocked(settings)
    slot = SECTORS[5][0]
    flash.write_register(CR, 2 << 8 | PG)
    flash.write(slot, 4, 0x11223344)
    flash.write_register(OPTCR, 0x0FFFAAEC)  # still locked: ignored
    assert not settings.protected(5)
    for key in OPTKEYS:
        flash.write_register(OPTKEYR, key)
    flash.write_register(OPTCR, (0xFFF & ~(1 << 5)) << 16 | 2)  # nWRP5 = 0, OPTSTRT
    assert settings.protected(5) and Settings(tmp_path / "flash.bin").protected(5)
    flash.write(slot + 4, 4, 0)
    assert flash.read_register(SR) & WRPERR and flash.read(slot + 4, 4) == 0xFFFFFFFF, "program refused"
    flash.write_register(SR, 0xF3)
    flash.write_register(CR, 2 << 8 | 5 << 3 | SER | STRT)
    assert flash.read_register(SR) & WRPERR and flash.read(slot, 4) == 0x11223344, "erase refused"
    flash.write_register(CR, 2 << 8 | 6 << 3 | SER | STRT)  # the other slot: erased
    assert settings.erases == 1
    flash.write_register(CR, 2 << 8 | 12 << 3 | SER | STRT)  # no sector 12 on an STM32F405
    assert flash.read_register(SR) & PGSERR


# -- the board --------------------------------------------------------------------------------------------------


@pytest.fixture
def channel():
    return fresh_name("board-commission")


def _boards(channel: str, serials: list[bytes], settings: list[Settings], node_ids: list[int] | None = None):
    boards: list[EmulatedModule] = []
    try:
        for k, (serial, sector) in enumerate(zip(serials, settings, strict=True)):
            node_id = node_ids[k] if node_ids else 0
            boards.append(EmulatedModule(f"m{node_id}" if node_id else "", node_id, serial=serial, settings=sector,
                                         interface="asm_sim", channel=channel))  # fmt: skip
    except BaseException:
        for board in boards:
            board.close()
        raise
    return boards


@needs_arm_gcc
@pytest.mark.parametrize("case", CASES, ids=lambda c: c["name"])
def test_golden_vectors_against_the_board_image(case: dict, channel) -> None:
    """Each command frame on the bus gets the stated answer frame from the board, or none within 0.2 s."""
    serial = bytes.fromhex(case["serial"])
    (board,) = _boards(channel, [serial], [Settings()], [case["node_id"]] if case["node_id"] else None)
    bus = can.Bus(interface="asm_sim", channel=channel)
    try:
        for step in case["steps"]:
            while bus.recv(timeout=0) is not None:
                pass
            bus.send(can.Message(arbitration_id=int(step["command"]["id"], 16), is_extended_id=True,
                                 data=bytes.fromhex(step["command"]["data"])))  # fmt: skip
            got = None
            deadline = time.monotonic() + (5.0 if step["answer"] else 0.2)
            while got is None and (left := deadline - time.monotonic()) > 0:
                frame = bus.recv(timeout=left)
                if frame is not None and parse_reply(frame) is not None:
                    got = f"{frame.arbitration_id:08x}"
                    assert not frame.data
            assert got == step["answer"], step
    finally:
        bus.shutdown()
        board.close()


@needs_arm_gcc
def test_boards_are_numbered_keep_their_ids_across_a_power_cycle_and_answer_under_them(channel) -> None:
    serials = [os.urandom(SERIAL_BYTES) for _ in range(4)]
    settings = [Settings() for _ in serials]
    boards = _boards(channel, serials, settings)
    bus = can.Bus(interface="asm_sim", channel=channel)
    try:
        assert not any(board.configured for board in boards)
        tool = Commissioner(bus, window=0.3)  # boards in real time lag the wall clock on a busy machine
        assigned = tool.number(first=10, order=[serials[2]])
        by_serial = {m.serial: m.node_id for m in assigned}
        assert by_serial[serials[2]] == 10 and sorted(by_serial.values()) == [10, 11, 12, 13]
        assert [board.commissioned_id() for board in boards] == [by_serial[s] for s in serials]
        assert all(board.configured for board in boards)
        # a record is two words, appended (an ASSIGN the tool repeated is one more): no erase
        assert all(sector.erases == 0 and sector.programs >= 2 and sector.programs % 2 == 0 for sector in settings)
        for board in boards:
            board.close()
        boards = _boards(channel, serials, settings)  # power cycled: the same settings sectors
        assert [board.commissioned_id() for board in boards] == [by_serial[s] for s in serials]
        assert {m.serial: m.node_id for m in tool.discover(CommissionScope.EVERY)} == by_serial
        tool_bus = can.Bus(interface="asm_sim", channel=channel)
        node = Node("tool", CanTransport(250, bus=tool_bus))
        try:
            name = f"m{by_serial[serials[2]]}"
            assert wait_until(lambda: name in node.transport.peers(), timeout=10)  # a commissioned board is m<ID>
            limits = node.lookup(name, "joint.limits", timeout=2)
            assert isinstance(limits, RemoteAttribute) and tuple(limits.peek()) == (-90.0, 90.0)
        finally:
            node.close()
            tool_bus.shutdown()
    finally:
        bus.shutdown()
        for board in boards:
            board.close()


@needs_arm_gcc
def test_a_full_settings_sector_is_erased_and_two_boards_with_one_id_are_reported(channel) -> None:
    full = Settings()
    record = (0x41534D31).to_bytes(4, "little") + (0xA55A0000 | 0xFC << 8 | 3).to_bytes(4, "little")  # ID 3
    full.data[:] = record * (len(full.data) // 8)
    serials = [os.urandom(SERIAL_BYTES) for _ in range(2)]
    boards = _boards(channel, serials, [full, Settings()], [0, 3])  # the first from its settings, the second flashed
    bus = can.Bus(interface="asm_sim", channel=channel)
    try:
        assert [board.commissioned_id() for board in boards] == [3, 3]
        tool = Commissioner(bus, window=0.3)  # boards in real time lag the wall clock on a busy machine
        clash = conflicts(tool.discover(CommissionScope.EVERY))
        assert list(clash) == [3] and sorted(clash[3]) == sorted(serials)
        with pytest.raises(ValueError, match="node ID 3 is held by 2 modules"):
            tool.number()
        tool.assign(serials[0], 8)  # the log is full: the sector is erased and the record written at its start
        assert full.erases == 1 and boards[0].commissioned_id() == 8
        assert full.data[:8] == (0x41534D31).to_bytes(4, "little") + (0xA55A0000 | 0xF7 << 8 | 8).to_bytes(4, "little")
        assert conflicts(tool.discover(CommissionScope.EVERY)) == {}
    finally:
        bus.shutdown()
        for board in boards:
            board.close()
