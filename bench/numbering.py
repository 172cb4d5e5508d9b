"""Issue 28's "Done when", timed without the page: a simulated caterpillar whose eight modules are a fresh batch of
emulated boards (``--emulated-modules all --board-flash DIR``, a new folder), numbered along the chain through the
robot's commissioning service (server/commission_service.py) as the Modules tab does — list by serial, then per
board a wiggle (a temporary ID, the joint moved and back, the ID erased) whose moving joint says the chain position,
and an assign of that position — until m1..m8 answer module.info.

    .venv/bin/python bench/numbering.py

- ``numbering_8_boards_s_vs_120s``: the wall time of the whole numbering, the robot's share of it (the person's
  look at the joint not counted), over 15 s a board: a wait a person numbering a robot does not mind. Target <= 1.

Also printed: the list's time, each wiggle's and assign's, and how long the numbered boards took to answer as
modules. Emulated boards run the image in real time on this machine: its load is in every figure.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from asm_module.commission_link import commission
from asm_py.node import Node
from asm_py.transport.zenoh import ZenohTransport
from gaits.model import LIBRARY
from server.robot import Robot, RobotOptions
from server.zenoh_args import ZenohOptions
from tests.transports import free_port

BOARDS = tuple(range(1, 9))


def moved_joint(robot: Robot, ask) -> tuple[int, dict]:
    """Run ``ask()`` (a wiggle) sampling every joint: the chain position that moved most, and the answer."""
    sim = robot.sim
    assert sim is not None
    rest = {p: sim.modules[p].driver.read().angle for p in BOARDS}  # type: ignore[attr-defined]
    swing = dict.fromkeys(BOARDS, 0.0)
    done = threading.Event()

    def sample() -> None:
        while not done.is_set():
            for p in BOARDS:
                swing[p] = max(swing[p], abs(sim.modules[p].driver.read().angle - rest[p]))  # type: ignore[attr-defined]
            time.sleep(0.01)

    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    try:
        answer = ask()
    finally:
        done.set()
        thread.join(5)
    return max(swing, key=lambda p: swing[p]), answer


def main() -> int:
    if shutil.which("arm-none-eabi-gcc") is None:
        print("bench/numbering.py needs arm-none-eabi-gcc", file=sys.stderr)
        return 1
    folder = Path(tempfile.mkdtemp(prefix="asm-bench-boards-"))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    began = time.monotonic()
    robot = Robot(RobotOptions(sim=LIBRARY / "caterpillar.toml", emulated_modules="all", board_flash=folder,
                               network=ZenohOptions(listen=(endpoint,))))  # fmt: skip
    print(f"robot of 8 fresh emulated boards up in {time.monotonic() - began:.1f} s")
    client = Node("bench-numbering", ZenohTransport(connect=[endpoint]))
    session = client.transport.session  # type: ignore[attr-defined]
    try:
        began = time.monotonic()
        listed = commission(session, "robot", {"op": "list"})["modules"]
        listing = time.monotonic() - began
        print(f"list: {len(listed)} boards, {sum(1 for m in listed if not m['id'])} without an ID, {listing:.2f} s")
        wiggles, assigns = [], []
        for module in listed:
            t = time.monotonic()
            position, answer = moved_joint(robot, lambda m=module: commission(session, "robot", {
                "op": "wiggle", "serial": m["serial"]}))  # fmt: skip
            wiggles.append(time.monotonic() - t)
            t = time.monotonic()
            commission(session, "robot", {"op": "assign", "serial": module["serial"], "id": position})
            assigns.append(time.monotonic() - t)
            print(f"  {module['serial']}: joint {position} moved {answer['moved']:.1f}° (wiggle {wiggles[-1]:.2f} s, "
                  f"assign {assigns[-1]:.2f} s)")  # fmt: skip
        t = time.monotonic()
        names = [f"m{p}" for p in BOARDS]
        while True:
            try:
                infos = [client.lookup(n, "module.info", timeout=5).get(timeout=5) for n in names]  # type: ignore[attr-defined]
                if all(int(i["language"]) == 1 for i in infos):
                    break
            except Exception:  # not every board is up under its ID yet
                pass
            if time.monotonic() - t > 120:
                print("the numbered boards did not all answer within 120 s", file=sys.stderr)
                return 1
            time.sleep(0.2)
        answering = time.monotonic() - t
        total = listing + sum(wiggles) + sum(assigns) + answering
        print(f"m1..m8 answer module.info as boards {answering:.2f} s after the last assign")
        print(f"wiggle mean {sum(wiggles) / len(wiggles):.2f} s (worst {max(wiggles):.2f}), assign mean "
              f"{sum(assigns) / len(assigns):.2f} s (worst {max(assigns):.2f})")  # fmt: skip
        print(f"ratio numbering_8_boards_s_vs_120s {total / 120:.3f} (target <= 1)")
    finally:
        client.close()
        robot.close()
        shutil.rmtree(folder, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
