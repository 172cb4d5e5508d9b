"""Safety benchmark: the e-stop under a flood, and the bridge's memory under oversized and never-answered requests.

Eight module runtimes on a virtual CAN bus, the CAN↔Zenoh bridge and an operator's Zenoh node run in this process
(as in the studio); a second process is the hostile client, a raw Zenoh session.

- ``estop_latency_under_flood_vs_idle``: median time from the operator's E-STOP (a Zenoh put) to every module
  latched, while the hostile client floods the bridge with maximum-size (4,096-byte) requests to a module as fast as
  it can, over the same median with nobody flooding. Target <= 2.
- ``bridge_rss_after_flood_vs_idle``: this process's resident memory after a minute of oversized (10 MB) queries
  with the longest timeout byte and of never-answered waits ("block forever"), over before it. Target <= 1.2.

Run: .venv/bin/python bench/safety.py
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

# bench/ holds a can.py: keep this directory off the path, or "import can" would import that script.
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from asm_module.bus_robot import BusRobot as Robot
from asm_py import Event
from asm_py.node import Node
from asm_py.transport.zenoh import ZenohTransport
from bench._processes import free_port
from server.bridge import CanZenohBridge
from server.realtime import prefer_latency
from server.zenoh_args import ZenohOptions

STOPS = 25
FLOOD_SECONDS = float(os.environ.get("FLOOD_SECONDS", "60"))

FLOODER = r"""
import sys, time, zenoh
from asm_py.protocol import Kind, Message, Method, encode
endpoint, mode, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
class_id, object_id = int(sys.argv[4]), int(sys.argv[5])
config = zenoh.Config()
config.insert_json5("scouting/multicast/enabled", "false")
config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
config.insert_json5("connect/endpoints", f'["{endpoint}"]')
session = zenoh.open(config)
time.sleep(1.0)
print("FLOODING", flush=True)
end = time.monotonic() + seconds
sent = 0
if mode == "max":  # the largest message allowed, as fast as the session takes it: sets of gait.staged on m1
    data = encode(Message(Kind.REQUEST, Method.SET, 0, 0x27, 0, data=bytes(4092)))
    publisher = session.declare_publisher("asm/robot/m1/msg/flooder", congestion_control=zenoh.CongestionControl.BLOCK)
    while time.monotonic() < end:
        publisher.put(data)
        sent += 1
else:  # oversized queries with the longest timeout, and waits that are never answered
    big = encode(Message(Kind.REQUEST_REPLY, Method.SET, 1, 0x27, 0, timeout=0xFE, data=bytes(10 * 1024 * 1024)))
    txn = 0
    while time.monotonic() < end:
        if mode != "waits":
            session.get("asm/robot/m1/req/hog", lambda reply: None, payload=big, timeout=30.0)
        for _ in range(20 if mode != "big" else 0):
            txn = (txn + 1) & 0x7F
            wait = encode(Message(Kind.REQUEST_REPLY, Method.WAIT, txn, class_id, object_id, timeout=0xFF))
            session.get(f"asm/robot/m{1 + txn % 8}/req/hog{txn % 16}", lambda reply: None, payload=wait, timeout=30.0)
        sent += 21
        time.sleep(0.01)
print("SENT", sent, flush=True)
session.close()
"""


def rss_kib() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError("no VmRSS")


def estop_latencies(robot: Robot, operator: Node, count: int) -> list[float]:
    latencies = []
    for _ in range(count):
        for runtime in robot.runtimes:
            runtime.estop.set(False)
        done = threading.Event()

        def check(_: object, done: threading.Event = done) -> None:
            if all(r.latched for r in robot.runtimes):
                done.set()

        removers = [r.estop.on_change(check) for r in robot.runtimes]
        started = time.perf_counter()
        operator.estop("bench")
        if not done.wait(10):
            raise RuntimeError("an e-stop did not latch every module within 10 s")
        latencies.append(time.perf_counter() - started)
        for remove in removers:
            remove()
        time.sleep(0.05)
    return latencies


def flood(endpoint: str, mode: str, seconds: float, never: tuple[int, int]) -> subprocess.Popen[str]:
    root = str(Path(__file__).resolve().parent.parent)
    process = subprocess.Popen([sys.executable, "-c", FLOODER, endpoint, mode, str(seconds), *map(str, never)],
                               stdout=subprocess.PIPE, text=True, cwd=root,
                               env={**os.environ, "PYTHONPATH": root})  # fmt: skip
    assert process.stdout is not None
    if process.stdout.readline().strip() != "FLOODING":
        raise RuntimeError("the flooding client did not start")
    return process


def main() -> None:
    prefer_latency()
    robot = Robot(8, heartbeat_period=0.5, watch_bus=False)
    never = Event("never", codec="float32")  # a WAIT on it is never answered
    for node in robot.nodes:
        node.register(never)
    entry = robot.nodes[0].entry("never")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    bridge = CanZenohBridge({"interface": "asm_sim", "channel": robot.channel, **robot.options},
                            network=ZenohOptions(listen=(endpoint,)))  # fmt: skip
    operator = Node("operator", ZenohTransport(connect=[endpoint]))
    flooder: subprocess.Popen[str] | None = None
    try:
        while not {f"m{i}" for i in range(1, 9)} <= set(operator.discover()):
            time.sleep(0.1)
        time.sleep(1.0)
        idle = estop_latencies(robot, operator, STOPS)
        flooder = flood(endpoint, "max", 600.0, (entry.class_id, entry.object_id))
        time.sleep(1.0)
        flooded = estop_latencies(robot, operator, STOPS)
        flooder.kill()
        flooder.wait()
        ratio = statistics.median(flooded) / statistics.median(idle)
        print(f"e-stop latency: idle median {statistics.median(idle) * 1e3:.2f} ms (max {max(idle) * 1e3:.1f}), "
              f"flooded median {statistics.median(flooded) * 1e3:.2f} ms (max {max(flooded) * 1e3:.1f}); "
              f"bridge refused {bridge.forwarded['refused']}, forwarded {bridge.forwarded['to_can']}")  # fmt: skip
        print(f"ratio estop_latency_under_flood_vs_idle {ratio:.2f} (target <= 2)", flush=True)

        time.sleep(2.0)
        before = rss_kib()
        flooder = flood(endpoint, os.environ.get("HOG", "hog"), FLOOD_SECONDS, (entry.class_id, entry.object_id))
        assert flooder.stdout is not None
        samples = []
        for _ in range(int(FLOOD_SECONDS // 10)):  # bounded means flat: resident memory every 10 s of the flood
            time.sleep(10.0)
            samples.append(rss_kib() / 1024)
        sent = flooder.stdout.readline().strip()
        flooder.wait(60)
        time.sleep(2.0)
        after = rss_kib()
        print("RSS every 10 s of the flood (MiB): " + ", ".join(f"{m:.0f}" for m in samples))
        print(f"bridge process RSS: {before / 1024:.1f} MiB idle, {after / 1024:.1f} MiB after {FLOOD_SECONDS:.0f} s "
              f"of oversized and never-answered requests ({sent}); pending now {bridge.pending}; "
              f"heap trimmed {bridge.heap.trims} time(s) after the flood")  # fmt: skip
        print(f"ratio bridge_rss_after_flood_vs_idle {after / before:.2f} (target <= 1.2)", flush=True)
    finally:
        if flooder is not None and flooder.poll() is None:
            flooder.kill()
            flooder.wait()
        operator.close()
        bridge.close()
        robot.close()


if __name__ == "__main__":
    main()
