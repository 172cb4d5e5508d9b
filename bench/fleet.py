"""Fleet benchmark: four simulated robots with the same module IDs and a studio on one Zenoh router (issue 25).

Every process is what a lab runs — ``asm-router``, four ``asm-robot --sim`` (8 modules each, robots a-d) as its
clients — and the figures are measured from here, a client of the same router:

- ``fleet_crosstalk_requests``: requests, deploys, drives and e-stops aimed at each robot in turn, counted where they
  arrive (each robot's bridge counts the messages from Zenoh it puts on its bus, and the e-stops); those that reached
  another robot than the one aimed at, over those sent — target 0;
- ``fleet_discovery_s_vs_2s``: from a studio's start (in this process, attached to the router) to its page listing
  all four robots with their 8 modules each, over 2 s;
- ``robot_estop_ms_via_router_vs_50ms``: a robot's e-stop through the router until every module of that robot holds
  (read from the robot's status, which reads its modules when asked), median of 10, over 50 ms;
- ``lab_estop_ms_vs_100ms``: the lab-wide e-stop until all 32 modules hold, median of 10, over 100 ms;
- ``rtt_via_router_vs_direct``: a remote get of a float32 through the router over the same get on a direct peer link
  to the same module node, interleaved rounds, medians, same run.

Run: .venv/bin/python bench/fleet.py
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import zenoh

from asm_module.feed import RobotStatus
from asm_module.names import module_name
from asm_py import Attribute, Node
from asm_py.keys import RobotKeys, lab_estop
from asm_py.transport.zenoh import ZenohTransport
from bench._processes import Child, free_port
from gaits.deploy import deploy, start_all
from gaits.drive import STOP, drive
from gaits.model import LIBRARY, load
from server.zenoh_args import ZenohOptions

ROBOTS = ("a", "b", "c", "d")
MODULES = [module_name(i) for i in range(1, 9)]
GAIT = LIBRARY / "caterpillar.toml"
ESTOPS = 10
GETS = 400


def status(session: zenoh.Session, robot: str) -> RobotStatus:
    for reply in session.get(RobotKeys(robot).robot_key("status"), timeout=2.0):
        if reply.ok is not None:
            return RobotStatus.from_json(reply.ok.payload.to_bytes())
    raise RuntimeError(f"robot {robot} did not answer")


def arrived(session: zenoh.Session) -> dict[str, int]:
    """Per robot: the messages from Zenoh its bridge put on its bus, plus the e-stops it took from Zenoh."""
    counts = {}
    for robot in ROBOTS:
        traffic = status(session, robot).traffic
        counts[robot] = traffic.get("to_can", 0) + traffic.get("estops", 0)
    return counts


def release(node: Node) -> None:
    for module in MODULES:
        node.lookup(module, "estop", timeout=5).set(False, timeout=5)


def crosstalk(router: str, session: zenoh.Session) -> tuple[int, int]:
    """(messages that reached a robot they were not aimed at, messages aimed)."""
    gait = load(GAIT)
    stray = sent = 0
    for robot in ROBOTS:
        node = Node("bench", ZenohTransport(robot=robot, mode="client", connect=[router]))
        try:
            deadline = time.monotonic() + 30
            while not set(MODULES) <= set(node.discover()) and time.monotonic() < deadline:
                time.sleep(0.1)
            before = arrived(session)
            for module in MODULES:  # requests: gets and sets
                goal = node.lookup(module, "joint.goal", timeout=5)
                goal.get(timeout=5)
                goal.set(0.0, timeout=5)
            deploy(node, gait)  # a deploy
            drive(node, gait, STOP, MODULES)  # a drive (stop), and a start
            start_all(node, MODULES)
            node.estop("bench")  # an e-stop
            time.sleep(0.3)
            after = arrived(session)
            sent += after[robot] - before[robot]
            stray += sum(after[r] - before[r] for r in ROBOTS if r != robot)
            release(node)
        finally:
            node.close()
    return stray, sent


def discovery_seconds(router: str) -> float:
    from server.studio import Studio, StudioOptions

    start = time.monotonic()
    studio = Studio(StudioOptions(robot=router, network=ZenohOptions(mode="client", connect=(router,)), port=0))
    try:
        while True:
            robots = studio.app.bar.robots
            if len(robots) == len(ROBOTS) and all(r.modules == len(MODULES) for r in robots):
                return time.monotonic() - start
            if time.monotonic() - start > 60:
                raise RuntimeError(f"the studio listed {robots}")
            time.sleep(0.005)
    finally:
        studio.close()


def estop_ms(session: zenoh.Session, robots: tuple[str, ...], send) -> float:
    """Milliseconds from ``send()`` until every module of ``robots`` reads back latched (their statuses)."""
    start = time.perf_counter()
    send()
    waiting = set(robots)
    while waiting:
        waiting = {r for r in waiting if len(status(session, r).estop or []) < len(MODULES)}
    return (time.perf_counter() - start) * 1000


def estops(router: str, session: zenoh.Session) -> tuple[float, float]:
    tools = {r: Node("bench", ZenohTransport(robot=r, mode="client", connect=[router])) for r in ROBOTS}
    try:
        robot_ms, lab_ms = [], []
        lab = lab_estop("~bench")
        for _ in range(ESTOPS):
            robot_ms.append(estop_ms(session, ("a",), lambda: tools["a"].estop("bench")))
            release(tools["a"])
            lab_ms.append(
                estop_ms(session, ROBOTS, lambda: session.put(lab, b"bench", priority=zenoh.Priority.REAL_TIME))
            )
            for node in tools.values():
                release(node)
        return statistics.median(robot_ms), statistics.median(lab_ms)
    finally:
        for node in tools.values():
            node.close()


def rtt_ratio(router: str) -> tuple[float, float]:
    """Median get round trip through the router and over a direct peer link, to one module node."""
    direct = f"tcp/127.0.0.1:{free_port()}"
    module = Node("probe", ZenohTransport(robot="bench", role="module", mode="peer", listen=[direct],
                                           connect=[router]))  # fmt: skip
    module.register(Attribute("value", 1.5, codec="float32"))
    via_router = Node("via-router", ZenohTransport(robot="bench", mode="client", connect=[router]))
    peer = Node("peer", ZenohTransport(robot="bench", connect=[direct]))
    try:
        remotes = [node.lookup("probe", "value", timeout=10) for node in (via_router, peer)]
        times: list[list[float]] = [[], []]
        for _ in range(GETS // 100):
            for k, remote in enumerate(remotes):
                for _ in range(100):
                    start = time.perf_counter()
                    remote.get()
                    times[k].append(time.perf_counter() - start)
        return statistics.median(times[0]) * 1e6, statistics.median(times[1]) * 1e6
    finally:
        peer.close()
        via_router.close()
        module.close()


def raw_rtt_ratio(router: str) -> tuple[float, float]:
    """The same two paths for a raw Zenoh queryable (no ASM): what the router hop costs Zenoh itself."""
    direct = f"tcp/127.0.0.1:{free_port()}"
    server = ZenohOptions(listen=(direct,), connect=(router,)).open()
    queryable = server.declare_queryable("bench/raw", lambda q: (q.reply("bench/raw", b"\x00\x00\xc0?"), q.drop()))
    sessions = [ZenohOptions(mode="client", connect=(router,)).open(), ZenohOptions(connect=(direct,)).open()]
    try:
        time.sleep(0.5)
        queriers = [s.declare_querier("bench/raw", timeout=2.0) for s in sessions]
        times: list[list[float]] = [[], []]
        for _ in range(GETS // 100):
            for k, querier in enumerate(queriers):
                for _ in range(100):
                    start = time.perf_counter()
                    list(querier.get())
                    times[k].append(time.perf_counter() - start)
        return statistics.median(times[0]) * 1e6, statistics.median(times[1]) * 1e6
    finally:
        for session in sessions:
            session.close()
        queryable.undeclare()
        server.close()


def main() -> int:
    router = f"tcp/127.0.0.1:{free_port()}"
    children = [Child("router", "-m", "server.router", "--listen", router)]
    try:
        children[0].ready("READY router")
        for robot in ROBOTS:
            children.append(Child(f"robot {robot}", "-m", "server.robot", "--name", robot, "--sim", str(GAIT),
                                  "--zenoh-mode", "client", "--zenoh-connect", router))  # fmt: skip
        for child in children[1:]:
            child.ready("READY robot", timeout=120)
        session = ZenohOptions(mode="client", connect=(router,)).open()
        try:
            stray, sent = crosstalk(router, session)
            discovery = discovery_seconds(router)
            robot_ms, lab_ms = estops(router, session)
            routed, direct = rtt_ratio(router)
            raw_routed, raw_direct = raw_rtt_ratio(router)
        finally:
            session.close()
    finally:
        for child in reversed(children):
            child.stop()
    print(f"messages aimed at one robot: {sent}; reached another: {stray}")
    print(f"ratio fleet_crosstalk_requests {stray / max(sent, 1):.3f} (target == 0)")
    print(f"ratio fleet_discovery_s_vs_2s {discovery / 2.0:.2f} (target <= 1)  [{discovery:.2f} s]")
    print(f"ratio robot_estop_ms_via_router_vs_50ms {robot_ms / 50.0:.2f} (target <= 1)  [{robot_ms:.1f} ms]")
    print(f"ratio lab_estop_ms_vs_100ms {lab_ms / 100.0:.2f} (target <= 1)  [{lab_ms:.1f} ms, 32 modules]")
    print(f"ratio rtt_via_router_vs_direct {routed / direct:.2f} (target <= 1.5)  [{routed:.0f} us vs {direct:.0f} us]")
    print(
        f"context: raw Zenoh get via the router over direct {raw_routed / raw_direct:.2f}  "
        f"[{raw_routed:.0f} us vs {raw_direct:.0f} us]: the router hop's own cost"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
