"""``asm-module --can INTERFACE:CHANNEL --node-id N``: one module on a CAN bus, as a Linux-based module runs it.

The module itself — its objects, its gait, its e-stop — is asm_py.module (the program a module runs, whether its
joint is simulated or real); this is only its command line.
"""

from __future__ import annotations

import threading

from asm_py.module import FakeDriver, ModuleRuntime
from asm_py.node import Node


def main(argv: list[str] | None = None) -> int:
    """``asm-module --can INTERFACE:CHANNEL --node-id N``: one module on a CAN bus (a Linux-based module)."""
    import argparse
    import signal

    from asm_py.transport.can import CanTransport
    from server.bridge import parse_can
    from server.realtime import prefer_latency

    cli = argparse.ArgumentParser(prog="asm-module", description=main.__doc__.splitlines()[0] if main.__doc__ else "")
    cli.add_argument("--can", type=parse_can, required=True, metavar="INTERFACE:CHANNEL")
    cli.add_argument("--bitrate", type=int)
    cli.add_argument("--node-id", type=int, required=True, help="CAN node ID 1..254; also names the node m<ID>")
    cli.add_argument("--name", help="node name (default m<node-id>, what gaits.deploy expects)")
    cli.add_argument("--driver", choices=["fake"], default="fake", help="joint driver (fake: a servo model)")
    cli.add_argument("--limits", type=float, nargs=2, default=(-90.0, 90.0), metavar=("MIN", "MAX"))
    cli.add_argument("--rate", type=float, default=50.0, help="control ticks per second (default 50)")
    args = cli.parse_args(argv)
    prefer_latency()
    options = {**args.can, **({"bitrate": args.bitrate} if args.bitrate else {})}
    name = args.name or f"m{args.node_id}"
    node = Node(name, CanTransport(args.node_id, **options))
    runtime = ModuleRuntime(FakeDriver(), node=node, limits=tuple(args.limits), control_rate=args.rate)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    print(f"READY {name}", flush=True)
    done.wait()
    runtime.close()
    node.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
