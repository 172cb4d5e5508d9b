"""What every example shares: the command line for reaching a Zenoh network, and opening a node on it."""

from __future__ import annotations

import argparse

from asm_py import Node
from asm_py.transport.zenoh import ZenohTransport


def parser(description: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument(
        "--connect", action="append", default=[], help="endpoint to connect to, e.g. tcp/127.0.0.1:7447"
    )
    parser.add_argument("--listen", action="append", default=[], help="endpoint to listen on, e.g. tcp/127.0.0.1:7447")
    parser.add_argument("--mode", default="peer", choices=["peer", "client"], help="zenoh mode (client: via a router)")
    parser.add_argument("--robot", default="robot", help="the robot (Zenoh namespace) to join (default robot)")
    return parser


def open_node(name: str, args: argparse.Namespace, *, role: str = "tool") -> Node:
    """A node of robot ``--robot``: a tool (it calls modules), or with ``role="module"`` a module (it answers for
    its name, which must not be alive in the robot yet)."""
    transport = ZenohTransport(robot=args.robot, role=role, mode=args.mode, listen=args.listen, connect=args.connect)
    return Node(name, transport)
