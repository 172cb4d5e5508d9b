"""Gait files under attack: the time to answer the worst malformed files, against the 2 s the issue allows.

- ``gait_validate_worst_vs_2s``: the slowest of: 10 MB of states (refused unread), as many bad states as fit in
  2 MiB, 2 MiB of bad module assignments, arrays nested 100,000 deep; best of 3 each, over 2 s. Target <= 1.
- ``gait_validate_peak_memory_vs_file``: peak Python memory while answering the 2 MiB file of bad states
  (tracemalloc, a separate run), over the file's size. Bounded means a small constant factor. Target <= 30.

Run: .venv/bin/python bench/gaits.py
"""

from __future__ import annotations

import sys
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from gaits.model import LIBRARY, GaitError, loads
from gaits.validate import MAX_FILE_BYTES

BASE = (LIBRARY / "caterpillar.toml").read_text(encoding="utf-8")
STATE = "{ angle = 999.0, duration = -1, interpolation = 'x' },\n"
MODULE = "{ id = 300, automaton = 'nope', phase = 2.0 },\n"


def fill(marker: str, row: str, size: int) -> bytes:
    return BASE.replace(marker, marker + row * ((size - len(BASE)) // len(row)), 1).encode()


CASES = {
    "10 MB of states": fill("states = [\n", STATE, 10_000_000),
    "2 MiB of bad states": fill("states = [\n", STATE, MAX_FILE_BYTES),
    "2 MiB of bad modules": fill("modules = [\n", MODULE, MAX_FILE_BYTES),
    "arrays nested 100,000 deep": (BASE + "x = " + "[" * 100_000 + "]" * 100_000 + "\n").encode(),
}


def answer(data: bytes) -> GaitError:
    try:
        loads(data)
    except GaitError as exc:
        return exc
    raise AssertionError("a malformed file was accepted")


def main() -> None:
    worst = 0.0
    for name, data in CASES.items():
        times = []
        for _ in range(3):
            started = time.perf_counter()
            error = answer(data)
            times.append(time.perf_counter() - started)
        best = min(times)
        worst = max(worst, best)
        print(f"{name}: {len(data) / 1e6:.1f} MB answered in {best:.2f} s ({len(error.problems)} listed, "
              f"{error.more} more): {error.problems[0]}"[:160])  # fmt: skip
    print(f"ratio gait_validate_worst_vs_2s {worst / 2.0:.2f} (target <= 1)", flush=True)
    data = CASES["2 MiB of bad states"]
    tracemalloc.start()
    answer(data)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(f"peak memory answering {len(data) / 1e6:.1f} MB: {peak / 1e6:.0f} MB")
    print(f"ratio gait_validate_peak_memory_vs_file {peak / len(data):.1f} (target <= 30)", flush=True)


if __name__ == "__main__":
    main()
