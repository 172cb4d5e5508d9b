"""Real modules (issue 28): commissioning a batch of modules that have no node IDs yet.

    .venv/bin/python bench/modules.py

- ``commissioning_24_modules_s_vs_10s``: 24 Python modules with random serials and no IDs on one simulated CAN bus
  (asm_module.commissioning.Fleet, each a module runtime under a 50 Hz tick once numbered), found and numbered by
  the tool (asm_py.canbus.commission.Commissioner.number: a roster of every module, then one ID each), wall time
  over 10 s. Target <= 1. The median of three batches, each new serials.

Also printed: the commands the tool sent, the round trips per module that implies, the time of a roster of the
numbered bus (what `asm-commission list` does). Emulated boards are not timed here: eight of them in real time
cost about a core while idle (firmware/README.md) and fall behind the wall clock on a shared two-core machine, so
their round trips grow to seconds; tests/firmware/test_commissioning.py numbers four.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import can

from asm_module.commissioning import Fleet
from asm_py.canbus.commission import Commissioner, CommissionScope

MODULES = 24


def batch(k: int) -> tuple[float, float, int]:
    """Seconds to number 24 fresh modules, seconds of the roster after, commands sent to number them."""
    channel = f"bench-modules-{time.monotonic_ns()}-{k}"
    with tempfile.TemporaryDirectory() as directory:
        fleet = Fleet(Path(directory), MODULES, channel)
        bus = can.Bus(interface="asm_sim", channel=channel)
        try:
            tool = Commissioner(bus)
            began = time.perf_counter()
            assigned = tool.number()
            numbering = time.perf_counter() - began
            sent = tool.commands_sent
            if sorted(m.node_id for m in assigned) != list(range(1, MODULES + 1)):
                raise SystemExit(f"numbered {len(assigned)} of {MODULES} modules: {assigned}")
            began = time.perf_counter()
            roster = tool.discover(CommissionScope.EVERY)
            listing = time.perf_counter() - began
            if len(roster) != MODULES:
                raise SystemExit(f"the roster after numbering has {len(roster)} modules, not {MODULES}")
        finally:
            bus.shutdown()
            fleet.close()
    return numbering, listing, sent


def main() -> int:
    runs = [batch(k) for k in range(3)]
    numbering = statistics.median(r[0] for r in runs)
    listing = statistics.median(r[1] for r in runs)
    sent = statistics.median(r[2] for r in runs)
    print(f"numbering {MODULES} modules: {', '.join(f'{r[0]:.2f}' for r in runs)} s; {sent:.0f} commands "
          f"({sent / MODULES:.1f} a module); a roster of the numbered bus {listing:.2f} s")  # fmt: skip
    print(f"ratio commissioning_24_modules_s_vs_10s {numbering / 10:.3f} (target <= 1)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
