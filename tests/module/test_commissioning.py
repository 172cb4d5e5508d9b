"""Commissioning (docs/protocol.md §7): modules without node IDs found by their serials and numbered over the bus;
IDs kept across a reset; a shared ID reported."""

from __future__ import annotations

import json
import random
import signal
import subprocess
import sys
from pathlib import Path

import can
import pytest

from asm_module.commissioning import CommissionedModule, Fleet, IdFile
from asm_py import Node
from asm_py.canbus.commission import (
    SERIAL_BYTES,
    Answer,
    Commissionee,
    Commissioner,
    CommissionOp,
    CommissionReply,
    CommissionScope,
    command_frame,
    conflicts,
    parse_reply,
    reply_frame,
)
from asm_py.canbus.faults import FaultyBus
from asm_py.remote import RemoteAttribute
from asm_py.transport.can import CanTransport
from server.commission import main as commission_main
from tests.helpers import wait_until
from tests.transports import fresh_name

pytestmark = pytest.mark.timeout(120)
VECTORS = Path(__file__).resolve().parents[1] / "vectors" / "commissioning.json"


@pytest.fixture
def channel():
    return fresh_name("commission")


@pytest.fixture
def tool_bus(channel):
    bus = can.Bus(interface="asm_sim", channel=channel)
    yield bus
    bus.shutdown()


def write_ids(directory: Path, node_ids: list[int], rng: random.Random) -> list[bytes]:
    """ID files for modules with random serials and the given IDs (0: none); their serials."""
    serials = [rng.randbytes(SERIAL_BYTES) for _ in node_ids]
    for k, (serial, node_id) in enumerate(zip(serials, node_ids, strict=True)):
        (directory / f"module{k}.json").write_text(json.dumps({"serial": serial.hex(), "node_id": node_id}))
    return serials


# -- the protocol: the golden vectors, and a module's state machine --------------------------------------------


@pytest.mark.parametrize("case", json.loads(VECTORS.read_text())["cases"], ids=lambda c: c["name"])
def test_golden_vectors(case: dict) -> None:
    """Each command frame, given to a module with the case's serial and ID, gets exactly the stated answer frame."""
    module = Commissionee(bytes.fromhex(case["serial"]), case["node_id"])
    for step in case["steps"]:
        frame = can.Message(arbitration_id=int(step["command"]["id"], 16), data=bytes.fromhex(step["command"]["data"]),
                            is_extended_id=True)  # fmt: skip
        answer = module.command(bytes(frame.data))
        got = None if answer is None else f"{reply_frame(answer).arbitration_id:08x}"
        assert got == step["answer"], step


def test_frames_are_what_the_vectors_say() -> None:
    """The frame builders agree with the vectors' identifiers (a tool built from the contract sends these)."""
    cases = json.loads(VECTORS.read_text())["cases"]
    scan = cases[0]["steps"][0]["command"]
    frame = command_frame(CommissionOp.SCAN, CommissionScope.UNCONFIGURED, 0)
    assert (f"{frame.arbitration_id:08x}", bytes(frame.data).hex()) == (scan["id"], scan["data"])
    assert parse_reply(reply_frame(Answer(CommissionReply.BYTE, 0x3A, 11))) == (CommissionReply.BYTE, 0x3A, 11)
    assert parse_reply(frame) is None


def test_a_module_out_of_scope_or_muted_stays_silent() -> None:
    serial = bytes(range(SERIAL_BYTES))
    module = Commissionee(serial, 5)
    assert module.command(bytes((CommissionOp.SCAN, CommissionScope.UNCONFIGURED, 0))) is None
    assert module.command(bytes((CommissionOp.SCAN, CommissionScope.NODE_ID, 6))) is None
    assert module.command(bytes((CommissionOp.SCAN, CommissionScope.NODE_ID, 5))) == Answer(CommissionReply.BYTE, 0)
    answer = None
    for at in range(SERIAL_BYTES):
        answer = module.command(bytes((CommissionOp.NARROW, at, serial[at])))
    assert answer == Answer(CommissionReply.FOUND, 5)
    assert module.command(bytes((CommissionOp.MUTE,))) == Answer(CommissionReply.MUTED, 5)
    assert module.command(bytes((CommissionOp.SCAN, CommissionScope.EVERY, 0))) is None  # muted
    module.command(bytes((CommissionOp.UNMUTE,)))
    assert module.command(bytes((CommissionOp.SCAN, CommissionScope.EVERY, 0))) == Answer(CommissionReply.BYTE, 0)
    assert module.command(bytes((CommissionOp.NARROW, 0, 1))) is None  # another serial's byte: out of the scan
    assert module.command(bytes((CommissionOp.NARROW, 1, 1))) is None


def test_id_file_keeps_the_serial_and_the_id(tmp_path) -> None:
    first = IdFile(tmp_path / "m.json")
    first.save(9)
    again = IdFile(tmp_path / "m.json")
    assert (again.serial, again.node_id) == (first.serial, 9)
    with pytest.raises(ValueError, match="holds serial"):
        IdFile(tmp_path / "m.json", serial=bytes(SERIAL_BYTES))


# -- on a bus ------------------------------------------------------------------------------------------------------


def test_24_modules_are_found_numbered_and_keep_their_ids_across_a_reset(tmp_path, channel, tool_bus) -> None:
    fleet = Fleet(tmp_path, 24, channel)
    try:
        tool = Commissioner(tool_bus)
        serials = {m.serial for m in fleet.modules}
        assert len(tool.discover(CommissionScope.EVERY)) == 24
        assigned = tool.number(first=3)
        assert {m.serial for m in assigned} == serials
        assert sorted(m.node_id for m in assigned) == list(range(3, 27))
        assert [m.serial for m in assigned] == sorted(serials)  # no order given: serial order
        by_serial = {m.serial: m.node_id for m in assigned}
        assert {m.serial: m.node_id for m in fleet.modules} == by_serial
        fleet.reset()
        assert {m.serial: m.node_id for m in fleet.modules} == by_serial  # from the files, after the power cycle
        roster = tool.discover(CommissionScope.EVERY)
        assert {m.serial: m.node_id for m in roster} == by_serial  # and as the bus tells it
        assert tool.number() == []  # nobody left to number
        # the modules run under their IDs: a tool reaches m<ID> by its name
        bus = can.Bus(interface="asm_sim", channel=channel)
        node = Node("tool", CanTransport(250, bus=bus, heartbeat_period=0.2))
        try:
            some = sorted(by_serial.values())[::8]
            for node_id in some:
                assert wait_until(lambda n=node_id: f"m{n}" in node.transport.peers(), timeout=10)
                limits = node.lookup(f"m{node_id}", "joint.limits", timeout=2)
                assert isinstance(limits, RemoteAttribute) and tuple(limits.peek()) == (-90.0, 90.0)
        finally:
            node.close()
            bus.shutdown()
    finally:
        fleet.close()


def test_numbering_follows_the_order_given_and_skips_ids_in_use(tmp_path, channel, tool_bus) -> None:
    serials = write_ids(tmp_path, [0, 0, 2, 0], random.Random(5))
    fleet = Fleet(tmp_path, 4, channel)
    try:
        order = [serials[3], serials[0]]
        assigned = Commissioner(tool_bus).number(first=1, order=order)
        assert [(m.serial, m.node_id) for m in assigned] == [(serials[3], 1), (serials[0], 3), (serials[1], 4)]
    finally:
        fleet.close()


def test_two_modules_with_one_id_are_reported_and_nothing_is_numbered(tmp_path, channel, tool_bus) -> None:
    serials = write_ids(tmp_path, [5, 5, 6, 0], random.Random(7))
    fleet = Fleet(tmp_path, 4, channel)
    try:
        tool = Commissioner(tool_bus)
        roster = tool.discover(CommissionScope.EVERY)
        assert conflicts(roster) == {5: sorted(serials[:2], key=[m.serial for m in roster].index)}
        with pytest.raises(ValueError, match=f"node ID 5 is held by 2 modules: .*{serials[0].hex()}"):
            tool.number()
        assert fleet.modules[3].node_id == 0  # refused before anything was assigned
        same = tool.discover(CommissionScope.NODE_ID, 5)  # the scope of one ID finds both
        assert {m.serial for m in same} == set(serials[:2])
    finally:
        fleet.close()


def test_lost_frames_are_asked_again(tmp_path, channel) -> None:
    """A tool behind a bus that drops a tenth of the frames both ways still finds and numbers every module."""
    fleet = Fleet(tmp_path, 6, channel)
    bus = FaultyBus(can.Bus(interface="asm_sim", channel=channel), seed=3, drop=0.1)
    try:
        assigned = Commissioner(bus, window=0.03, retries=6).number()
        assert sorted(m.node_id for m in assigned) == list(range(1, 7))
        assert {m.serial: m.node_id for m in fleet.modules} == {m.serial: m.node_id for m in assigned}
    finally:
        bus.shutdown()
        fleet.close()


def test_a_reassigned_module_moves_to_its_new_id_and_erase_unconfigures(tmp_path, channel, tool_bus) -> None:
    identity = IdFile(tmp_path / "m.json")
    identity.save(4)
    module = CommissionedModule(identity, lambda: can.Bus(interface="asm_sim", channel=channel),
                                heartbeat_period=0.2)  # fmt: skip
    try:
        assert module.node is not None and module.node.name == "m4"
        tool = Commissioner(tool_bus)
        tool.assign(module.serial, 9)
        assert module.node is not None and module.node.name == "m9"
        assert IdFile(tmp_path / "m.json").node_id == 9
        tool.assign(module.serial, 0)
        assert module.node is None and module.node_id == 0
        with pytest.raises(LookupError, match="did not answer"):
            Commissioner(tool_bus, window=0.01, retries=0).assign(bytes(SERIAL_BYTES), 3)
    finally:
        module.close()


def test_the_command_line(tmp_path, channel, capsys) -> None:
    serials = write_ids(tmp_path, [0, 0, 7], random.Random(11))
    order = tmp_path / "chain.txt"
    order.write_text(f"# along the chain\n{serials[1].hex()}\n{serials[0].hex()}\n")
    fleet = Fleet(tmp_path, 3, channel)
    bus = ["--can", f"asm_sim:{channel}"]
    try:
        assert commission_main([*bus, "number", "--order", str(order)]) == 0
        assert capsys.readouterr().out.split() == [serials[1].hex(), "1", serials[0].hex(), "2"]
        assert commission_main([*bus, "set", serials[2].hex(), "7"]) == 0
        assert commission_main([*bus, "erase", serials[0].hex()]) == 0
        capsys.readouterr()
        assert commission_main([*bus, "list"]) == 0
        out = capsys.readouterr().out
        assert f"{serials[1].hex()}  1" in out and f"{serials[0].hex()}  -" in out and "1 without a node ID" in out
        # a review: set gave an ID another module holds (a conflict made by the tool itself) and the tools' 254
        assert commission_main([*bus, "set", serials[1].hex(), "7"]) == 1
        assert f"node ID 7 is held by module {serials[2].hex()}: IDs are never shared" in capsys.readouterr().err
        assert commission_main([*bus, "--node-id", "9", "set", serials[1].hex(), "9"]) == 1
        assert "this tool's own" in capsys.readouterr().err
        assert commission_main([*bus, "list"]) == 0, "no conflict made"
        for argv in (["set", "12ab", "3"], ["set", serials[1].hex(), "254"], ["set", serials[1].hex(), "0"]):
            with pytest.raises(SystemExit) as ended:
                commission_main([*bus, *argv])  # not a serial, the tools' ID, none: a usage error
            assert ended.value.code == 2
        bad = tmp_path / "bad-order.txt"
        bad.write_text("nothex\n")
        with pytest.raises(SystemExit) as ended:
            commission_main([*bus, "number", "--order", str(bad)])
        err = capsys.readouterr().err
        assert ended.value.code == 2 and "--order" in err and "Traceback" not in err
    finally:
        fleet.close()


def test_the_command_line_changes_no_id_while_a_module_is_latched_or_walks(tmp_path, channel, capsys) -> None:
    """Issue 28's third review: asm-commission set/erase reset a latched board (its latch released) or a walking one
    (its joint dropped mid-step), as the robot's commissioning service and a firmware update no longer do."""
    serials = write_ids(tmp_path, [0, 7], random.Random(12))
    fleet = Fleet(tmp_path, 2, channel)
    bus = ["--can", f"asm_sim:{channel}"]
    tool = Node("latcher", CanTransport(100, interface="asm_sim", channel=channel))
    try:
        assert wait_until(lambda: "m7" in tool.discover(), timeout=20)
        estop = tool.lookup("m7", "estop", timeout=5)
        estop.set(True, timeout=5)  # type: ignore[attr-defined]
        for argv in (["set", serials[1].hex(), "3"], ["erase", serials[1].hex()], ["number"]):
            assert commission_main([*bus, *argv]) == 1, argv
            err = capsys.readouterr().err
            assert "refused: the robot's e-stop is latched (m7); an ID given or erased resets the board" in err, err
        estop.set(False, timeout=5)  # type: ignore[attr-defined]
        service = tool.lookup("m7", "gait.service", timeout=5)
        service.start()  # type: ignore[attr-defined]
        assert wait_until(lambda: service.running, timeout=10)  # type: ignore[attr-defined]
        assert commission_main([*bus, "erase", serials[1].hex()]) == 1
        assert "refused: a gait runs on m7; " in capsys.readouterr().err
        capsys.readouterr()
        assert commission_main([*bus, "list"]) == 0
        out = capsys.readouterr().out
        assert f"{serials[1].hex()}  7" in out and f"{serials[0].hex()}  -" in out, "nothing changed"
        service.stop()  # type: ignore[attr-defined]
        assert wait_until(lambda: not service.running, timeout=10)  # type: ignore[attr-defined]
        assert commission_main([*bus, "number", "--first", "1"]) == 0, "stopped and released: it goes ahead"
    finally:
        tool.close()
        fleet.close()


def test_asm_module_with_an_id_file_boots_unconfigured_and_keeps_its_serial(tmp_path) -> None:
    """``asm-module --id-file``: the file is made with a random serial and no ID, the module says so when ready,
    and a second start reads the same serial (and the ID the file holds)."""
    path = tmp_path / "m.json"
    command = [sys.executable, "-m", "server.module", "--can", "virtual:id-file", "--id-file", str(path)]

    def ready_line() -> str:
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert process.stdout is not None
            line = process.stdout.readline()
        finally:
            process.send_signal(signal.SIGTERM)
            _, err = process.communicate(timeout=30)
        assert process.returncode == 0, err[-2000:]
        return line.strip()

    first = ready_line()
    serial = json.loads(path.read_text())["serial"]
    assert first == f"READY serial {serial} node ID none"
    IdFile(path).save(12)
    assert ready_line() == f"READY serial {serial} node ID 12"
