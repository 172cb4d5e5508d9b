"""``asm-flash --robot INTERFACE:CHANNEL --modules all|odd|even|1,3 image.bin``: update the firmware of a robot's
modules over its CAN bus (docs/protocol.md §12), all at once, with a progress bar; each module's old and new version.

    asm-flash --robot socketcan:can0 --modules all firmware/build/stm32f4.img
    asm-flash --robot socketcan:can0 --modules 1,3 --bitrate 1000000 module.img

The image is an update image (``python -m asm_module.firmware_image ELF OUT`` makes one from a linked ELF). Each
module writes it into its inactive slot, checks it, resets into it and confirms it; a module that refuses it, or
whose new image does not confirm itself, keeps running its old one and is reported so (exit 1). Modules without
firmware objects (Python modules) are reported as skipped.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path
from typing import TextIO

from asm_module.firmware_image import check
from asm_py.cli import bitrate, can_channel, input_file, module_selection, node_id, positive_seconds, run, summary
from asm_py.node import Node
from asm_py.transport.can import CanTransport
from gaits.update import update_robot


class ProgressBar:
    """One line on ``out``, redrawn at most 10 times a second: the bytes written to every module over their total."""

    def __init__(self, modules: list[str], size: int, out: TextIO) -> None:
        self.done = dict.fromkeys(modules, 0)
        self.size, self.out = size, out
        self._lock = threading.Lock()
        self._drawn = 0.0

    def __call__(self, module: str, done: int, _total: int) -> None:
        with self._lock:
            self.done[module] = done
            now = time.monotonic()
            if now - self._drawn >= 0.1 or all(d == self.size for d in self.done.values()):
                self._drawn = now
                self.draw()

    def finish(self, written: set[str]) -> None:
        """The last line over the modules that were written to (one skipped or refused before a byte counts no more:
        the bar ended at 62.9 % with a tool node in the total)."""
        with self._lock:
            self.done = {m: d for m, d in self.done.items() if m in written} or self.done
            self.draw()

    def draw(self) -> None:
        fraction = sum(self.done.values()) / (self.size * len(self.done))
        bar = "#" * round(30 * fraction)
        self.out.write(f"\r[{bar:<30}] {100 * fraction:5.1f}%  {len(self.done)} modules x {self.size} bytes")
        self.out.flush()


def select(transport: CanTransport, selection: tuple[int, ...] | str) -> tuple[list[str], list[int]]:
    """The node names the selection means on the bus now, and the IDs it names that are not there."""
    present = {
        i: n
        for n in transport.peers()
        if n != transport.name and (i := transport.resolve(n)) is not None and n == f"m{i}"
    }  # modules, not tools
    if isinstance(selection, str):
        wanted = [i for i in sorted(present) if selection == "all" or (i % 2 == 1) == (selection == "odd")]
        return [present[i] for i in wanted], []
    return [present[i] for i in selection if i in present], [i for i in selection if i not in present]


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-flash", description=summary(__doc__),
                                  formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    cli.add_argument("--robot", type=can_channel, required=True, metavar="INTERFACE:CHANNEL",
                     help="the robot's CAN bus (python-can interface and channel)")  # fmt: skip
    cli.add_argument("--bitrate", type=bitrate)
    cli.add_argument("--fd", action="store_true", help="a CAN FD bus")
    cli.add_argument("--modules", type=module_selection, default="all", help="all (default), odd, even or IDs: 1,3")
    cli.add_argument("--node-id", type=node_id, default=253, help="the tool's own CAN node ID (default 253)")
    cli.add_argument("--discover", type=positive_seconds, default=1.5,
                     help="seconds to listen for the modules' heartbeats first (default 1.5)")  # fmt: skip
    cli.add_argument("--timeout", type=positive_seconds, default=10.0,
                     help="seconds each request may take (default 10)")  # fmt: skip
    cli.add_argument("--reboot-timeout", type=positive_seconds, default=30.0,
                     help="seconds a module may take to come back running the new image (default 30)")  # fmt: skip
    cli.add_argument("image", type=input_file)
    args = cli.parse_args(argv)
    return run(cli.prog, lambda: _flash(args))


def _flash(args: argparse.Namespace) -> int:
    image = Path(args.image).read_bytes()
    info = check(image)  # not an image: an error before the bus is touched
    options = {**args.robot, **({"bitrate": args.bitrate} if args.bitrate else {}), **({"fd": True} if args.fd else {})}
    # a board erasing a slot (1-2 s on an STM32F4) or checking an image is silent for a while: not gone
    transport = CanTransport(args.node_id, missed_heartbeats=10, **options)
    node = Node("asm-flash", transport)
    try:
        time.sleep(args.discover)
        modules, missing = select(transport, args.modules)
        for module_id in missing:
            print(f"m{module_id}: not on the bus", file=sys.stderr)
        if not modules:
            raise RuntimeError("no module to update on the bus")
        print(f"updating {', '.join(modules)} to {info.version_text} ({info.size} bytes, CRC-32 {info.crc:08x})")
        bar = ProgressBar(modules, info.size, sys.stderr)
        results = update_robot(node, modules, image, progress=bar, timeout=args.timeout,
                                 reboot_timeout=args.reboot_timeout)  # fmt: skip
        bar.finish({m for m, done in bar.done.items() if done})
        print(file=sys.stderr)
    finally:
        node.close()
    for result in results:
        print(result)
    good = ("updated", "skipped")
    return 0 if not missing and all(r.outcome in good for r in results) else 1


if __name__ == "__main__":
    raise SystemExit(main())
