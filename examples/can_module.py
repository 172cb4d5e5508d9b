"""The example module on a CAN bus (any python-can interface), optionally with a Zenoh bridge in the same process.

    python examples/can_module.py --can socketcan:can0 --node-id 1 --name m1
    python examples/can_module.py --can virtual:bus0 --node-id 1 --name m1 --bridge --listen tcp/127.0.0.1:7447
With --bridge, Zenoh clients (examples/get.py …) reach the module through server/bridge.py, as if it were next door.
Prints "READY <name>" once it is reachable; Ctrl-C (or SIGTERM) stops it.
"""

from __future__ import annotations

import sys

from _common import parser
from module import populate, serve

from asm_py import Node
from asm_py.cli import can_channel
from asm_py.transport.can import CanTransport
from server.bridge import CanZenohBridge
from server.zenoh_args import ZenohOptions


def main() -> int:
    cli = parser(__doc__.splitlines()[0])
    cli.add_argument("--can", type=can_channel, required=True, metavar="INTERFACE:CHANNEL")
    cli.add_argument("--node-id", type=int, default=1)
    cli.add_argument("--name", default="m1")
    cli.add_argument("--bridge", action="store_true", help="also bridge the bus to Zenoh (--listen/--connect)")
    args = cli.parse_args()
    node = Node(args.name, CanTransport(args.node_id, **args.can))
    bridge = None
    if args.bridge:
        network = ZenohOptions(args.mode, tuple(args.listen), tuple(args.connect))
        bridge = CanZenohBridge(args.can, robot=args.robot, network=network)
    services = populate(node)
    serve(args.name, node, services, *([bridge] if bridge else []))
    return 0


if __name__ == "__main__":
    sys.exit(main())
