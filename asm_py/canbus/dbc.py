"""A DBC file describing every ASM frame on a bus, for CAN tools (cantools, SavvyCAN, Vector tools, …).

DBC names a message by its full identifier, and ASM's identifier holds the source, the destination and a fragment
counter, so the file lists, for a given set of module nodes and one tool node (a studio, a bridge):

- ``ASM_PUB_N<n>``: publications of each module (the class ID in byte 2 multiplexes the value signals);
- ``ASM_REQ_N<t>_TO_N<n>`` and ``ASM_REP_N<n>_TO_N<t>``: the tool's requests and the module's replies;
- ``ASM_BROADCAST_N<t>`` and ``ASM_GROUP<g>_N<t>``: the tool's requests to every node and to each group 0-255;
- ``ASM_HEARTBEAT_N<k>``, ``ASM_LEAVE_N<k>``: heartbeats and leave frames of **every** node ID 1-254 (tools too);
- ``ASM_ESTOP_N<k>``: e-stops from every source ID 0-255 (a receiver honours them all);
- ``ASM_FIRST_…``, ``ASM_MIDDLE_…_C<c>``, ``ASM_LAST_…_C<c>``: the fragments of long messages on each of those
  paths (priority 5; heartbeats at 6), with the first frame's length and CRC as signals.

Value signals take their type from the module objects' codecs (:data:`CLASS_CODECS`, checked against a module
runtime by the tests): floats decode as floats. ASM frames carry 0-8 bytes and the DBC gives the longest form, so
decode with ``allow_truncated=True``. docs/protocol.md ("Decoding a log") lists the signals with a worked example.

CLI: ``asm-dbc --nodes 1-8 --tool 254 -o asm.dbc``.
"""

from __future__ import annotations

import argparse
import functools
from collections.abc import Iterable, Mapping
from enum import IntEnum

from cantools.database.can import Database, Message, Signal
from cantools.database.conversion import BaseConversion

from ..classes import well_known
from ..cli import node_id, output_file, run
from ..codec import Codec
from ..codec_parse import parse_codec
from ..protocol import Kind, Method, Status
from .ids import MAX_NODE_ID, MIN_NODE_ID, CanId, Dest, FrameType, Priority, SystemCode

CLASS_CODECS: dict[str, str] = {
    "estop": "bool",
    "joint.goal": "float32",
    "joint.angle": "float32",
    "joint.torque": "float32",
    "gait.phase": "float32",
    "gait.direction": "int8",
    "gait.state": "uint16",
    "gait.tick": "float64",
    "gait.checksum": "uint32",
    "gait.staged_checksum": "uint32",
    "gait.activate": "uint32",
    "sensor.contact": "bool",
}
"""The value codecs of the well-known module objects with a fixed-size value (docs/protocol.md §9)."""

_STRUCT = {"float32": (32, True, True), "float64": (64, True, True), "int8": (8, True, False),
           "uint8": (8, False, False), "int16": (16, True, False), "uint16": (16, False, False),
           "int32": (32, True, False), "uint32": (32, False, False), "bool": (8, False, False)}  # fmt: skip


def _signal(name: str, start: int, length: int, *, signed: bool = False, is_float: bool = False,
            choices: Mapping[int, str] | None = None, **kw) -> Signal:  # fmt: skip
    conversion = BaseConversion.factory(scale=1, offset=0, choices=dict(choices) if choices else None,  # pyright: ignore[reportArgumentType]  # cantools' Choices maps to str or NamedSignalValue
                                        is_float=is_float)  # fmt: skip
    return Signal(name, start, length, byte_order="little_endian", is_signed=signed, conversion=conversion, **kw)


def _bytes(prefix: str, first: int, count: int) -> list[Signal]:
    """One 8-bit signal per data byte (``name_0``, ``name_1``, …): a frame shorter than the longest form still
    decodes the bytes it has, where one wide signal would be dropped whole by ``allow_truncated``."""
    return [_signal(f"{prefix}_{k}", 8 * (first + k), 8) for k in range(count)]


def _names(enum: type[IntEnum]) -> dict[int, str]:
    return {int(member): member.name for member in enum}


def _header(third: str, *, multiplexed: bool) -> list[Signal]:
    return [
        _signal("method", 0, 4, choices=_names(Method)),
        _signal("kind", 4, 2, choices=_names(Kind)),
        _signal("version", 6, 2),
        _signal("txn", 8, 7),
        _signal("timeout_flag", 15, 1),
        _signal(third, 16, 8, is_multiplexer=multiplexed, choices=_names(Status) if third == "status" else None),
        _signal("object_id", 24, 8),
    ]


def _values(classes: Mapping[str, Codec], frame_size: int) -> list[Signal]:
    signals = []
    for class_name, codec in classes.items():
        if codec.spec not in _STRUCT or class_name not in well_known():
            continue
        length, signed, is_float = _STRUCT[codec.spec]
        if 4 + length // 8 > frame_size:  # a float64 value makes a 12-byte message: fragmented on classic CAN
            continue
        mux = {"multiplexer_ids": [well_known()[class_name]], "multiplexer_signal": "class_id"}
        signals.append(_signal(class_name.replace(".", "_"), 32, length, signed=signed, is_float=is_float, **mux))
    typed = {i for signal in signals for i in signal.multiplexer_ids or ()}
    others = [i for i in range(256) if i not in typed]  # services, tables, local classes: their bytes, undecoded
    signals.append(_signal("value_raw", 32, 32, multiplexer_ids=others, multiplexer_signal="class_id"))
    return signals


def _frame_id(priority: int, dest_kind: int, dest: int, source: int, frame: int = FrameType.SINGLE,
              counter: int = 0) -> int:  # fmt: skip
    return CanId(priority, dest_kind, dest, source, frame, counter).pack()


def build(nodes: Iterable[int], tool: int = 254, classes: Mapping[str, str] | None = None, *,
          fragments: bool = True, fd: bool = False) -> Database:  # fmt: skip
    """The cantools database of the ASM frames between module ``nodes`` and the ``tool`` node; ``fd``: CAN FD,
    whose single frames carry up to 64 bytes (so a float64 value, e.g. ``gait_tick``, is a signal too)."""
    codecs = {name: parse_codec(spec) for name, spec in (classes or CLASS_CODECS).items()}
    length = 64 if fd else 8
    messages: list[Message] = []

    def add(frame_id: int, name: str, signals: list[Signal], sender: int, comment: str, size: int = 8) -> None:
        messages.append(Message(frame_id, name, size, signals, is_extended_frame=True, senders=[f"N{sender}"],
                                comment=comment, strict=False))  # fmt: skip

    def muxed() -> list[Signal]:
        return [*_header("class_id", multiplexed=True), *_values(codecs, length)]

    def fragmented(priority: int, dest_kind: int, dest: int, source: int, path: str) -> None:
        add(_frame_id(priority, dest_kind, dest, source, FrameType.FIRST), f"ASM_FIRST_{path}",
            [_signal("message_length", 0, 16), _signal("message_crc16", 16, 16), *_bytes("data", 4, 4)],
            source, f"first fragment, {path}: length, CRC-16, then message bytes", length)  # fmt: skip
        for counter in range(64):
            for frame, word in ((FrameType.MIDDLE, "MIDDLE"), (FrameType.LAST, "LAST")):
                if frame == FrameType.MIDDLE and counter == 0:
                    continue  # a middle frame counts 1, 2, … 63 and wraps to 0 only after 63 others: listed below
                add(_frame_id(priority, dest_kind, dest, source, frame, counter), f"ASM_{word}_{path}_C{counter}",
                    _bytes("data", 0, 8), source, f"{word.lower()} fragment {counter}, {path}",
                    length)  # fmt: skip
        add(_frame_id(priority, dest_kind, dest, source, FrameType.MIDDLE, 0), f"ASM_MIDDLE_{path}_C0",
            _bytes("data", 0, 8), source, f"middle fragment 64 (counter 0), {path}", length)  # fmt: skip

    for n in sorted(set(nodes)):
        add(_frame_id(Priority.PUBLICATION, Dest.BROADCAST, 0, n), f"ASM_PUB_N{n}", muxed(), n,
            f"publications of node {n}", length)  # fmt: skip
        add(_frame_id(Priority.REQUEST, Dest.NODE, n, tool), f"ASM_REQ_N{tool}_TO_N{n}", muxed(), tool,
            f"requests of node {tool} to {n}", length)  # fmt: skip
        add(_frame_id(Priority.REPLY, Dest.NODE, tool, n), f"ASM_REP_N{n}_TO_N{tool}",
            [*_header("status", multiplexed=False), _signal("value_raw", 32, 32)], n,
            f"replies of {n} to {tool}: a reply does not name its class; the request with the same txn does "
            f"(decode value_raw with that class's codec, e.g. asm_py.codec_parse.parse_codec)")  # fmt: skip
        if fragments:
            fragmented(Priority.BULK_PUBLICATION, Dest.BROADCAST, 0, n, f"PUB_N{n}")
            fragmented(Priority.BULK, Dest.NODE, n, tool, f"N{tool}_TO_N{n}")
            fragmented(Priority.BULK, Dest.NODE, tool, n, f"N{n}_TO_N{tool}")
    add(_frame_id(Priority.REQUEST, Dest.BROADCAST, 0, tool), f"ASM_BROADCAST_N{tool}", muxed(), tool,
        f"broadcast requests of node {tool}", length)  # fmt: skip
    for group in range(256):
        add(_frame_id(Priority.REQUEST, Dest.GROUP, group, tool), f"ASM_GROUP{group}_N{tool}", muxed(), tool,
            f"requests of node {tool} to group {group}", length)  # fmt: skip
    if fragments:
        fragmented(Priority.BULK, Dest.BROADCAST, 0, tool, f"BROADCAST_N{tool}")
    for k in range(MIN_NODE_ID, MAX_NODE_ID + 1):
        add(_frame_id(Priority.HEARTBEAT, Dest.SYSTEM, SystemCode.HEARTBEAT, k), f"ASM_HEARTBEAT_N{k}",
            _bytes("name", 0, 8), k, f"heartbeat of node {k}: its name, UTF-8 (0-8 bytes; a longer name "
            f"goes in ASM_FIRST/MIDDLE/LAST_HEARTBEAT_N{k}_… frames)")  # fmt: skip
        add(_frame_id(Priority.HEARTBEAT, Dest.SYSTEM, SystemCode.LEAVE, k), f"ASM_LEAVE_N{k}", [], k,
            f"node {k} leaves the bus (orderly close); no data", 0)  # fmt: skip
        if fragments and (k in nodes or k == tool):
            fragmented(Priority.HEARTBEAT, Dest.SYSTEM, SystemCode.HEARTBEAT, k, f"HEARTBEAT_N{k}")
    for k in range(256):
        add(_frame_id(Priority.ESTOP, Dest.SYSTEM, SystemCode.ESTOP, k), f"ASM_ESTOP_N{k}",
            _bytes("reason", 0, 8), k, f"e-stop from source {k}: a reason, UTF-8, 0-8 bytes")  # fmt: skip
    return Database(messages=messages, strict=False)


def generate(nodes: Iterable[int], tool: int = 254, classes: Mapping[str, str] | None = None, *,
             fragments: bool = True, fd: bool = False) -> str:  # fmt: skip
    """The DBC text (see :func:`build`). cantools takes seconds over the ~1800 frames of even one node (the 256
    groups, the heartbeats and e-stops of every ID), so the text for the module profiles' classes is kept for the
    next call with the same arguments."""
    if classes is None:
        return _generate_known(tuple(sorted(set(nodes))), tool, fragments, fd)
    return build(nodes, tool, classes, fragments=fragments, fd=fd).as_dbc_string()


@functools.lru_cache(maxsize=8)
def _generate_known(nodes: tuple[int, ...], tool: int, fragments: bool, fd: bool) -> str:
    return build(nodes, tool, fragments=fragments, fd=fd).as_dbc_string()


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
    cli = argparse.ArgumentParser(prog="asm-dbc", description=(__doc__ or "").splitlines()[0])
    cli.add_argument("--nodes", type=_ids, default=_ids("1-8"), help="module node IDs, e.g. 1-8 or 1,3,5")
    cli.add_argument("--tool", type=node_id, default=254, help="node ID of the tool, studio or bridge (default 254)")
    cli.add_argument("-o", "--output", type=output_file, help="write here instead of stdout")
    cli.add_argument("--fd", action="store_true", help="CAN FD: frames of up to 64 bytes (float64 values as signals)")
    cli.add_argument("--no-fragments", action="store_true",
                     help="leave out the fragment frames of long messages (129 identifiers per path)")  # fmt: skip
    args = cli.parse_args(argv)
    if args.tool in args.nodes:
        cli.error(f"--tool {args.tool} is also one of --nodes: every node on a bus needs its own ID")

    def write() -> int:
        text = generate(args.nodes, args.tool, fragments=not args.no_fragments, fd=args.fd)
        if args.output:
            args.output.write_text(text, encoding="utf-8")
        else:
            print(text)
        return 0

    return run(cli.prog, write)


if __name__ == "__main__":
    raise SystemExit(main())
