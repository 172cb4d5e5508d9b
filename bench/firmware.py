"""The C module runtime (firmware/, issue 17): hostile input at scale, its size, its vectors and its speed.

    .venv/bin/python bench/firmware.py

Builds firmware/tests/fuzz.c with AddressSanitizer and UndefinedBehaviorSanitizer and feeds it 10 million random
and mutated frames, messages, gait tables and module requests, and random programs run with random sensors; links
the example Cortex-M4 port (firmware/port/stm32f4_bxcan.c, -Os, one 640-byte reassembly slot) and reads its flash
and RAM with arm-none-eabi-size (`make test` installs Debian's gcc-arm-none-eabi); reproduces every golden vector;
and counts the remote gets a C module and a Python module answer on the simulated robot's bus (asm_sim), in the
same run, from bursts a raw CAN tester sends: per second of each module's own CPU time (the headline: a module has
a processor of its own) and, for context, per second of wall time on this shared 2-core machine. Then
bench/firmware_update.py: 8 emulated boards updated over the bus at once.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from asm_module.firmware_build import C_FLAGS, runtime_sources
from asm_module.firmware_build import build_test_program as build

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
    from asm_module.firmware_build import build_cortex_m4

    text, data, bss = build_cortex_m4(workdir / "m4.elf")
    print(f"# Cortex-M4 (STM32F4 example port, -Os): text {text}, data {data}, bss {bss} bytes")
    return text + data, data + bss


def gets_per_second(remote: object, count: int) -> float:
    began = time.perf_counter()
    for _ in range(count):
        remote.peek()  # type: ignore[attr-defined]
    return count / (time.perf_counter() - began)


def cpu_seconds(threads: Iterable[threading.Thread]) -> float:
    """CPU time the threads have used so far (each thread's own clock: the tester's work is not counted)."""
    total = 0.0
    for thread in threads:
        if thread.is_alive() and thread.ident is not None:
            try:
                total += time.clock_gettime(time.pthread_getcpuclockid(thread.ident))
            except OSError:  # it ended just now
                pass
    return total


def answered_per_second(bus: object, client_id: int, module_id: int, object_id: int,
                        threads: list[threading.Thread]) -> tuple[float, float]:  # fmt: skip
    """Gets (peeks) of joint.goal a module answers from a burst of BURST requests: (per second of wall time, per
    second of the module's own CPU time).

    A raw CAN client, as a bus tester loads a controller: the requests are made beforehand and sent back to back,
    then the tester only waits for the replies. The wall-time rate still includes the tester's and the bus's share
    of this 2-core machine; the CPU-time rate is what the module's ``threads`` spent answering, what it could
    answer with a processor of its own, as every module on a robot has."""
    import can

    from asm_module._profile import CLASSES
    from asm_py.canbus.ids import CanId, Dest, FrameType, Priority
    from asm_py.protocol import Kind, Message, Method, encode

    request_id = CanId(Priority.REQUEST, Dest.NODE, module_id, client_id, FrameType.SINGLE).pack()
    goal = CLASSES["joint.goal"]
    frames = [
        can.Message(arbitration_id=request_id, is_extended_id=True,
                    data=encode(Message(Kind.REQUEST_REPLY, Method.PEEK, i & 0x7F, goal, object_id)))
        for i in range(BURST)
    ]  # fmt: skip
    answered = 0
    cpu = cpu_seconds(threads)
    began = time.perf_counter()
    for frame in frames:
        bus.send(frame)  # type: ignore[attr-defined]
    last = began
    while answered < BURST and (reply := bus.recv(timeout=1.0)) is not None:  # type: ignore[attr-defined]
        if CanId.unpack(reply.arbitration_id).source == module_id:
            answered += 1
            last = time.perf_counter()
    cpu = cpu_seconds(threads) - cpu
    if answered < BURST:
        return 0.0, 0.0
    return answered / (last - began), answered / cpu


BURST = 2000


def c_vs_python_gets() -> float:
    """Remote gets of joint.goal answered per CPU second by a C module over a Python module, one simulated bus,
    bursts alternated; also, for context, per second of wall time, and one Python client's round trips."""
    import can

    from asm_module.c_module import CModule
    from asm_module.drivers import FakeDriver
    from asm_module.runtime import ModuleRuntime
    from asm_py.node import Node
    from asm_py.transport.can import CanTransport

    bus = {"interface": "asm_sim", "channel": f"bench-firmware-{time.monotonic_ns()}"}  # the simulated robot's bus
    before = set(threading.enumerate())
    c_module = CModule("c1", 5, **bus)
    c_threads = list(set(threading.enumerate()) - before)
    before = set(threading.enumerate())
    python_node = Node("p1", CanTransport(6, **bus, watch_bus=False))
    runtime = ModuleRuntime(FakeDriver(), node=python_node, module_id=6)
    p_threads = list(set(threading.enumerate()) - before)
    client = Node("bench", CanTransport(100, **bus, heartbeat_period=0.1))
    tester = can.Bus(**bus)
    try:
        while not {"c1", "p1"} <= set(client.discover()):
            time.sleep(0.05)
        remotes = {name: client.lookup(name, "joint.goal", timeout=5) for name in ("c1", "p1")}
        trips: dict[str, list[float]] = {"c1": [], "p1": []}
        for _ in range(5):
            for name, remote in remotes.items():
                trips[name].append(gets_per_second(remote, 400))
        client.close()  # it watches the whole bus: its thread would take a share of every burst
        tester.set_filters([{"can_id": 101 << 16, "can_mask": 0xFF << 16, "extended": True}])
        wall: dict[str, list[float]] = {"c1": [], "p1": []}
        cpu: dict[str, list[float]] = {"c1": [], "p1": []}
        for _ in range(5):
            for name, module_id, threads in (("c1", 5, c_threads), ("p1", 6, p_threads)):
                rates = answered_per_second(tester, 101, module_id, remotes[name].info.object_id, threads)
                wall[name].append(rates[0])
                cpu[name].append(rates[1])
        c_trip, p_trip = (sorted(trips[n])[2] for n in ("c1", "p1"))
        c_wall, p_wall = (sorted(wall[n])[2] for n in ("c1", "p1"))
        c_cpu, p_cpu = (sorted(cpu[n])[2] for n in ("c1", "p1"))
        print(f"# one client's round trips, one get at a time (median of 5 rounds of 400): C module {c_trip:.0f}/s, "
              f"Python module {p_trip:.0f}/s (the client's own stack sets this pace)")  # fmt: skip
        print(f"# gets answered from a burst of {BURST}, median of 5: per second of wall time, C module {c_wall:.0f}, "
              f"Python module {p_wall:.0f} (ratio {c_wall / p_wall:.2f}: the tester and the bus share the machine); "
              f"per second of the module's CPU time, C module {c_cpu:.0f}, Python module {p_cpu:.0f}")  # fmt: skip
        return c_cpu / p_cpu
    finally:
        tester.shutdown()
        client.close()
        runtime.close()
        python_node.close()
        c_module.close()


def vectors_reproduced(workdir: Path) -> tuple[int, int]:
    """(reproduced, present) over every golden vector in tests/vectors/: messages, CAN frames and codecs by the C
    runner (codecs both ways: the bytes checked against the descriptor, the value encoded to them), module objects
    by a C module on a virtual bus."""
    from asm_module.c_module import CModule
    from asm_module.golden import can_vector_lines, codec_lines, message_lines, reproduce_module_object_vectors

    lines = message_lines() + can_vector_lines() + codec_lines()
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
    not_reproduced = f" (not: {', '.join(missing)})" if missing else ""
    print(f"# golden vectors: {wire} of {len(lines)} messages, CAN frames and codecs; {len(objects) - len(missing)} "
          f"of {len(objects)} module objects{not_reproduced}")  # fmt: skip
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
    if m4 is not None:  # firmware update over the bus: bench/firmware_update.py, on emulated boards
        import firmware_update

        firmware_update.main([])
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
