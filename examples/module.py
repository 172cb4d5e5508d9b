"""A module node: a joint that follows its goal, the four kinds of attribute, an event and a service.

    python examples/module.py --name m1 --listen tcp/127.0.0.1:7447
Prints "READY <name>" once it is reachable; Ctrl-C (or SIGTERM) stops it.
"""

from __future__ import annotations

import sys

from _common import open_node, parser

from asm_py import Attribute, Event, Node, Service, TimerTrigger
from asm_py.cli import stop_requested


class Servo(Service):
    """Moves joint.angle towards joint.goal at 50 Hz (a first-order lag, as a position servo does)."""

    def __init__(self, goal: Attribute, angle: Attribute) -> None:
        super().__init__("servo.service")
        self.goal, self.angle = goal, angle

    def run(self) -> None:
        while self.sleep(0.02):
            current = self.angle.peek()
            self.angle.set(current + 0.3 * (self.goal.peek() - current))


def populate(node: Node) -> list[Service]:
    """Register the module's objects on ``node``; start and return its running services."""
    goal = Attribute("joint.goal", 0.0, codec="float32")
    angle = Attribute("joint.angle", 0.0, codec="float32")
    angle.publish(rate=50, deadband=0.001)
    tick = Event("gait.tick", codec="float64")
    timer = TimerTrigger(0.05, name="tick.timer")
    tick.add_trigger(timer)
    servo = Servo(goal, angle)
    for obj in (goal, angle, tick, servo, timer,
                Attribute("plain", 0, codec="int32"),
                Attribute("fresh", sync_get=True, codec="int32"),
                Attribute("used", sync_set=True, codec="int32"),
                Attribute("slot", sync_get=True, sync_set=True, codec="int32")):  # fmt: skip
        node.register(obj)
    servo.start()
    timer.start()
    return [timer, servo]


def serve(name: str, node: Node, services: list[Service], *closing: object) -> None:
    """Print the ready line, run until SIGTERM or Ctrl-C, then stop everything in order."""
    done = stop_requested()  # SIGTERM and Ctrl-C; its handlers take no lock (two signals at once once deadlocked)
    print(f"READY {name}", flush=True)
    done.wait()
    for service in services:
        service.stop(timeout=5)
    node.close()
    for other in closing:
        other.close()  # type: ignore[attr-defined]


def main() -> int:
    cli = parser(__doc__.splitlines()[0])
    cli.add_argument("--name", default="m1")
    args = cli.parse_args()
    node = open_node(args.name, args, role="module")
    serve(args.name, node, populate(node))
    return 0


if __name__ == "__main__":
    sys.exit(main())
