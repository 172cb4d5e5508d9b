"""What the robot process costs: CPU and threads of a simulated robot at rest and running (issue 31).

    .venv/bin/python bench/robot_load.py

- ``robot_cpu_cores_128_running_vs_0.5``: CPU seconds per wall second of ``asm-robot --sim`` with a 128-module
  caterpillar deployed and running, over half a core (read from /proc over 10 s, after 3 s of settling). Target <= 1.
- ``robot_cpu_cores_128_idle_vs_0.1``: the same robot at rest (no gait deployed, lying still), over a tenth of a core.
  Target <= 1.
- ``robot_threads_128_vs_32``: threads of the 128-module robot process over those of the 32-module one, both at rest
  after discovery. Target <= 1 (no thread per module).

Each robot's real-time factor while running is printed beside its CPU figure: a robot that saves CPU by falling
behind the wall clock has not saved anything.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.robot import resized, robot_process
from gaits.deploy import deploy
from gaits.model import load

TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def threads(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/task"))


def cores(pid: int, seconds: float = 10.0) -> float:
    c0, w0 = cpu_seconds(pid), time.monotonic()
    time.sleep(seconds)
    return (cpu_seconds(pid) - c0) / (time.monotonic() - w0)


def measure(path: Path, modules: int, *, running: bool) -> dict[str, float]:
    process, client, watch = robot_process(path)
    pid = process.popen.pid
    try:
        deadline = time.monotonic() + 60
        while not {f"m{i}" for i in range(1, modules + 1)} <= set(client.discover()):
            if time.monotonic() > deadline:
                raise RuntimeError(f"only {len(client.discover())} of {modules} modules discovered after 60 s")
            time.sleep(0.2)
        time.sleep(3.0)
        result = {"idle_cores": cores(pid), "threads": threads(pid)}
        if running:
            deploy(client, load(path), timeout=10.0, deadline=60.0)
            time.sleep(3.0)
            began = watch.status.time if watch.status else 0.0
            wall = time.monotonic()
            result["running_cores"] = cores(pid)
            ended = watch.status.time if watch.status else 0.0
            result["rtf"] = (ended - began) / (time.monotonic() - wall)
            result["threads_running"] = threads(pid)
        return result
    finally:
        watch.close()
        client.close()
        process.stop()


def main() -> None:
    with tempfile.TemporaryDirectory() as folder:
        small = measure(resized("caterpillar", 32, Path(folder)), 32, running=False)
        big = measure(resized("caterpillar", 128, Path(folder)), 128, running=True)
    print(f"32 modules at rest: {small['idle_cores']:.3f} cores, {small['threads']:.0f} threads")
    print(f"128 modules at rest: {big['idle_cores']:.3f} cores, {big['threads']:.0f} threads; running: "
          f"{big['running_cores']:.3f} cores, {big['threads_running']:.0f} threads, real-time factor {big['rtf']:.2f} "
          f"(from the status feed's simulated time)")  # fmt: skip
    print(f"ratio robot_cpu_cores_128_running_vs_0.5 {big['running_cores'] / 0.5:.2f} (target <= 1)")
    print(f"ratio robot_cpu_cores_128_idle_vs_0.1 {big['idle_cores'] / 0.1:.2f} (target <= 1)")
    print(f"ratio robot_threads_128_vs_32 {big['threads'] / small['threads']:.2f} (target <= 1)", flush=True)


if __name__ == "__main__":
    main()
