"""``asm-estop``: stop every robot on the Zenoh network (the lab-wide e-stop), or one robot — one line, at once.

    asm-estop --zenoh-connect tcp/127.0.0.1:7447                 # every module of every robot
    asm-estop --robot a --zenoh-connect tcp/127.0.0.1:7447       # every module of robot a, no other

The stop is one Zenoh put at real-time priority on ``asm/@lab/estop/~asm-estop`` (or ``asm/a/@estop/~asm-estop``):
every module node, every bridge (which puts it on its bus as one priority-0 frame) and every studio acts on it. The
command then asks the robots for their status and prints, on one line, how many modules of each have latched; it
exits 0 when every module of every robot it reached is latched, 1 otherwise (a robot on a real bus, which does not
report latches, counts as unconfirmed).

Given ``--zenoh-connect``, it is a Zenoh client of that peer or router unless ``--zenoh-mode peer`` says otherwise:
it puts the moment it has connected, before a peer would have met the rest of the mesh (docs/protocol.md §6).
"""

from __future__ import annotations

import argparse
import time

import zenoh

from asm_module.feed import RobotStatus, read_statuses
from asm_py.cli import name, run, summary
from asm_py.keys import TOOL, RobotKeys, lab_estop
from asm_py.transport.base import short_reason

from .zenoh_args import ZenohOptions, add_zenoh_arguments, zenoh_options

SOURCE = f"{TOOL}asm-estop"
CONFIRM_SECONDS = 2.0


def send_estop(session: zenoh.Session, robot: str | None, reason: str) -> None:
    """The e-stop of ``robot`` (None: every robot), one put at Zenoh's real-time priority."""
    key = lab_estop(SOURCE) if robot is None else RobotKeys(robot).estop(SOURCE)
    session.put(key, short_reason(reason).encode("utf-8"), priority=zenoh.Priority.REAL_TIME,
                congestion_control=zenoh.CongestionControl.BLOCK, express=True)  # fmt: skip


def _latched_everywhere(statuses: dict[str, RobotStatus]) -> bool:
    return bool(statuses) and all(s.estop is not None and len(s.estop) >= s.modules for s in statuses.values())


def describe(statuses: dict[str, RobotStatus]) -> str:
    parts = []
    for robot, status in sorted(statuses.items()):
        if status.estop is None:
            parts.append(f"robot {robot}: sent (a real bus does not report latches)")
        else:
            parts.append(f"robot {robot}: {len(status.estop)} of {status.modules} modules latched")
    return "; ".join(parts) or "no robot answered"


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="asm-estop", description=summary(__doc__))
    cli.add_argument("--robot", type=name, help="stop this robot only (default: every robot on the network)")
    cli.add_argument("--reason", default="asm-estop", help="a short reason (its first 8 bytes travel)")
    add_zenoh_arguments(cli, one_shot=True)
    args = cli.parse_args(argv)
    network = zenoh_options(cli, args)
    return run(cli.prog, lambda: _stop(args.robot, args.reason, network))


def _stop(robot: str | None, reason: str, network: ZenohOptions) -> int:
    session = network.open()
    try:
        send_estop(session, robot, reason)
        deadline = time.monotonic() + CONFIRM_SECONDS
        statuses = read_statuses(session, robot)
        while not _latched_everywhere(statuses) and time.monotonic() < deadline:
            send_estop(session, robot, reason)  # idempotent: a robot that joined late, a put lost, stop it too
            time.sleep(0.1)
            statuses = read_statuses(session, robot)
    finally:
        session.close()
    scope = "lab-wide e-stop" if robot is None else f"e-stop of robot {robot}"
    print(f"asm-estop: {scope} sent; {describe(statuses)}", flush=True)
    return 0 if _latched_everywhere(statuses) else 1


if __name__ == "__main__":
    raise SystemExit(main())
