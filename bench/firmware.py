"""The C module runtime (firmware/, issue 17): hostile input at scale, and its size.

    .venv/bin/python bench/firmware.py

Builds firmware/tests/fuzz.c with AddressSanitizer and UndefinedBehaviorSanitizer and feeds it 10 million random
and mutated frames, messages, gait tables and module requests; links the example Cortex-M4 port
(firmware/port/stm32f4_bxcan.c, -Os, one 640-byte reassembly slot) and reads its flash and RAM with
arm-none-eabi-size (`make test` installs Debian's gcc-arm-none-eabi); and times remote gets answered by a C module
and by a Python module on one python-can virtual bus, in the same run.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# bench/ holds a can.py: keep this directory off the path, or "import can" would import that script.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != ROOT / "bench"]
sys.path.insert(0, str(ROOT))

from asm_py.firmware import C_FLAGS, runtime_sources  # noqa: E402
from tests.test_firmware import build  # noqa: E402

INPUTS = 10_000_000


def fuzz(workdir: Path) -> tuple[int, float]:
    binary = build(workdir / "fuzz", "fuzz")  # the test suite's build: both sanitizers, warnings as errors
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
    for source in runtime_sources():
        obj = workdir / f"{tag}-{source.stem}.o"
        subprocess.run([compiler, *C_FLAGS, "-Os", *flags, "-c", str(source), "-o", str(obj)], check=True)
        objects.append(str(obj))
    tool = compiler.replace("gcc", "size")
    report = subprocess.run([tool if shutil.which(tool) else "size", *objects], capture_output=True, text=True)
    text = data = bss = 0
    for line in report.stdout.splitlines()[1:]:
        fields = line.split()
        text, data, bss = text + int(fields[0]), data + int(fields[1]), bss + int(fields[2])
    print(f"# {tag}: flash (text + data) {text + data} bytes, RAM (data + bss) {data + bss} bytes "
          f"(one reassembler of ASM_CAN_PARTIALS slots is the caller's: see firmware/include/asm/can.h)")  # fmt: skip


def cortex_m4(workdir: Path) -> tuple[int, int]:
    """(flash, RAM) bytes of the example STM32F4 port linked with the runtime: text + data, data + bss."""
    from asm_py.firmware import build_cortex_m4

    text, data, bss = build_cortex_m4(workdir / "m4.elf")
    print(f"# Cortex-M4 (STM32F4 example port, -Os): text {text}, data {data}, bss {bss} bytes")
    return text + data, data + bss


def gets_per_second(remote: object, count: int) -> float:
    began = time.perf_counter()
    for _ in range(count):
        remote.peek()  # type: ignore[attr-defined]
    return count / (time.perf_counter() - began)


def c_vs_python_gets() -> float:
    """Remote gets of joint.goal per second from a C module over a Python module, one virtual bus, rounds alternated."""
    from asm_py.firmware import CModule
    from asm_py.module.runtime import FakeDriver, ModuleRuntime
    from asm_py.node import Node
    from asm_py.transport.can import CanTransport

    channel = f"bench-firmware-{time.monotonic_ns()}"
    c_module = CModule("c1", 5, interface="virtual", channel=channel)
    python_node = Node("p1", CanTransport(6, interface="virtual", channel=channel, watch_bus=False))
    runtime = ModuleRuntime(FakeDriver(), node=python_node, module_id=6)
    client = Node("bench", CanTransport(100, interface="virtual", channel=channel, heartbeat_period=0.1))
    try:
        while not {"c1", "p1"} <= set(client.discover()):
            time.sleep(0.05)
        remotes = {name: client.lookup(name, "joint.goal", timeout=5) for name in ("c1", "p1")}
        rates: dict[str, list[float]] = {"c1": [], "p1": []}
        for _ in range(5):
            for name, remote in remotes.items():
                rates[name].append(gets_per_second(remote, 400))
        c_rate, p_rate = (sorted(rates[n])[2] for n in ("c1", "p1"))
        print(
            f"# remote gets per second (median of 5 rounds of 400): C module {c_rate:.0f}, Python module {p_rate:.0f}"
        )
        return c_rate / p_rate
    finally:
        client.close()
        runtime.close()
        python_node.close()
        c_module.close()


def vectors_reproduced(workdir: Path) -> tuple[int, int]:
    """(reproduced, present) over every golden vector in tests/vectors/: messages, CAN frames and codecs by the C
    runner (codecs both ways: the bytes checked against the descriptor, the value encoded to them), module objects
    by a C module on a virtual bus."""
    from asm_py.firmware import CModule
    from tests.test_c_module import reproduce_module_object_vectors
    from tests.test_firmware import _can_vector_lines, _codec_lines, _message_lines

    lines = _message_lines() + _can_vector_lines() + _codec_lines()
    runner = build(workdir / "vectors", "vectors")
    out = subprocess.run([str(runner)], input="\n".join(lines) + "\n", capture_output=True, text=True).stdout
    wire = len(lines) if out.strip() == f"ok {len(lines)} failed 0" else 0
    channel = f"bench-vectors-{time.monotonic_ns()}"
    module = CModule("c1", 5, interface="virtual", channel=channel)
    try:
        objects = reproduce_module_object_vectors(module, channel)
    finally:
        module.close()
    missing = sorted(name for name, ok in objects.items() if not ok)
    print(f"# golden vectors: {wire} of {len(lines)} messages, CAN frames and codecs; {len(objects) - len(missing)} "
          f"of {len(objects)} module objects (not: {', '.join(missing)})")  # fmt: skip
    return wire + len(objects) - len(missing), len(lines) + len(objects)


def mixed_vs_python() -> float:
    """Distance of the caterpillar with modules 1, 3, 5, 7 in C over the all-Python one, each deployed to its own
    robot process and measured over the same 10 s of wall time (bench/robot.py's live distance)."""
    from bench.robot import live_distance
    from gaits.model import LIBRARY

    path = LIBRARY / "caterpillar.toml"
    python = live_distance(path)
    mixed = live_distance(path, "--c-modules", "odd")
    print(f"# caterpillar in 10 s of wall time: {python:.3f} m all Python, {mixed:.3f} m with modules 1, 3, 5, 7 in C")
    return mixed / python if python > 0 else 0.0


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        fed, seconds = fuzz(workdir)
        size("gcc", [], workdir, "host x86-64")
        m4 = cortex_m4(workdir) if shutil.which("arm-none-eabi-gcc") else None
        reproduced, present = vectors_reproduced(workdir)
    gets = c_vs_python_gets()
    mixed = mixed_vs_python()
    print(f"ratio firmware_fuzz_inputs_vs_10M {fed / INPUTS:.2f} (target >= 1)")
    print(f"ratio c_fuzz_inputs_vs_10m {fed / INPUTS:.2f} (target >= 1)")
    if m4 is None:
        print("# Cortex-M4: arm-none-eabi-gcc is not installed (make test installs it)")
    else:
        print(f"ratio c_runtime_flash_vs_16k {m4[0] / 16384:.2f} (target <= 1)")
        print(f"ratio c_runtime_ram_vs_8k {m4[1] / 8192:.2f} (target <= 1)")
    print(f"ratio c_vectors_reproduced {reproduced / present:.2f} (target == 1)")
    print(f"ratio c_module_gets_vs_python_module {gets:.2f} (target >= 1.5)")
    print(f"ratio mixed_robot_distance_vs_python {mixed:.2f} (target >= 0.95)")
    print(f"ratio mixed_robot_distance_vs_python {mixed:.2f} (target <= 1.05)")


if __name__ == "__main__":
    main()
