"""Building the C module runtime (firmware/): the flags every build uses, the host library the Python binding loads,
and the Cortex-M4 image of the example board port.

The library is built from firmware/ with the system's C compiler when it is missing or older than its sources
(firmware/build/, ignored by git), so a fresh checkout needs nothing but gcc; the board image with Debian's
arm-none-eabi toolchain.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import zlib
from collections.abc import Callable
from pathlib import Path

FIRMWARE = Path(__file__).resolve().parent.parent / "firmware"
LIBRARY = FIRMWARE / "build" / "libasm_host.so"

C_FLAGS = ["-std=c11", "-Wall", "-Wextra", "-Werror", "-pedantic", f"-I{FIRMWARE / 'include'}"]
"""How every build of the firmware compiles it (the library, the board port, the test and fuzz programs)."""


HOST_FLAGS = ["-DASM_TABLE_BYTES=1400"]
"""The host library's limits beyond the defaults: a gait table of 1,400 bytes, a version-2 program of 64 states in
four modes (every gait of the library; a board keeps the default, a version-1 table of 64 states)."""


CONTRACT = FIRMWARE.parent / "contract"


def ensure_contract() -> None:
    """Regenerate the C headers of the wire contract when contract/*.toml changed: the C build always compiles what
    the contract says (contract/generate.py --headers). The Python copy and the doc are `make contract`'s: a build
    never rewrites them behind the developer's back, and the suite fails while they are stale."""
    generator = CONTRACT / "generate.py"
    if not generator.exists():  # an installed package without the repository: the headers are what they are
        return
    headers = [FIRMWARE / "include" / "asm" / name for name in ("contract.h", "profile.h")]
    newest = max(p.stat().st_mtime for p in (generator, *CONTRACT.glob("*.toml")))
    if all(h.exists() and h.stat().st_mtime >= newest for h in headers):
        return
    subprocess.run([sys.executable, str(generator), "--headers"], check=True, capture_output=True, text=True)


def build_id(*ports: str) -> int:
    """The build ID module.info reports (``-DASM_FW_BUILD``): the CRC-32 of the sources of a build with the port
    files ``ports`` (the runtime, those port files, the headers) by path and content, so two images report the same
    build exactly when they were built from the same sources (and a build is redone exactly when they change)."""
    port = FIRMWARE / "port"
    crc = 0
    for path in sorted([*runtime_sources(), *(port / p for p in ports), *(FIRMWARE / "include" / "asm").glob("*.h")]):
        crc = zlib.crc32(path.relative_to(FIRMWARE).as_posix().encode() + b"\0" + path.read_bytes(), crc)
    return crc


def stamp(*ports: str) -> str:
    """The compiler flag that stamps :func:`build_id` of a build with ``ports`` into it."""
    return f"-DASM_FW_BUILD={build_id(*ports):#x}u"


def runtime_sources() -> list[Path]:
    """The portable runtime (firmware/src/), without a port."""
    return sorted((FIRMWARE / "src").glob("*.c"))


def _sources() -> list[Path]:
    return [*runtime_sources(), FIRMWARE / "port" / "host.c"]


def build_library() -> Path:
    """firmware/build/libasm_host.so, compiled now if missing or older than a source or header."""
    ensure_contract()
    inputs = [*_sources(), *(FIRMWARE / "include" / "asm").glob("*.h")]
    flags = [*C_FLAGS, *HOST_FLAGS, stamp("host.c")]
    return _shared_library(LIBRARY, _sources(), inputs, flags, "the C module runtime")


CORTEX_CLOCK = FIRMWARE / "build" / "libasm_cortex_clock.so"
CORTEX_CLOCK_SOURCE = Path(__file__).resolve().parent / "cortex_clock.c"


def build_cortex_clock() -> Path:
    """firmware/build/libasm_cortex_clock.so, the emulator's per-block hook (asm_module/cortex_clock.c), compiled now
    if missing or older than its source."""
    return _shared_library(CORTEX_CLOCK, [CORTEX_CLOCK_SOURCE], [CORTEX_CLOCK_SOURCE],
                           ["-std=c11", "-Wall", "-Wextra", "-Werror"], "the emulator's clock")  # fmt: skip


def _shared_library(out: Path, sources: list[Path], inputs: list[Path], flags: list[str], what: str) -> Path:
    """``out`` compiled from ``sources`` with the system's C compiler (-O2, position-independent) if missing or
    older than one of ``inputs``, through a temporary file renamed after: parallel builds never clash."""
    if out.exists() and out.stat().st_mtime >= max(p.stat().st_mtime for p in inputs):
        return out
    out.parent.mkdir(exist_ok=True)
    fd, temporary = tempfile.mkstemp(dir=out.parent, suffix=".so")
    os.close(fd)
    try:
        subprocess.run([os.environ.get("CC", "gcc"), *flags, "-O2", "-fPIC", "-shared", *map(str, sources), "-lm",
                        "-o", temporary], check=True, capture_output=True, text=True)  # fmt: skip
        os.replace(temporary, out)
    except subprocess.CalledProcessError as exc:
        raise RuntimeError(f"building {what} failed:\n{exc.stderr}") from None
    finally:
        if os.path.exists(temporary):
            os.unlink(temporary)
    return out


CORTEX_M4_FLAGS = [
    *("-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16", "-ffunction-sections", "-fdata-sections"),
    *("-DASM_CAN_PARTIALS=1", "-DASM_CAN_MAX_MESSAGE=640", "-DASM_NODE_OUT=640"),
    "-fno-tree-loop-distribute-patterns",
]
"""A small module's limits: one reassembly slot of 640 bytes (a staged 64-state table is 597), replies as long. And
no loop turned into a library call: newlib's word-at-a-time strlen alone is 220 bytes, for names a few bytes long."""


PORT_SOURCES = ["stm32f4_bxcan.c", "stm32f4_update.c", "stm32f4_flash.c"]
"""The example port: the board (CAN, SysTick, joint, settings), the update objects, the flash driver and boot log."""


def build_cortex_m4(elf: Path, *, replace: dict[str, Path] | None = None,
                    flags: tuple[str, ...] = ()) -> tuple[int, int, int]:  # fmt: skip
    """Link the example STM32F4 port (firmware/port/; ``replace``: other files for some of its PORT_SOURCES by name,
    ``flags`` added: a test's broken port) with the runtime, -Os; its (text, data, bss) in bytes."""
    ensure_contract()
    replace = replace or {}
    sources = [*runtime_sources(), *(replace.get(name, FIRMWARE / "port" / name) for name in PORT_SOURCES)]
    _link(elf, sources, FIRMWARE / "port" / "stm32f4.ld", (stamp(*PORT_SOURCES), *flags))
    report = subprocess.run(["arm-none-eabi-size", str(elf)], capture_output=True, text=True, check=True)
    text, data, bss = (int(v) for v in report.stdout.splitlines()[1].split()[:3])
    return text, data, bss


def _link(elf: Path, sources: list[Path], script: Path, flags: tuple[str, ...] = ()) -> None:
    subprocess.run(["arm-none-eabi-gcc", *C_FLAGS, f"-I{FIRMWARE / 'port'}", "-Os", *CORTEX_M4_FLAGS, *flags,
                    *map(str, sources), "-nostartfiles", "--specs=nano.specs", "--specs=nosys.specs",
                    "-Wl,--gc-sections", f"-T{script}", "-lm", "-o", str(elf)], check=True, capture_output=True,
                   text=True)  # fmt: skip


def build_bootloader(elf: Path) -> tuple[int, int, int]:
    """Link the example port's bootloader (firmware/port/stm32f4_boot.c, sector 0); its (text, data, bss)."""
    ensure_contract()
    port = FIRMWARE / "port"
    _link(elf, [port / "stm32f4_boot.c", port / "stm32f4_flash.c", FIRMWARE / "src" / "wire.c"],
          port / "stm32f4_boot.ld")  # fmt: skip
    report = subprocess.run(["arm-none-eabi-size", str(elf)], capture_output=True, text=True, check=True)
    text, data, bss = (int(v) for v in report.stdout.splitlines()[1].split()[:3])
    return text, data, bss


def build_test_program(out: Path, program: str) -> Path:
    """``firmware/tests/<program>.c`` with the runtime, warnings as errors, under both sanitizers (the vector runner
    and the fuzz of the test suite and the benches)."""
    ensure_contract()
    sources = [*runtime_sources(), FIRMWARE / "tests" / f"{program}.c"]
    subprocess.run(["gcc", *C_FLAGS, "-O1", "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                    *map(str, sources), "-lm", "-o", str(out)], check=True, capture_output=True, text=True)  # fmt: skip
    return out


BOARD_IMAGE = FIRMWARE / "build" / "stm32f4.elf"
BOOTLOADER = FIRMWARE / "build" / "stm32f4_boot.elf"


def _inputs() -> list[Path]:
    port = FIRMWARE / "port"
    return [*runtime_sources(), *port.glob("stm32f4*"), *(FIRMWARE / "include" / "asm").glob("*.h")]


def _cached(out: Path, build: Callable[[Path], object]) -> Path:
    """``out``, built now with ``build`` if missing or older than a source, header or linker script (through a
    temporary file renamed after: parallel builds never clash)."""
    ensure_contract()
    if out.exists() and out.stat().st_mtime >= max(p.stat().st_mtime for p in _inputs()):
        return out
    out.parent.mkdir(exist_ok=True)
    fd, temporary = tempfile.mkstemp(dir=out.parent, suffix=".elf")
    os.close(fd)
    try:
        build(Path(temporary))
        os.replace(temporary, out)
    except subprocess.CalledProcessError as exc:
        raise RuntimeError(f"building {out.name} failed:\n{exc.stderr}") from None
    finally:
        if os.path.exists(temporary):
            os.unlink(temporary)
    return out


def build_board_image(version: int | None = None) -> Path:
    """firmware/build/stm32f4.elf, the example port's image (build_cortex_m4), linked now if missing or stale: what
    asm_module.emulated runs. ``version`` (0xMMmmpp) builds the same sources as another version
    (stm32f4-<version>.elf): an update to try."""
    if version is None:
        return _cached(BOARD_IMAGE, build_cortex_m4)
    if not 0 <= version <= 0xFFFFFF:
        raise ValueError(f"a firmware version is 0xMMmmpp, not {version:#x}")
    out = BOARD_IMAGE.with_name(f"stm32f4-{version:06x}.elf")
    return _cached(out, lambda elf: build_cortex_m4(elf, flags=(f"-DASM_FW_VERSION={version:#x}u",)))


def build_board_bootloader() -> Path:
    """firmware/build/stm32f4_boot.elf, the example port's bootloader, linked now if missing or stale."""
    return _cached(BOOTLOADER, build_bootloader)
