"""How long `make test` takes after installation: issue 27's budget is five minutes on two cores.

Runs `make test` in this checkout (the venv already installed, as a developer runs it after a change) and prints the
wall time over 300 s, with the lint step and the suite timed apart so a miss says where the time went. Takes about
as long as the suite (this is the one bench past two minutes: the figure *is* the suite's time).

    .venv/bin/python bench/make_test.py            # the figure
    .venv/bin/python bench/make_test.py --slowest  # and the 15 slowest tests
    .venv/bin/python bench/make_test.py --cpu      # and the suite's CPU by kind of process (bench/_cpu.py)
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench._cpu import CpuSampler, machine_busy, report

ROOT = Path(__file__).resolve().parent.parent
BUDGET = 300.0


def _timed(command: list[str]) -> tuple[float, str, int]:
    began = time.monotonic()
    done = subprocess.run(
        command, cwd=ROOT, capture_output=True, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"}
    )
    return time.monotonic() - began, done.stdout + done.stderr, done.returncode


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--slowest", action="store_true", help="also list the 15 slowest tests")
    parser.add_argument("--cpu", action="store_true", help="also sum the CPU of every process by kind during the suite")
    args = parser.parse_args()
    if not (ROOT / ".venv" / ".installed").exists():
        sys.exit("install first: make .venv/.installed (this figure is the time after installation)")
    make = ["make", "--no-print-directory", "test"]
    if args.slowest:
        make.append("PYTEST_ARGS=--durations=15")
    lint_s, _, _ = _timed(["make", "--no-print-directory", "lint"])
    sampler = CpuSampler().start() if args.cpu else None
    busy_before = machine_busy()
    total_s, output, code = _timed(make)
    busy = machine_busy() - busy_before
    if sampler is not None:
        sampler.stop()
    # one summary line per pytest run of `make test` (from four workers on, two: the rest, then the realtime tests)
    summary = "; ".join(line.strip("= ") for line in output.splitlines() if re.search(r"\d+ (passed|failed)", line))
    print(f"make lint: {lint_s:.1f} s; make test: {total_s:.1f} s, exit {code}: {summary}")
    for line in output.splitlines():
        if line.startswith(("FAILED ", "ERROR ")):
            print(line)
    if args.slowest:
        block = output.split("slowest 15 durations", 1)[-1].splitlines()[1:17]
        print("\n".join(block))
    cores = os.cpu_count() or 1
    print(f"{cores} cores {busy / (cores * total_s):.0%} busy during make test ({busy:.0f} CPU-s of the machine)")
    if sampler is not None:
        cpu, count = sampler.totals()
        print(report(cpu, count))
        # processes shorter than the sampling interval, and each one's last interval, are not in the sum
        print(f"{busy - sum(cpu.values()):8.1f} CPU-s of the machine's busy time not seen per process")
    print(f"ratio make_test_seconds_vs_300 {total_s / BUDGET:.2f} (target <= 1)")
    if code:
        sys.exit(code)


if __name__ == "__main__":
    main()
