"""The little of a 32-bit little-endian ELF file an emulator needs: what a flasher writes (the loadable segments, at
their load addresses) and where the symbols are.

Parsed with struct rather than a library: the board image is one format from one toolchain, and these 60 lines are
all the emulator (asm_module/emulator.py) reads of it.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Segment:
    """One loadable segment: ``data`` written at ``address`` (its load address: flash for initialised RAM, which
    the image's reset code copies), ``memory_size`` bytes reserved at ``virtual``."""

    address: int
    virtual: int
    data: bytes
    memory_size: int


@dataclass(frozen=True)
class Image:
    """A linked image: its entry point, segments and symbols (name to (address, size))."""

    entry: int
    segments: list[Segment]
    symbols: dict[str, tuple[int, int]]

    def symbol(self, name: str) -> int:
        """The address of ``name`` (a Thumb function's with its low bit clear); KeyError naming it if absent."""
        try:
            return self.symbols[name][0] & ~1
        except KeyError:
            raise KeyError(f"the image has no symbol {name!r}") from None


def read_image(path: Path) -> Image:
    """Parse ``path``; ValueError if it is not a 32-bit little-endian ARM executable."""
    raw = path.read_bytes()
    if raw[:6] != b"\x7fELF\x01\x01":
        raise ValueError(f"{path}: not a 32-bit little-endian ELF file")
    (machine,) = struct.unpack_from("<H", raw, 18)
    if machine != 40:  # EM_ARM
        raise ValueError(f"{path}: not an ARM image (machine {machine})")
    entry, phoff, shoff = struct.unpack_from("<III", raw, 24)
    phentsize, phnum, shentsize, shnum = struct.unpack_from("<HHHH", raw, 42)
    segments = []
    for k in range(phnum):
        kind, offset, vaddr, paddr, filesz, memsz = struct.unpack_from("<IIIIII", raw, phoff + k * phentsize)
        if kind == 1:  # PT_LOAD
            segments.append(Segment(paddr, vaddr, raw[offset : offset + filesz], memsz))
    sections = [struct.unpack_from("<IIIIIIIIII", raw, shoff + k * shentsize) for k in range(shnum)]
    symbols: dict[str, tuple[int, int]] = {}
    for _, kind, _, _, offset, size, link, _, _, entsize in sections:
        if kind != 2:  # SHT_SYMTAB
            continue
        strings = sections[link]
        names = raw[strings[4] : strings[4] + strings[5]]
        for at in range(offset, offset + size, entsize or 16):
            name_at, value, sym_size, _info, _other, _shndx = struct.unpack_from("<IIIBBH", raw, at)
            name = names[name_at : names.index(b"\0", name_at)].decode("ascii", "replace")
            if name and not name.startswith("$"):
                symbols.setdefault(name, (value, sym_size))
    return Image(entry, segments, symbols)
