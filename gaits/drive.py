"""Drive a running robot: switch every module to another gait of its program at one cycle boundary, confirmed.

The PC only sends commands; the modules switch themselves (asm_module/gait_service.py). One group message
``gait.switch`` = {mode, direction, after} reaches every module; ``after`` is a time on the modules' clock a little
ahead of their latest tick, so every module picks the same boundary even when the message reaches them at slightly
different moments. The switch is then read back from each module's ``gait.mode`` and ``gait.direction``: a drive
never reports a switch the modules did not make.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from asm_module.gait_service import SWITCH
from asm_py.group import BROADCAST
from asm_py.node import Node

from .calls import DeployError, ModuleCalls
from .deploy import start_all, stop_all
from .model import Gait
from .programs import mode_index

MARGIN = 0.3
"""Seconds between the modules' latest tick and the earliest boundary a switch may use (the message's way there)."""
STOP = "stop"
"""The drive command that stops every module's gait (the joints hold where they are)."""


def drive(
    node: Node,
    gait: Gait,
    command: str,
    modules: Sequence[str],
    *,
    direction: int = 1,
    group: str = BROADCAST,
    timeout: float | None = None,
) -> list[str]:
    """Switch ``modules`` (node names, running ``gait``) to program gait ``command`` going ``direction``, or stop
    them (``command`` == STOP). Returns the modules confirmed; DeployError names those that did not follow."""
    if command == STOP:
        stop_all(node, group)
        return list(modules)
    mode = mode_index(gait, command)
    if direction not in (1, -1):
        raise ValueError(f"direction must be +1 or -1, not {direction}")
    by_index = dict(enumerate(modules, start=1))
    checker = ModuleCalls(node, by_index, 2.0, 3)
    checker.check_not_latched(list(by_index), f"drive {command}")
    if not all(checker.running(m, "drive") for m in by_index):
        start_all(node, modules, group=group)
    now = float(checker.peek(1, "gait.tick", "drive"))
    node.group(group).attribute("gait.switch", SWITCH).set(
        {"mode": mode, "direction": direction, "after": now + MARGIN}
    )
    periods = [a.period for a in gait.automata.values() if a.period is not None]
    wait = timeout if timeout is not None else 2 * max(periods, default=5.0) + MARGIN + 2.0
    deadline = time.monotonic() + wait
    missing = list(by_index)
    while missing and time.monotonic() < deadline:
        time.sleep(0.05)
        missing = [m for m in missing if not _switched(checker, m, mode)]
    if missing:
        raise DeployError(f"drive {command}: {', '.join(by_index[m] for m in missing)} did not confirm the switch")
    return list(modules)


def _switched(checker: ModuleCalls, module: int, mode: int) -> bool:
    try:
        return int(checker.get(module, "gait.mode", "drive")) == mode
    except DeployError:
        return False
