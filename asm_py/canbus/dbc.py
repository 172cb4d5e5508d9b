"""A DBC file describing ASM frames on a bus, for CAN tools (cantools, SavvyCAN, Vector tools, …).

DBC identifies a message by its full identifier, so the file describes the single frames of a given set of nodes:
for each module node N — its publications (``ASM_PUB_N``), its replies to the tool node T (``ASM_REP_N_TO_T``),
the tool's requests to it (``ASM_REQ_T_TO_N``), its heartbeat and its e-stop — plus the tool's broadcasts. Every
message splits the 4-byte ASM header into signals; in publications and requests the class ID (byte 2) is the
multiplexer, and each well-known class with a value of up to 4 bytes has its own signal in bytes 4-7 (e.g.
``joint_angle``, a little-endian float32). Frames shorter than 8 bytes decode with ``allow_truncated=True``.
Fragmented messages (longer than one frame) are beyond what DBC can describe.

CLI: ``python -m asm_py.canbus.dbc --nodes 1-8 --tool 254 -o asm.dbc``.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Mapping

from cantools.database.can import Database, Message, Signal
from cantools.database.conversion import BaseConversion

from ..cli import node_id, output_file, run
from ..codec import Codec, parse_codec
from ..protocol import WELL_KNOWN_CLASSES
from .ids import CanId, Dest, FrameType, Priority, SystemCode

CLASS_CODECS: dict[str, str] = {
    "joint.goal": "float32",
    "joint.angle": "float32",
    "joint.torque": "float32",
    "gait.phase": "float32",
    "gait.direction": "int8",
    "gait.state": "uint8",
    "gait.tick": "uint32",
    "gait.checksum": "uint32",
    "sensor.contact": "bool",
}
"""The value codecs of the well-known classes the module runtime uses (and the DBC describes)."""

_STRUCT = {"float32": (32, True, True), "int8": (8, True, False), "uint8": (8, False, False),
           "int16": (16, True, False), "uint16": (16, False, False), "int32": (32, True, False),
           "uint32": (32, False, False), "bool": (8, False, False)}  # fmt: skip


def _signal(name: str, start: int, length: int, *, signed: bool = False, is_float: bool = False, **kw) -> Signal:
    conversion = BaseConversion.factory(scale=1, offset=0, choices=None, is_float=is_float)
    return Signal(name, start, length, byte_order="little_endian", is_signed=signed, conversion=conversion, **kw)


def _header(third: str, *, multiplexed: bool) -> list[Signal]:
    return [
        _signal("method", 0, 4),
        _signal("kind", 4, 2),
        _signal("version", 6, 2),
        _signal("txn", 8, 7),
        _signal("timeout_flag", 15, 1),
        _signal(third, 16, 8, is_multiplexer=multiplexed),
        _signal("object_id", 24, 8),
    ]


def _values(classes: Mapping[str, Codec]) -> list[Signal]:
    signals = []
    for class_name, codec in classes.items():
        if codec.spec not in _STRUCT or class_name not in WELL_KNOWN_CLASSES:
            continue
        length, signed, is_float = _STRUCT[codec.spec]
        mux = {"multiplexer_ids": [WELL_KNOWN_CLASSES[class_name]], "multiplexer_signal": "class_id"}
        signals.append(_signal(class_name.replace(".", "_"), 32, length, signed=signed, is_float=is_float, **mux))
    return signals


def _frame_id(priority: int, dest_kind: int, dest: int, source: int) -> int:
    return CanId(priority, dest_kind, dest, source, FrameType.SINGLE, 0).pack()


def build(nodes: Iterable[int], tool: int = 254, classes: Mapping[str, str] | None = None) -> Database:
    """The cantools database of ASM single frames between ``nodes`` and the ``tool`` node."""
    codecs = {name: parse_codec(spec) for name, spec in (classes or CLASS_CODECS).items()}
    messages: list[Message] = []

    def add(frame_id: int, name: str, signals: list[Signal], sender: int, comment: str) -> None:
        messages.append(Message(frame_id, name, 8, signals, is_extended_frame=True, senders=[f"N{sender}"],
                                comment=comment, strict=False))  # fmt: skip

    for n in sorted(set(nodes)):
        muxed = [*_header("class_id", multiplexed=True), *_values(codecs)]
        add(_frame_id(Priority.PUBLICATION, Dest.BROADCAST, 0, n), f"ASM_PUB_N{n}", muxed, n,
            f"publications of node {n}")  # fmt: skip
        add(
            _frame_id(Priority.REQUEST, Dest.NODE, n, tool),
            f"ASM_REQ_N{tool}_TO_N{n}",
            [*_header("class_id", multiplexed=True), *_values(codecs)],
            tool,
            f"requests of node {tool} to {n}",
        )
        add(
            _frame_id(Priority.REPLY, Dest.NODE, tool, n),
            f"ASM_REP_N{n}_TO_N{tool}",
            [*_header("status", multiplexed=False), _signal("value_raw", 32, 32)],
            n,
            f"replies of {n} to {tool}",
        )
        add(
            _frame_id(Priority.HEARTBEAT, Dest.SYSTEM, SystemCode.HEARTBEAT, n),
            f"ASM_HEARTBEAT_N{n}",
            [_signal("name_raw", 0, 64)],
            n,
            f"heartbeat of node {n}: its name, UTF-8",
        )
        add(
            _frame_id(Priority.ESTOP, Dest.SYSTEM, SystemCode.ESTOP, n),
            f"ASM_ESTOP_N{n}",
            [_signal("reason_raw", 0, 64)],
            n,
            f"emergency stop sent by node {n}",
        )
    add(
        _frame_id(Priority.REQUEST, Dest.BROADCAST, 0, tool),
        f"ASM_BROADCAST_N{tool}",
        [*_header("class_id", multiplexed=True), *_values(codecs)],
        tool,
        f"broadcast requests of node {tool}",
    )
    add(
        _frame_id(Priority.ESTOP, Dest.SYSTEM, SystemCode.ESTOP, tool),
        f"ASM_ESTOP_N{tool}",
        [_signal("reason_raw", 0, 64)],
        tool,
        f"emergency stop sent by node {tool}",
    )
    return Database(messages=messages, strict=False)


def generate(nodes: Iterable[int], tool: int = 254, classes: Mapping[str, str] | None = None) -> str:
    """The DBC text (see :func:`build`)."""
    return build(nodes, tool, classes).as_dbc_string()


def _ids(spec: str) -> list[int]:
    """``1-8`` or ``1,3,5`` (or both, ``1-4,9``): node IDs, each 1..254, as an argparse type."""
    out: list[int] = []
    for part in spec.split(","):
        low, _, high = part.partition("-")
        first, last = node_id(low.strip()), node_id((high or low).strip())
        if last < first:
            raise argparse.ArgumentTypeError(f"{part!r}: a range runs from low to high, e.g. 1-8")
        out += range(first, last + 1)
    return sorted(set(out))


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-dbc", description=__doc__.splitlines()[0])
    cli.add_argument("--nodes", type=_ids, default=_ids("1-8"), help="module node IDs, e.g. 1-8 or 1,3,5")
    cli.add_argument("--tool", type=node_id, default=254, help="node ID of the tool, studio or bridge (default 254)")
    cli.add_argument("-o", "--output", type=output_file, help="write here instead of stdout")
    args = cli.parse_args(argv)
    if args.tool in args.nodes:
        cli.error(f"--tool {args.tool} is also one of --nodes: every node on a bus needs its own ID")

    def write() -> int:
        text = generate(args.nodes, args.tool)
        if args.output:
            args.output.write_text(text, encoding="utf-8")
        else:
            print(text)
        return 0

    return run(cli.prog, write)


if __name__ == "__main__":
    raise SystemExit(main())
