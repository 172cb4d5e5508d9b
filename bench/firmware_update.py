"""Firmware update over the bus (issue 28, docs/protocol.md §12): 8 emulated boards updated at once with a 32 KiB
image each, wall time over what a 1 Mbit/s classic CAN bus needs to carry those bytes with ASM's framing.

    .venv/bin/python bench/firmware_update.py      (bench/firmware.py runs it too)

The bus limit is computed from the frame format: each 512-byte piece is one SET request of 4 (header) + 1 (timeout
byte) + 4 (offset) + 512 bytes, fragmented as asm_py/canbus/fragments.py does (a FIRST frame with the 4-byte
preamble, then 8 bytes a frame), answered by one 4-byte reply frame; a classic extended data frame of n bytes is
67 + 8n bits on the wire (SOF, 29-bit identifier with SRR, IDE and RTR, control, data, CRC, delimiters, ACK, EOF,
intermission), bit stuffing left out: the limit is the least time the bus could take (stuffing adds up to ~20%).
The install, status reads and resets are not counted in the limit (they are in the wall time).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

MODULES = 8
IMAGE_BYTES = 32 * 1024
BITRATE = 1_000_000


def frame_bits(data_bytes: int) -> int:
    """A classic CAN data frame with a 29-bit identifier and ``data_bytes`` bytes, without stuffing bits."""
    return 67 + 8 * data_bytes


def bus_seconds(image_bytes: int, modules: int) -> float:
    """What the pieces of ``modules`` updates and their replies take on the bus at BITRATE."""
    from asm_module._profile import IMAGE_CHUNK
    from asm_py.canbus.fragments import fragment
    from asm_py.protocol import HEADER_SIZE

    bits = 0
    for offset in range(0, image_bytes, IMAGE_CHUNK):
        piece = min(IMAGE_CHUNK, image_bytes - offset)
        message = bytes(HEADER_SIZE + 1 + 4 + piece)
        bits += sum(frame_bits(len(data)) for _, _, data in fragment(message)) + frame_bits(HEADER_SIZE)
    return bits * modules / BITRATE


def update_modules_at_once(modules: int = MODULES) -> tuple[float, float, list[str]]:
    """(wall seconds, bus-limit seconds, each module's report line) for ``modules`` boards."""
    from asm_module.emulated import EmulatedModule, versioned_image
    from asm_module.firmware_image import image_bytes
    from asm_module.flash import Settings
    from asm_module.flasher import update_modules
    from asm_py.node import Node
    from asm_py.transport.can import CanTransport

    image = image_bytes(versioned_image(0x000200), pad_to=IMAGE_BYTES)
    channel = f"bench-fwupdate-{time.monotonic_ns()}"
    boards = [EmulatedModule(f"m{k}", k, settings=Settings(), interface="virtual", channel=channel)
              for k in range(1, modules + 1)]  # fmt: skip
    tool = Node("tool", CanTransport(100, interface="virtual", channel=channel, missed_heartbeats=10))
    try:
        names = [f"m{k}" for k in range(1, modules + 1)]
        deadline = time.monotonic() + 60
        while not set(names) <= set(tool.discover()) and time.monotonic() < deadline:
            time.sleep(0.1)
        began = time.perf_counter()
        results = update_modules(tool, names, image, timeout=20, reboot_timeout=60)
        wall = time.perf_counter() - began
    finally:
        tool.close()
        for board in boards:
            board.close()
    return wall, bus_seconds(len(image), modules), [str(r) for r in results]


def main(argv: list[str] | None = None) -> None:
    """``--modules N`` (default 8): fewer boards, for a machine that cannot run eight in real time (then the ratio
    printed is named for N and is not the figure)."""
    args = sys.argv[1:] if argv is None else argv
    modules = int(args[args.index("--modules") + 1]) if "--modules" in args else MODULES
    wall, limit, lines = update_modules_at_once(modules)
    for line in lines:
        print(f"# {line}")
    print(f"# {modules} modules x {IMAGE_BYTES} bytes: {wall:.1f} s wall; a 1 Mbit/s bus needs {limit:.2f} s")
    ok = all(": updated" in line for line in lines)
    print(f"ratio firmware_update_{modules}_modules_s_vs_bus_limit {wall / limit if ok else float('inf'):.2f} "
          "(target <= 2)")  # fmt: skip


if __name__ == "__main__":
    main()
