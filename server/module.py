"""``asm-module --can INTERFACE:CHANNEL --node-id N``: one module on a CAN bus, as a Linux-based module runs it.

``--id-file PATH`` instead of ``--node-id``: the module's serial and node ID live in that file (made with a random
serial and no ID if missing); without an ID it boots unconfigured and waits to be numbered by ``asm-commission``
(asm_module/commissioning.py), and keeps the ID it is given across restarts.

``--type NAME`` is what its ``module.type`` reports: its type's name, as a gait's robot description names it, so a
deploy can tell a robot of other modules (gaits/compatible.py).

``--calibration-file PATH`` keeps its joint.calibration (zero, direction, soft limits) across restarts; with
``--id-file`` it defaults to the file next to it (``<id-file>.calibration.json``, asm_module/commissioning.py).

The module itself — its objects, its gait, its e-stop — is asm_module (the program a module runs, whether its
joint is simulated or real); this is only its command line.
"""

from __future__ import annotations

import argparse

import can

from asm_module import FakeDriver, ModuleRuntime
from asm_module.calibration import CalibrationFile, check_module_type
from asm_module.commissioning import CommissionedModule, IdFile, calibration_path
from asm_py.cli import (
    bitrate,
    bounded,
    can_channel,
    close_and_exit,
    name,
    node_id,
    output_file,
    rate,
    run,
    stop_requested,
    summary,
)
from asm_py.node import Node
from asm_py.transport.can import CanTransport
from server.realtime import prefer_latency

HARDWARE_RANGE = (-90.0, 90.0)
"""The joint's range (ModuleRuntime's default): what a stored calibration is checked against."""


def main(argv: list[str] | None = None) -> int:
    """``asm-module --can INTERFACE:CHANNEL --node-id N``: one module on a CAN bus (a Linux-based module)."""
    cli = argparse.ArgumentParser(prog="asm-module", description=summary(main.__doc__))
    cli.add_argument("--can", type=can_channel, required=True, metavar="INTERFACE:CHANNEL")
    cli.add_argument("--bitrate", type=bitrate)
    identity = cli.add_mutually_exclusive_group(required=True)
    identity.add_argument("--node-id", type=node_id, help="CAN node ID 1..254; also names the node m<ID>")
    identity.add_argument("--id-file", type=output_file, metavar="PATH",
                          help="the module's serial and commissioned node ID (asm-commission numbers it)")  # fmt: skip
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
    cli.add_argument("--calibration-file", type=output_file, metavar="PATH",
                     help="where the joint's calibration is kept (default with --id-file: next to it)")  # fmt: skip
    cli.add_argument("--rate", type=rate, default=50.0, help="control ticks per second (default 50)")
    cli.add_argument("--type", type=_module_type, default="", metavar="NAME",
                     help="the module's type, as a gait's robot description names it ([robot.types.NAME]): what its "
                     "module.type reports (default: none said)")  # fmt: skip
    args = cli.parse_args(argv)
    if not args.limits[0] < args.limits[1]:
        cli.error(f"--limits: MIN must be below MAX, not {args.limits[0]:g} {args.limits[1]:g}")
    return run(cli.prog, lambda: _serve(args))


def _module_type(text: str) -> str:
    try:
        return check_module_type(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _serve(args: argparse.Namespace) -> int:
    prefer_latency()
    options = {**args.can, **({"bitrate": args.bitrate} if args.bitrate else {})}
    if args.id_file is not None:
        return _serve_commissioned(args, options)
    store = CalibrationFile(args.calibration_file) if args.calibration_file is not None else None
    if store is not None:
        store.load(HARDWARE_RANGE)  # a damaged file is refused before the bus is opened
    name = args.name or f"m{args.node_id}"
    node = Node(name, CanTransport(args.node_id, **options))
    runtime = ModuleRuntime(FakeDriver(), node=node, limits=tuple(args.limits), control_rate=args.rate,
                            calibration_store=store, module_type=args.type)  # fmt: skip
    done = stop_requested()
    print(f"READY {name}", flush=True)
    done.wait()

    def close() -> None:
        runtime.close()
        node.close()

    close_and_exit(close, "asm-module")


def _serve_commissioned(args: argparse.Namespace, options: dict) -> int:
    store = CalibrationFile(args.calibration_file or calibration_path(args.id_file))
    store.load(HARDWARE_RANGE)  # a damaged file is refused before the bus is opened

    def runtime(node: Node, module_id: int) -> ModuleRuntime:
        return ModuleRuntime(FakeDriver(), node=node, limits=tuple(args.limits), control_rate=args.rate,
                             module_id=module_id, calibration_store=store, module_type=args.type)  # fmt: skip

    module = CommissionedModule(IdFile(args.id_file), lambda: can.Bus(**options), runtime=runtime)
    done = stop_requested()
    print(f"READY serial {module.serial.hex()} node ID {module.node_id or 'none'}", flush=True)
    done.wait()
    close_and_exit(module.close, "asm-module")


if __name__ == "__main__":
    raise SystemExit(main())
