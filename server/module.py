"""``asm-module --can INTERFACE:CHANNEL --node-id N``: one module on a CAN bus, as a Linux-based module runs it.

The module itself — its objects, its gait, its e-stop — is asm_module (the program a module runs, whether its
joint is simulated or real); this is only its command line.
"""

from __future__ import annotations

import argparse

from asm_module import FakeDriver, ModuleRuntime
from asm_py.cli import bitrate, bounded, can_channel, name, node_id, rate, run, stop_requested
from asm_py.node import Node
from asm_py.transport.can import CanTransport
from server.realtime import prefer_latency


def main(argv: list[str] | None = None) -> int:
    """``asm-module --can INTERFACE:CHANNEL --node-id N``: one module on a CAN bus (a Linux-based module)."""
    cli = argparse.ArgumentParser(prog="asm-module", description=main.__doc__.splitlines()[0] if main.__doc__ else "")
    cli.add_argument("--can", type=can_channel, required=True, metavar="INTERFACE:CHANNEL")
    cli.add_argument("--bitrate", type=bitrate)
    cli.add_argument("--node-id", type=node_id, required=True, help="CAN node ID 1..254; also names the node m<ID>")
    cli.add_argument("--name", type=name, help="node name (default m<node-id>, what gaits.deploy expects)")
    cli.add_argument("--driver", choices=["fake"], default="fake", help="joint driver (fake: a servo model)")
    cli.add_argument(
        "--limits",
        type=bounded(float, -180, 180, what="a joint limit in degrees"),
        nargs=2,
        default=(-90.0, 90.0),
        metavar=("MIN", "MAX"),
        help="joint limits, degrees (default -90 90)",
    )
    cli.add_argument("--rate", type=rate, default=50.0, help="control ticks per second (default 50)")
    args = cli.parse_args(argv)
    if not args.limits[0] < args.limits[1]:
        cli.error(f"--limits: MIN must be below MAX, not {args.limits[0]:g} {args.limits[1]:g}")
    return run(cli.prog, lambda: _serve(args))


def _serve(args: argparse.Namespace) -> int:
    prefer_latency()
    options = {**args.can, **({"bitrate": args.bitrate} if args.bitrate else {})}
    name = args.name or f"m{args.node_id}"
    node = Node(name, CanTransport(args.node_id, **options))
    runtime = ModuleRuntime(FakeDriver(), node=node, limits=tuple(args.limits), control_rate=args.rate)
    done = stop_requested()
    print(f"READY {name}", flush=True)
    done.wait()
    runtime.close()
    node.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
