"""Where a run's CPU goes, by kind of process: bench/make_test.py --cpu samples every process on the machine while
the suite runs and sums their CPU by what they are (Chromium, pytest's workers, robot children, studios, ...).

Issue 27's suite is CPU-bound on two cores (stop 50: 83 % of both busy for the whole run), so its time follows the
CPU of whatever the tests start; this says which of those to cut. Linux only (it reads /proc)."""

from __future__ import annotations

import os
import threading
from collections import Counter
from pathlib import Path

PROC = Path("/proc")
TICKS = os.sysconf("SC_CLK_TCK")


XDIST_WORKER = "import sys;exec(eval(sys.stdin.readline()))"
"""The code execnet starts each pytest-xdist worker with (``python -u -c <this>``)."""


def kind(command: list[str]) -> str:
    """What a process is, from its command line (argv): the label its CPU is summed under."""
    if len(command) == 1 and " " in command[0]:
        # Chromium's helpers rewrite their command line as one string: split it, or a path in an argument
        # (--user-data-dir=...) would be taken for the program
        command = command[0].split()
    if not command:
        return "?"
    program = os.path.basename(command[0])
    if "chromium" in program or "chrome" in program:
        return "chromium"
    if program == "node":
        return "playwright driver" if any("playwright" in arg for arg in command) else "node"
    if "python" not in program:
        return program
    args = command[1:]
    for i, arg in enumerate(args):
        if arg == "-m" and i + 1 < len(args):
            module = args[i + 1]
            if module == "pytest":
                return "pytest"
            if module in ("basedpyright", "ruff"):
                return module
            return f"python -m {module}"
        if arg == "-c":
            code = args[i + 1] if i + 1 < len(args) else ""
            return "pytest worker" if code == XDIST_WORKER else "python -c"
        if not arg.startswith("-"):
            name = os.path.basename(arg)
            return f"python {name}" if not name.startswith("asm-") else name
    return "python"


def machine_busy() -> float:
    """CPU seconds the whole machine has spent busy since boot (/proc/stat: all but idle and I/O wait)."""
    # user nice system idle iowait irq softirq steal (guest time, after these, is already counted in user)
    fields = [int(x) for x in (PROC / "stat").read_text().split("\n", 1)[0].split()[1:9]]
    return (sum(fields) - fields[3] - fields[4]) / TICKS


def _sample() -> dict[tuple[int, int], tuple[float, list[str]]]:
    """Every readable process: (pid, start time) -> (CPU seconds so far, argv; for a process without a command line,
    a kernel thread or a zombie, its name from /proc/<pid>/stat in brackets)."""
    seen: dict[tuple[int, int], tuple[float, list[str]]] = {}
    for entry in PROC.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            command = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:  # gone meanwhile, or not ours to read
            continue
        fields = stat[stat.rfind(")") + 2 :].split()
        cpu = (int(fields[11]) + int(fields[12])) / TICKS  # utime + stime
        argv = [part.decode(errors="replace") for part in command if part]
        seen[(int(entry.name), int(fields[19]))] = (cpu, argv or [f"[{stat[stat.find('(') + 1 : stat.rfind(')')]}]"])
    return seen


class CpuSampler:
    """Samples every process every ``interval`` seconds from start() to stop(); totals() then gives the CPU seconds
    each kind of process used meanwhile. What a process uses after its last sample, and a process living less than
    one interval, is missed: bench/make_test.py prints that part as the machine's busy time the sampler did not see
    (a review measured 10 children of 0.1 CPU-s each counted as 0.18 of their 1.27 CPU-s)."""

    def __init__(self, interval: float = 0.2) -> None:
        self.interval = interval
        self._before: dict[tuple[int, int], float] = {}
        self._last: dict[tuple[int, int], tuple[float, list[str]]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="cpu sampler", daemon=True)

    def start(self) -> CpuSampler:
        self._before = {key: cpu for key, (cpu, _) in _sample().items()}
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        self._update()

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            self._update()

    def _update(self) -> None:
        for key, (cpu, argv) in _sample().items():
            known = self._last.get(key)
            # a process that has exited but not been waited for (a zombie) has no command line left: keep the one
            # it had, with its CPU, which stays readable
            self._last[key] = (cpu, known[1] if known and argv[0].startswith("[") else argv)

    def _used(self) -> list[tuple[int, float, str]]:
        """Every process sampled: (pid, CPU seconds used after start(), kind)."""
        return [
            (key[0], seconds - self._before.get(key, 0.0), kind(argv)) for key, (seconds, argv) in self._last.items()
        ]

    def entries(self) -> dict[int, tuple[float, str]]:
        """Per process id: the CPU seconds it used after start() and its kind (the last process of that id)."""
        return {pid: (seconds, label) for pid, seconds, label in self._used()}

    def totals(self) -> tuple[Counter[str], Counter[str]]:
        """(CPU seconds, processes) per kind, counting only CPU used after start(), this process left out."""
        cpu: Counter[str] = Counter()
        count: Counter[str] = Counter()
        for pid, seconds, label in self._used():
            if pid != os.getpid():
                cpu[label] += seconds
                count[label] += 1
        return cpu, count


def report(cpu: Counter[str], count: Counter[str], top: int = 12) -> str:
    """The kinds that used the most CPU, one line each, and the total."""
    lines = [f"{seconds:8.1f} CPU-s  {count[label]:5d} processes  {label}" for label, seconds in cpu.most_common(top)]
    lines.append(f"{sum(cpu.values()):8.1f} CPU-s in all")
    return "\n".join(lines)
