"""The bad days: frames dropped, duplicated, reordered and corrupted between a tool and a module on CAN.

Every call either succeeds or raises within its deadline; no thread hangs (the suite's leak check runs after each
test); the reassembly buffers stay bounded and drain once the faults stop.
"""

from __future__ import annotations

import time

import can
import pytest

from asm_py import AsmError, Attribute
from asm_py.canbus.faults import FaultyBus
from asm_py.node import Node
from asm_py.transport.can import CanTransport

from ..helpers import wait_until
from ..transports import fresh_name

CALL_TIMEOUT = 0.3
MARGIN = 1.0


def faulty_pair(**faults):
    channel = fresh_name("asm-faults")
    buses = [FaultyBus(can.Bus(interface="virtual", channel=channel), seed=i, **faults) for i in (1, 2)]
    options = {"heartbeat_period": 0.05, "missed_heartbeats": 20, "reassembly_timeout": 0.3}
    module = Node("m1", CanTransport(1, bus=buses[0], **options))
    tool = Node("tool", CanTransport(2, bus=buses[1], **options), call_timeout=CALL_TIMEOUT)
    return module, tool, buses


def exercise(tool: Node, calls: int, allowed: tuple[type[BaseException], ...]) -> dict[str, int]:
    """Gets and sets, small and fragmented, each within its deadline; returns the outcome counts."""
    remote = {}
    while len(remote) < 2:
        for name in ("joint.angle", "gait.table"):
            try:
                remote.setdefault(name, tool.lookup("m1", name, timeout=1.0))
            except TimeoutError:
                pass
    outcomes = {"ok": 0, "timeout": 0, "other": 0}
    table = bytes(range(100))
    operations = [
        lambda: remote["joint.angle"].get(),
        lambda: remote["joint.angle"].set(1.5, wait=True),
        lambda: remote["gait.table"].set(table, wait=True),
        lambda: remote["gait.table"].peek(),
    ]
    for i in range(calls):
        began = time.monotonic()
        try:
            operations[i % len(operations)]()
            outcomes["ok"] += 1
        except TimeoutError:
            outcomes["timeout"] += 1
        except allowed:
            outcomes["other"] += 1
        assert time.monotonic() - began <= CALL_TIMEOUT + MARGIN, f"call {i} overran its deadline"
    return outcomes


@pytest.mark.parametrize(
    "faults",
    [
        {"drop": 0.05},
        {"duplicate": 0.1},
        {"reorder": 0.05},
        {"drop": 0.03, "duplicate": 0.03, "reorder": 0.03},
    ],
    ids=["drop", "duplicate", "reorder", "mixed"],
)
def test_calls_succeed_or_time_out_within_their_deadline(faults) -> None:
    module, tool, buses = faulty_pair(**faults)
    try:
        module.register(Attribute("joint.angle", 0.5, codec="float32"))
        module.register(Attribute("gait.table", b"", codec="bytes"))
        outcomes = exercise(tool, 24, allowed=())
        assert outcomes["ok"] > 0 and outcomes["other"] == 0
        injected = sum(sum(b.counts.values()) for b in buses)
        assert injected > 0, "the faults were never injected"
        for node in (module, tool):
            reassembler = node.transport.reassembler  # type: ignore[attr-defined]
            assert reassembler.buffered_bytes <= reassembler.bound
        for bus in buses:
            bus.drop = bus.duplicate = bus.reorder = 0.0
        assert wait_until(lambda: all(n.transport.reassembler.partials == 0 for n in (module, tool)), timeout=5)  # type: ignore[attr-defined]
        assert tool.lookup("m1", "joint.angle", timeout=2).get() in (0.5, 1.5)
    finally:
        tool.close()
        module.close()
        for bus in buses:
            bus.shutdown()  # the caller owns a bus it hands to a transport (python-can's convention)


def test_corrupted_frames_end_in_a_result_or_a_documented_error() -> None:
    """Bit flips (which a real bus's CRC would catch) never hang a call or escape as an undocumented error."""
    module, tool, buses = faulty_pair(corrupt=0.05)
    try:
        module.register(Attribute("joint.angle", 0.5, codec="float32"))
        module.register(Attribute("gait.table", b"", codec="bytes"))
        outcomes = exercise(tool, 24, allowed=(LookupError, ValueError, TypeError, AsmError))
        assert outcomes["ok"] > 0 and sum(b.counts["corrupted"] for b in buses) > 0
        crc = sum(n.transport.reassembler.dropped.get("crc mismatch", 0) for n in (module, tool))  # type: ignore[attr-defined]
        gaps = sum(n.transport.reassembler.dropped.get("fragment gap", 0) for n in (module, tool))  # type: ignore[attr-defined]
        assert crc + gaps + outcomes["timeout"] + outcomes["other"] > 0
    finally:
        tool.close()
        module.close()
        for bus in buses:
            bus.shutdown()  # the caller owns a bus it hands to a transport (python-can's convention)
