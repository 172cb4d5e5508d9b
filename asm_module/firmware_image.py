"""The update image (docs/protocol.md §12): what a slot holds and ``asm-flash`` sends — the linked image's RAM-code
bytes from 0x20000000, its 128-byte header completed with the size and the CRC-32 that the linker cannot compute.

The header the C image carries (firmware/port/stm32f4_update.c: magic, versions, load address) is kept as linked;
only ``size`` and ``crc`` are filled in here, so what the bootloader checks is what the compiler wrote.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

from ._profile import IMAGE_HEADER_SIZE, IMAGE_HEADER_VERSION, IMAGE_MAGIC
from .elf import Image, read_image

LOAD_ADDRESS = 0x20000000
MAX_SIZE = 64 << 10
"""The RAM an image runs from (firmware/port/stm32f4_layout.h): no image is larger."""
_FIELDS = struct.Struct("<IIHHIII")


class ImageError(ValueError):
    """Bytes that are not an update image (wrong magic, header, size or CRC)."""


@dataclass(frozen=True)
class ImageInfo:
    """An image's header as read: its version (0xMMmmpp), size in bytes and CRC-32."""

    version: int
    size: int
    crc: int

    @property
    def version_text(self) -> str:
        return version_text(self.version)


def version_text(version: int) -> str:
    """0xMMmmpp as ``M.m.p``."""
    return f"{version >> 16 & 0xFF}.{version >> 8 & 0xFF}.{version & 0xFF}"


def image_bytes(image: Image, *, pad_to: int = 0) -> bytes:
    """The update image of a linked ELF (its segments loaded between 0x20000000 and +64 KiB), with ``size`` and
    ``crc`` filled in; ``pad_to`` bytes at least (zeros appended, covered by the CRC: a larger image to measure)."""
    parts = sorted((s.address, s.data) for s in image.segments if LOAD_ADDRESS <= s.address < LOAD_ADDRESS + MAX_SIZE)
    if not parts or parts[0][0] != LOAD_ADDRESS:
        raise ImageError("the ELF has nothing linked at 0x20000000: not an image for the bootloader")
    end = max(address + len(data) for address, data in parts) - LOAD_ADDRESS
    raw = bytearray(max(end, pad_to))
    for address, data in parts:
        raw[address - LOAD_ADDRESS : address - LOAD_ADDRESS + len(data)] = data
    raw += bytes(-len(raw) % 4)
    if len(raw) > MAX_SIZE:
        raise ImageError(f"an image is at most {MAX_SIZE} bytes, this one {len(raw)}")
    struct.pack_into("<I", raw, 16, len(raw))
    struct.pack_into("<I", raw, 4, zlib.crc32(raw[8:]))
    check(bytes(raw))
    return bytes(raw)


def elf_image(path: Path, *, pad_to: int = 0) -> bytes:
    """:func:`image_bytes` of the ELF file ``path``."""
    return image_bytes(read_image(path), pad_to=pad_to)


def check(data: bytes) -> ImageInfo:
    """The header of ``data`` if it is a whole image (what the bootloader and firmware.install check); ImageError
    naming what is wrong otherwise."""
    if data[:4] == b"\x7fELF":  # the linker's output, not what a module takes: say how to make one
        raise ImageError("an ELF file, not an update image: make one with python -m asm_module.firmware_image ELF OUT")
    if len(data) < IMAGE_HEADER_SIZE:
        raise ImageError(f"not an update image: {len(data)} bytes, shorter than an image header ({IMAGE_HEADER_SIZE})")
    magic, crc, header_version, header_size, version, size, load = _FIELDS.unpack_from(data)
    if magic != IMAGE_MAGIC:
        raise ImageError(f"not an update image (its first bytes are not the image magic: {magic:#010x})")
    if (header_version, header_size, load) != (IMAGE_HEADER_VERSION, IMAGE_HEADER_SIZE, LOAD_ADDRESS):
        raise ImageError(f"header version {header_version}, size {header_size}, load address {load:#x}: not this "
                         f"bootloader's (version {IMAGE_HEADER_VERSION})")  # fmt: skip
    if len(data) > MAX_SIZE:
        raise ImageError(f"{len(data):,} bytes: an image is at most {MAX_SIZE:,} bytes (the RAM a module runs it "
                         "from)")  # fmt: skip
    if size != len(data):
        raise ImageError(f"the file has {len(data):,} bytes, its header says the image has {size:,}: cut short "
                         "or with bytes appended")  # fmt: skip
    if size % 4:
        raise ImageError(f"{size:,} bytes: an image is a whole number of 4-byte words")
    if zlib.crc32(data[8:]) != crc:
        raise ImageError(f"CRC-32 {zlib.crc32(data[8:]):#010x}, the header says {crc:#010x}: the image is damaged")
    return ImageInfo(version, size, crc)


def main(argv: list[str] | None = None) -> int:
    """``python -m asm_module.firmware_image ELF OUT``: the update image of a linked ELF, for asm-flash."""
    import argparse

    cli = argparse.ArgumentParser(prog="python -m asm_module.firmware_image", description=main.__doc__)
    cli.add_argument("elf", type=Path)
    cli.add_argument("out", type=Path)
    args = cli.parse_args(argv)
    data = elf_image(args.elf)
    args.out.write_bytes(data)
    info = check(data)
    print(f"{args.out}: version {info.version_text}, {info.size} bytes, CRC-32 {info.crc:08x}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
