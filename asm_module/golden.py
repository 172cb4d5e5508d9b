"""The golden vectors of tests/vectors/ as the C firmware's vector runner (firmware/tests/vectors.c) reads them, and
their replay against a C module on a bus: what the test suite and bench/firmware.py both check, written once.

Each ``*_lines`` function turns one vector file into the runner's input lines; :func:`reproduce_module_object_vectors`
plays tests/vectors/module_objects.json against a running :class:`~asm_module.c_module.CModule`.
"""

from __future__ import annotations

import json
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can

from asm_py.canbus.ids import CanId

from .c_module import CModule

VECTORS = Path(__file__).resolve().parent.parent / "tests" / "vectors"


def message_lines() -> list[str]:
    lines = []
    for case in json.loads((VECTORS / "messages.json").read_text())["messages"]:
        m = case["message"]
        timeout = -1 if m["timeout"] is None else m["timeout"]
        status = m["status"] if m["kind"] == 2 else 0
        lines.append(f"MSG {case['hex']} {m['kind']} {m['method']} {m['txn']} {m['class_id'] if m['kind'] != 2 else 0} "
                     f"{status} {m['object_id']} {timeout}")  # fmt: skip
    return lines


def can_vector_lines() -> list[str]:
    lines = []
    for case in json.loads((VECTORS / "can_frames.json").read_text())["frames"]:
        frames = " ".join(f"{f['id']}:{f['data'] or '-'}" for f in case["frames"])
        lines.append(f"CAN {int(case['fd'])} {case['priority']} {case['dest_kind']} {case['dest']} {case['source']} "
                     f"{case['message_hex'] or '-'} {frames}")  # fmt: skip
    return lines


def _varint(data: bytes, at: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[at]
        at += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, at


def _tokens(descriptor: bytes, at: int, value: Any) -> tuple[list[str], int]:
    """The C runner's tokens for ``value`` of the codec at ``descriptor[at]``: one per scalar, text as hex.
    ``value`` is JSON from the vectors file, so its type is the descriptor's to say, not the checker's."""
    tag = descriptor[at]
    at += 1
    if tag == 0x01:
        return ["1" if value else "0"], at
    if 0x02 <= tag <= 0x09:
        return [str(int(value))], at
    if tag in (0x0A, 0x0B):
        return [repr(float(value))], at
    if tag in (0x0C, 0x0D):
        _, at = _varint(descriptor, at)
        raw = value.encode("utf-8") if tag == 0x0C else bytes.fromhex(value)
        return [raw.hex() or "-"], at
    if tag == 0x10:
        return [json.dumps(value, separators=(",", ":")).encode().hex()], at
    if tag == 0x0E:
        at += 1
        count, at = _varint(descriptor, at)
        return [repr(float(v)) for v in value], at
    count, at = _varint(descriptor, at)  # a record
    tokens: list[str] = []
    for _ in range(count):
        length, at = _varint(descriptor, at)
        name = descriptor[at : at + length].decode()
        more, at = _tokens(descriptor, at + length, value[name])
        tokens += more
    return tokens, at


def codec_lines() -> list[str]:
    lines = []
    for case in json.loads((VECTORS / "codecs.json").read_text())["codecs"]:
        descriptor = bytes.fromhex(case["descriptor_hex"])
        tokens, _ = _tokens(descriptor, 0, case["value"])
        lines.append(f"CODEC ok {case['descriptor_hex']} {case['hex'] or '-'} {' '.join(tokens)}")
    return lines


def _raw_request(bus: can.BusABC, message: bytes, *, dest_kind: int = 0, dest: int = 5, source: int = 77,
                 priority: int = 3, reply: bool = True) -> bytes | None:  # fmt: skip
    """Send ``message`` as frames from node ``source``; the reply addressed back to it, reassembled (or None)."""
    from asm_py.canbus.fragments import Reassembler, fragment
    from asm_py.canbus.ids import frame_priority

    pieces = list(fragment(message))
    for kind, counter, data in pieces:
        cid = CanId(frame_priority(priority, len(pieces)), dest_kind, dest, source, kind, counter)
        bus.send(can.Message(arbitration_id=cid.pack(), data=data, is_extended_id=True))
    if not reply:
        return None
    reassembler = Reassembler(max_partials=4)
    for frame in _frames_to(bus, source):
        cid = CanId.unpack(frame.arbitration_id)
        done = reassembler.feed((cid.source, cid.dest_kind, cid.dest), cid.frame, cid.counter, bytes(frame.data),
                                time.monotonic())  # fmt: skip
        if done is not None:
            return done
    return None


def reproduce_module_object_vectors(module: CModule, channel: str) -> dict[str, bool]:
    """Each vector of tests/vectors/module_objects.json a C module reproduces on the bus, byte for byte (a reply's
    status bytes for the §1 statuses), by name; False where it does not."""
    import json

    from asm_module.wire import checksum

    vectors = json.loads((VECTORS / "module_objects.json").read_text())
    bus = can.Bus(interface="virtual", channel=channel)
    done: dict[str, bool] = {}
    try:
        lookup = vectors["lookup_reply_read_only"]
        request = bytes([0x50, 0x04, 0x00, 0x00]) + lookup["object"].encode()  # LOOKUP by name, txn 4
        done["lookup_reply_read_only"] = _raw_request(bus, request) == bytes.fromhex(lookup["hex"])
        staged = bytes.fromhex(vectors["staged"]["hex"])
        set_staged = _raw_request(bus, bytes([0x52, 0x06, 0x27, 13]) + staged)
        peek = _raw_request(bus, bytes([0x5A, 0x07, 0x28, 14]))
        done["staged"] = (set_staged is not None and set_staged[2] == 0 and peek is not None
                          and peek[4:] == struct.pack("<I", checksum(staged)))  # fmt: skip
        _raw_request(bus, bytes.fromhex(vectors["activate"]["hex"]), dest_kind=2, dest=0, reply=False)
        time.sleep(0.2)
        activated = _raw_request(bus, bytes([0x5A, 0x08, 0x29, 15]))
        status = _raw_request(bus, bytes([0x58, 0x09, 0x24, 9]))
        deploy_id = struct.pack("<I", vectors["activate"]["deploy_id"])
        done["activate"] = (activated is not None and activated[4:] == deploy_id and status is not None
                            and status[4] & 4 != 0)  # fmt: skip
        lease = bytes.fromhex(vectors["lease"]["hex"])
        taken = _raw_request(bus, bytes([0x52, 0x0A, 0x2A, 16]) + lease)
        held = _raw_request(bus, bytes([0x5A, 0x0B, 0x2A, 16]))
        done["lease"] = taken is not None and taken[2] == 0 and held is not None and held[4:] == lease
        other = bytes([6]) + b"intrud" + struct.pack("<If", 99, 30.0)
        produced = {
            10: _raw_request(bus, bytes([0x52, 0x05, 0x26, 7, 0, 0, 0, 0])),  # SET of gait.checksum: READ_ONLY
            12: _raw_request(bus, bytes([0x52, 0x05, 0x2A, 16]) + other),  # another deployer's lease: LOCKED
        }
        module_estop = _raw_request(bus, bytes([0x52, 0x0C, 0x03, 12, 1]))  # latch
        produced[11] = _raw_request(bus, bytes([0x52, 0x05, 0x10, 1, 0, 0, 0, 0]))  # SET of joint.goal: ESTOP
        _raw_request(bus, bytes([0x52, 0x0D, 0x03, 12, 0]))  # release
        send_first_frame(bus, 5000, bytes([0x52, 0x05, 0x27, 13]))  # a 5,000-byte SET: its first frame only
        produced[13] = first_reply(bus)
        for vector in vectors["replies"]:
            got = produced.get(vector["status"])
            done[f"reply {vector['name']}"] = (module_estop is not None and got is not None
                                               and got[:3] == bytes.fromhex(vector["hex"])[:3])  # fmt: skip
        _raw_request(bus, bytes([0x55, 0x0E, 0x24, 9]))  # STOP gait.service: a table changes only while stopped
        program = vectors["program"]
        loaded = _raw_request(bus, bytes([0x52, 0x0F, 0x20, 6]) + bytes.fromhex(program["hex"]))
        crc = _raw_request(bus, bytes([0x5A, 0x10, 0x26, 7]))
        done["program"] = (loaded is not None and loaded[2] == 0 and crc is not None
                           and crc[4:] == struct.pack("<I", checksum(bytes.fromhex(program["hex"]))))  # fmt: skip
        for name, object_id in (("switch", 19), ("signal", 23)):  # group SETs, then read back from the object
            message = bytes.fromhex(vectors[name]["hex"])
            _raw_request(bus, message, dest_kind=2, dest=0, reply=False)
            value = _raw_request(bus, bytes([0x5A, 0x11, message[2], object_id]))
            done[name] = value is not None and value[2] == 0 and value[4:] == message[4:]
    finally:
        bus.shutdown()
    return done


def _frames_to(bus: can.BusABC, node: int = 77) -> Iterator[can.Message]:
    """The frames the C module (node 5) sends to ``node`` in the next 5 s."""
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        frame = bus.recv(timeout=0.5)
        if frame is not None and (frame.arbitration_id >> 8) & 0x3FFFF == (node << 8 | 5):
            yield frame


def send_first_frame(bus: can.BusABC, length: int, header: bytes) -> None:
    """Only the first frame of a ``length``-byte message from node 77 to the module: the length, a CRC, the header."""
    data = bytes([length & 0xFF, length >> 8, 0, 0]) + header
    bus.send(can.Message(arbitration_id=5 << 26 | 5 << 16 | 77 << 8 | 1 << 6, data=data, is_extended_id=True))


def first_reply(bus: can.BusABC) -> bytes | None:
    """The head of the next reply to node 77 (its first frame's message bytes, after the length and CRC, or a single
    frame's)."""
    for frame in _frames_to(bus):
        return bytes(frame.data[4:]) if (frame.arbitration_id >> 6) & 3 == 1 else bytes(frame.data)
    return None
