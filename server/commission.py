"""``asm-commission --can INTERFACE:CHANNEL list|number|set|erase``: find the modules of a bus by their serials and
give them node IDs (docs/protocol.md §7, "Commissioning").

    asm-commission --can socketcan:can0 list                  # every module: serial, node ID; conflicts (exit 1)
    asm-commission --can socketcan:can0 number --first 1      # every module without an ID gets the next free one
    asm-commission --can socketcan:can0 number --order chain.txt   # ... in the order of the serials in the file
    asm-commission --can socketcan:can0 set 0123456789abcdef01234567 5
    asm-commission --can socketcan:can0 erase 0123456789abcdef01234567

The IDs are stored in each module (flash on a board, its ID file on a Linux module) and kept across resets.
``number``, ``set`` and ``erase`` are refused (exit 1, nothing changed) while any numbered module on the bus has its
e-stop latched or runs a gait: an ID given or erased resets a board, which releases its latch or drops its joint.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import can

from asm_module.halts import read_halts
from asm_py.canbus.commission import (
    UNCONFIGURED,
    Commissioner,
    CommissionScope,
    conflicts,
    describe_conflicts,
    parse_serial,
)
from asm_py.canbus.ids import MAX_NODE_ID, MIN_NODE_ID
from asm_py.cli import bitrate, bounded, can_channel, input_file, node_id, positive_seconds, run, summary
from asm_py.node import Node
from asm_py.transport.can import ALIAS_PREFIX, CanTransport

LATCH_TIMEOUT = 1.0
"""Seconds each numbered module has to say whether it is latched or walks before IDs change."""
HEARD_TIMEOUT = 2.0
"""Seconds to hear the numbered modules' heartbeats (every 0.5 s by default) before asking them."""


def serial(text: str) -> bytes:
    """A module's serial: 24 hex digits."""
    try:
        return parse_serial(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def read_order(path: Path) -> list[bytes]:
    """Serials, one a line (``#`` starts a comment): the order modules are numbered in."""
    lines = (line.split("#", 1)[0].strip() for line in path.read_text().splitlines())
    return [serial(line) for line in lines if line]


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-commission", description=summary(__doc__),
                                  formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    cli.add_argument("--can", type=can_channel, required=True, metavar="INTERFACE:CHANNEL")
    cli.add_argument("--bitrate", type=bitrate)
    cli.add_argument("--fd", action="store_true", help="a CAN FD bus")
    cli.add_argument("--node-id", type=node_id, default=254, help="the tool's own CAN node ID (default 254)")
    cli.add_argument("--window", type=positive_seconds, default=0.05,
                     help="seconds a scan waits for a first answer (default 0.05)")  # fmt: skip
    commands = cli.add_subparsers(dest="command", required=True)
    commands.add_parser("list", help="every module on the bus: serial and node ID (exit 1 on a shared ID)")
    number = commands.add_parser("number", help="give every module without a node ID the next free one")
    number.add_argument("--first", type=node_id, default=1, help="the first node ID to give (default 1)")
    number.add_argument("--order", type=input_file, help="a file of serials, one a line: the numbering order")
    one = commands.add_parser("set", help="give one module a node ID")
    one.add_argument("serial", type=serial)
    one.add_argument("id", type=bounded(int, MIN_NODE_ID, MAX_NODE_ID - 1, what="a module's node ID"))  # 254: tools
    erase = commands.add_parser("erase", help="make one module unconfigured again")
    erase.add_argument("serial", type=serial)
    args = cli.parse_args(argv)
    try:
        order = read_order(args.order) if getattr(args, "order", None) else None
    except argparse.ArgumentTypeError as exc:  # a line of the file: a usage error naming it, not a traceback
        cli.error(f"argument --order: {args.order}: {exc}")
    return run(cli.prog, lambda: _command(args, order))


def refuse_while_stopped(options: dict[str, Any], tool_id: int, ids: Iterable[int], why: str) -> None:
    """RuntimeError while any module of ``ids`` (node IDs the scan found) has its e-stop latched or runs a gait
    (asm_module.halts: the robot's commissioning service and a firmware update refuse alike). Asked over ASM from a
    node of the tool's own ID on a bus handle of its own, once each module's heartbeat named it (a reply comes
    under the module's name; a module not heard within HEARD_TIMEOUT is silent, and not counted)."""
    ids = sorted(ids)
    if not ids:
        return
    transport = CanTransport(tool_id, **options)
    node = Node("asm-commission", transport)
    try:
        deadline = time.monotonic() + HEARD_TIMEOUT
        while any(transport.name_of(i).startswith(ALIAS_PREFIX) for i in ids) and time.monotonic() < deadline:
            time.sleep(0.05)
        refusal = read_halts(node, [transport.name_of(i) for i in ids], LATCH_TIMEOUT).refusal(why)
    finally:
        node.close()
    if refusal is not None:
        raise RuntimeError(refusal)


def _command(args: argparse.Namespace, order: list[bytes] | None) -> int:
    options = {**args.can, **({"bitrate": args.bitrate} if args.bitrate else {}), **({"fd": True} if args.fd else {})}
    bus = can.Bus(**options)
    try:
        tool = Commissioner(bus, tool_id=args.node_id, window=args.window)
        if args.command in ("number", "set", "erase"):  # each ID given or erased resets a board: its latch released
            numbered = {m.node_id for m in tool.discover(CommissionScope.EVERY)} - {UNCONFIGURED}
            refuse_while_stopped(options, args.node_id, numbered, "an ID given or erased resets the board")
        if args.command == "list":
            roster = tool.discover(CommissionScope.EVERY)
            for module in sorted(roster, key=lambda m: (m.node_id == UNCONFIGURED, m.node_id, m.serial)):
                print(f"{module.serial_hex}  {module.node_id or '-'}")
            print(f"{len(roster)} modules, {sum(m.node_id == UNCONFIGURED for m in roster)} without a node ID")
            clash = conflicts(roster)
            if clash:
                print(f"{'asm-commission'}: conflict: {describe_conflicts(clash)}", file=sys.stderr)
                return 1
        elif args.command == "number":
            for module in tool.number(first=args.first, order=order):
                print(f"{module.serial_hex}  {module.node_id}")
        elif args.command == "set":
            if args.id == args.node_id:
                raise RuntimeError(f"node ID {args.id} is this tool's own (--node-id): a module never gets it")
            holders = [
                m for m in tool.discover(CommissionScope.EVERY) if m.node_id == args.id and m.serial != args.serial
            ]
            if holders:  # the studio's service refuses it too: IDs are never shared
                raise RuntimeError(f"node ID {args.id} is held by module {holders[0].serial_hex}: IDs are never "
                                   "shared (erase that one first, or choose another)")  # fmt: skip
            tool.assign(args.serial, args.id)
            print(f"{args.serial.hex()}  {args.id}")
        else:
            tool.assign(args.serial, UNCONFIGURED)
            print(f"{args.serial.hex()}  -")
    except LookupError as exc:
        raise RuntimeError(str(exc).strip("'\"")) from None
    finally:
        bus.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
