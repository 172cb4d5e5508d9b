"""A board's flash as a debug probe first writes it (the bootloader, the board data, the first image: docs/protocol.md
§12), and the images the emulator knows the symbols of, by their CRC-32, as a debugger finds an image's ELF."""

from __future__ import annotations

import zlib
from collections.abc import Callable
from pathlib import Path

from ._profile import IMAGE_HEADER_SIZE
from .elf import Image, read_image
from .firmware_image import image_bytes
from .flash import BASE, SIZE, Settings

SLOT_A = 0x08020000
"""Where the probe writes the first image (firmware/port/stm32f4_layout.h)."""

_images: dict[int, tuple[Image, int]] = {}
"""Linked images by the CRC-32 of their code and data past the header (what runs, whatever padding or header an
update image adds), with its length: the symbols the emulator measures and calls a running image by, as a debugger
finds an image's ELF (asm_module.emulated registers the board image and every image it builds)."""
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
    return None


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
