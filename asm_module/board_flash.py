"""A board's flash as a debug probe first writes it (the bootloader, the board data, the first image: docs/protocol.md
§12), and the images the emulator knows the symbols of, by their CRC-32, as a debugger finds an image's ELF."""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable
from pathlib import Path

from ._profile import IMAGE_HEADER_SIZE
from .elf import Image, Segment, read_image
from .firmware_image import LOAD_ADDRESS, MAX_SIZE, image_bytes
from .flash import BASE, SIZE, Settings

SLOT_A = 0x08020000
"""Where the probe writes the first image (firmware/port/stm32f4_layout.h)."""

_images: dict[int, tuple[Image, int]] = {}
"""Linked images by the CRC-32 of their code and data past the header (what runs, whatever padding or header an
update image adds), with its length: the symbols the emulator measures and calls a running image by, as a debugger
finds an image's ELF (asm_module.emulated registers the board image and every image it builds)."""
VECTORS = 0x80
"""Where an image's vector table starts, past its header (firmware/port/stm32f4.ld)."""
VECTOR_COUNT = 16
PROBE = VECTORS + 4 * VECTOR_COUNT
"""Where asm_probe is: the linker script puts its section right after the vector table, in every image."""
PROBE_VERSION = 3
PROBE_SIZE = 60
_bootloader: Image | None = None
_built: set[tuple[Path, float]] = set()
"""The built images (path, modification time) read by :func:`known_image`'s search."""


def register_image(image: Image) -> None:
    """Make ``image``'s symbols known to every core that boots it."""
    body = image_bytes(image)[IMAGE_HEADER_SIZE:]
    _images[zlib.crc32(body)] = (image, len(body))


def bootloader() -> Image:
    """The example port's bootloader (built once per process)."""
    global _bootloader
    if _bootloader is None:
        from .firmware_build import build_board_bootloader

        _bootloader = read_image(build_board_bootloader())
    return _bootloader


def probe_flash(settings: Settings, image: Image) -> None:
    """Write a fresh board's flash as a debug probe does once: the bootloader in sector 0, the board data the image
    links in sector 1 (its defaults), the image in slot A."""
    boot = bootloader()
    for segment in [*boot.segments, *image.segments]:
        if segment.data and BASE <= segment.address < BASE + SIZE:
            settings.write(segment.address - BASE, segment.data)
    settings.write(SLOT_A - BASE, image_bytes(image))


def known_images() -> list[Image]:
    """Every image registered so far."""
    return [image for image, _ in _images.values()]


def known_image(read: Callable[[int, int], bytes]) -> Image | None:
    """The registered image that runs, if any: ``read(offset, length)`` reads the image in RAM from its start. An
    image not registered in this process (one a tool built and sent over the bus, as the studio's Modules tab
    does) is looked for among the board images built in firmware/build, as a debugger finds an ELF by its build."""
    for attempt in range(2):
        for crc, (image, length) in list(_images.items()):
            if zlib.crc32(read(IMAGE_HEADER_SIZE, length)) == crc:
                return image
        if attempt == 0 and not _register_built():
            break
    return image_without_elf(read)


def image_without_elf(read: Callable[[int, int], bytes]) -> Image | None:
    """What the emulator needs of an image whose ELF it has not (built elsewhere, or patched), from the image
    itself, as the linker script lays out every image: the probe right after the vector table, the fault handler
    where the table's unused exceptions point (NMI's entry). The control tick's address is not there: such an
    image runs and is measured by its own module.info, not by the emulator's cycles per tick. None when the
    bytes are not laid out so (another probe version, a table pointing outside the image): the board stops, as
    a debugger without symbols would leave it."""
    size = struct.unpack("<I", read(16, 4))[0]
    if not PROBE + PROBE_SIZE <= size <= MAX_SIZE:
        return None
    vectors = struct.unpack(f"<{VECTOR_COUNT}I", read(VECTORS, 4 * VECTOR_COUNT))
    probe = struct.unpack("<I", read(PROBE, 4))[0]
    fault = vectors[2] & ~1
    inside = all(LOAD_ADDRESS <= v & ~1 < LOAD_ADDRESS + size for v in (vectors[1], vectors[2], vectors[3]))
    if probe != PROBE_VERSION or not inside or vectors[3] & ~1 != fault:
        return None
    body = read(IMAGE_HEADER_SIZE, size - IMAGE_HEADER_SIZE)
    image = Image(vectors[1], [Segment(LOAD_ADDRESS, LOAD_ADDRESS, read(0, size), size)],
                  {"asm_probe": (LOAD_ADDRESS + PROBE, PROBE_SIZE), "Default_Handler": (fault, 0)})  # fmt: skip
    _images[zlib.crc32(body)] = (image, len(body))  # the next boot of any board finds it as a registered one
    return image


def _register_built() -> int:
    """Register the board images built in firmware/build (stm32f4*.elf) not read yet; how many were new."""
    from .firmware_build import BOARD_IMAGE

    new = 0
    for path in sorted(BOARD_IMAGE.parent.glob("stm32f4*.elf")):
        if path.name.startswith("stm32f4_boot"):
            continue
        try:
            seen = (path, path.stat().st_mtime)  # a file rebuilt under the same name is read again
            if seen in _built:
                continue
            image = read_image(path)
        except (OSError, ValueError):  # a build being written or removed, or not an ELF: not this one
            continue
        register_image(image)
        _built.add(seen)
        new += 1
    return new
