"""The C module runtime (firmware/, issue 17): hostile input at scale, and its size.

    .venv/bin/python bench/firmware.py

Builds firmware/tests/fuzz.c with AddressSanitizer and UndefinedBehaviorSanitizer and feeds it 10 million random
and mutated frames, messages and gait tables; then reports the code and data size of the firmware sources built
with -Os for this host (and for a Cortex-M4 when arm-none-eabi-gcc is installed).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FIRMWARE = ROOT / "firmware"
INPUTS = 10_000_000


def sources() -> list[str]:
    return [str(p) for p in sorted((FIRMWARE / "src").glob("*.c"))]


def fuzz(workdir: Path) -> tuple[int, float]:
    binary = workdir / "fuzz"
    subprocess.run(["gcc", "-std=c11", "-O1", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                    f"-I{FIRMWARE / 'include'}", *sources(), str(FIRMWARE / "tests" / "fuzz.c"), "-lm", "-o",
                    str(binary)], check=True)  # fmt: skip
    began = time.perf_counter()
    result = subprocess.run([str(binary), str(INPUTS), "1"], capture_output=True, text=True)
    seconds = time.perf_counter() - began
    print(f"# {result.stdout.strip()} ({seconds:.1f} s)")
    if result.returncode != 0 or "runtime error" in result.stderr:
        print(result.stderr[-2000:], file=sys.stderr)
        return 0, seconds
    return INPUTS, seconds


def size(compiler: str, flags: list[str], workdir: Path, tag: str) -> None:
    objects = []
    for source in sources():
        obj = workdir / f"{tag}-{Path(source).stem}.o"
        subprocess.run([compiler, "-std=c11", "-Os", *flags, f"-I{FIRMWARE / 'include'}", "-c", source, "-o",
                        str(obj)], check=True)  # fmt: skip
        objects.append(str(obj))
    tool = compiler.replace("gcc", "size")
    report = subprocess.run([tool if shutil.which(tool) else "size", *objects], capture_output=True, text=True)
    text = data = bss = 0
    for line in report.stdout.splitlines()[1:]:
        fields = line.split()
        text, data, bss = text + int(fields[0]), data + int(fields[1]), bss + int(fields[2])
    print(f"# {tag}: flash (text + data) {text + data} bytes, RAM (data + bss) {data + bss} bytes "
          f"(one reassembler of ASM_CAN_PARTIALS slots is the caller's: see firmware/include/asm/can.h)")  # fmt: skip


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        fed, seconds = fuzz(workdir)
        size("gcc", [], workdir, "host x86-64")
        if shutil.which("arm-none-eabi-gcc"):
            size("arm-none-eabi-gcc", ["-mcpu=cortex-m4", "-mthumb"], workdir, "Cortex-M4")
        else:
            print("# Cortex-M4: arm-none-eabi-gcc is not installed here (issue 17 still has to install it)")
    print(f"ratio firmware_fuzz_inputs_vs_10M {fed / INPUTS:.2f} (target >= 1)")


if __name__ == "__main__":
    main()
