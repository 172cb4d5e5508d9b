"""Several robots and tools on one Zenoh network, as a lab deploys them: an ``asm-router``, robots and tools as its
clients, in separate processes. Robots whose modules have the same IDs never hear each other; names are unique; a
tool never answers for a module; the robot e-stop stops one robot, the lab-wide e-stop every robot."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from asm_module.names import module_name
from asm_py import Attribute, Node
from asm_py.transport.zenoh import NameTaken, ZenohTransport
from gaits.deploy import deploy
from gaits.drive import drive
from gaits.model import LIBRARY, load

from ..helpers import ROOT, wait_until
from ..processes import Process, run
from ..transports import free_port, fresh_name

pytestmark = pytest.mark.timeout(180)
STEERABLE = LIBRARY / "steerable_caterpillar.toml"
MODULES = [module_name(a.id) for a in load(STEERABLE).modules]


def tool(robot: str, router: str, name: str = "tester") -> Node:
    return Node(name, ZenohTransport(robot=robot, mode="client", connect=[router]))


@pytest.fixture
def lab() -> Iterator[str]:
    """A router and two simulated steerable caterpillars, ``a`` and ``b`` (modules m1-m8 each), as its clients."""
    router = f"tcp/127.0.0.1:{free_port()}"
    processes = [Process("-m", "server.router", "--listen", router)]
    try:
        processes[0].wait_for_line("READY router")
        for robot in ("a", "b"):
            processes.append(Process("-m", "server.robot", "--name", robot, "--sim", str(STEERABLE), "--zenoh-mode",
                                     "client", "--zenoh-connect", router))  # fmt: skip
        for process in processes[1:]:
            process.wait_for_line("READY robot", timeout=60)
        yield router
    finally:
        for process in reversed(processes):
            process.stop()


def snapshot(node: Node) -> list[tuple[object, ...]]:
    """What a robot's modules run, read back from each: deploy ID, gait running, mode, e-stop, lease holder."""
    rows = []
    for module in MODULES:
        names = ("gait.activate", "gait.service", "gait.mode", "estop", "gait.lease")
        read = {name: node.lookup(module, name, timeout=5) for name in names}
        rows.append((read["gait.activate"].peek(), read["gait.service"].running, read["gait.mode"].peek(),
                     read["estop"].peek(), read["gait.lease"].peek()["holder"]))  # fmt: skip
    return rows


def test_a_deploy_a_drive_and_an_estop_for_robot_a_change_nothing_on_robot_b(lab: str) -> None:
    a, b = tool("a", lab), tool("b", lab)
    try:
        for node in (a, b):
            assert wait_until(lambda node=node: set(MODULES) <= set(node.discover()), timeout=20)
        before = snapshot(b)
        gait = load(STEERABLE)
        report = deploy(a, gait)
        assert report.running == [a.id for a in gait.modules]
        assert snapshot(b) == before, "a deploy to robot a reached robot b"
        assert drive(a, gait, "left", MODULES) == MODULES
        assert snapshot(b) == before, "a drive of robot a reached robot b"
        a.estop("test")
        assert wait_until(lambda: all(row[3] for row in snapshot(a)), timeout=10)
        assert snapshot(b) == before, "robot a's e-stop reached robot b"
        # and the other way round: robot b's own tool addresses b, a tool of a addresses b by its address
        assert a.lookup("b/m3", "estop", timeout=5).peek() is False
        assert a.lookup("m3", "estop", timeout=5).peek() is True
        # the lab-wide e-stop, from the one-line command: every module of both robots latches
        done = run("-m", "server.estop", "--zenoh-mode", "client", "--zenoh-connect", lab, timeout=60)
        assert done.returncode == 0, done.stdout + done.stderr
        count = len(MODULES)
        assert done.stdout.strip().count("\n") == 0 and f"robot a: {count} of {count}" in done.stdout, done.stdout
        assert f"robot b: {count} of {count} modules latched" in done.stdout
        assert all(row[3] for row in snapshot(b))
    finally:
        a.close()
        b.close()


def test_a_taken_name_is_refused_in_one_line_and_a_tool_never_answers_for_a_module(lab: str) -> None:
    again = run("-m", "server.robot", "--name", "a", "--zenoh-mode", "client", "--zenoh-connect", lab, timeout=60)
    assert again.returncode == 1 and "READY" not in again.stdout
    assert again.stderr.strip().count("\n") == 0, again.stderr
    assert "asm-robot: error: a robot named 'a' is already on this Zenoh network" in again.stderr
    with pytest.raises(NameTaken, match="a module named 'm3' is already alive in robot 'a'"):
        Node("m3", ZenohTransport(robot="a", role="module", mode="client", connect=[lab]))
    impostor = Node("m3", ZenohTransport(robot="a", mode="client", connect=[lab]))  # a tool may be called m3 …
    client = tool("a", lab)
    try:
        impostor.register(Attribute("estop", "not the module's", codec="str"))
        assert wait_until(lambda: {"m3", "~m3"} <= set(client.discover()), timeout=20)
        estop = client.lookup("m3", "estop", timeout=5)  # … and is never the one that answers for module m3
        assert estop.info.codec.spec == "bool" and estop.peek() in (True, False)
        assert client.lookup("~m3", "estop", timeout=5).peek() == "not the module's"
        with pytest.raises(NameTaken, match="a tool named 'tester'"):
            tool("a", lab)  # one name, one tool, per robot
        other = tool("b", lab)  # the same tool name in another robot is another name
        other.close()
    finally:
        client.close()
        impostor.close()


def _race(claim, count: int = 2) -> list[object]:  # type: ignore[no-untyped-def]
    """``claim()`` in ``count`` threads released at the same moment; what each returned or raised."""
    barrier = threading.Barrier(count)
    results: list[object] = []

    def run() -> None:
        barrier.wait()
        try:
            results.append(claim())
        except Exception as exc:
            results.append(exc)

    threads = [threading.Thread(target=run) for _ in range(count)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(30)
    return results


def test_two_sessions_claiming_one_name_at_the_same_moment_never_both_start(lab: str) -> None:
    """The tie-break after a claim: of two sessions started together for one name, exactly one keeps it (modules
    and robots alike), however the race falls."""
    from asm_module.feed import RobotStatus
    from asm_py.transport.zenoh_config import make_config
    from server.robot_feed import RobotFeed, RobotNameTaken

    for trial in range(4):
        name = f"m{90 + trial}"
        nodes = _race(lambda name=name: Node(name, ZenohTransport(robot="a", role="module", mode="client",
                                                                  connect=[lab])))  # fmt: skip
        kept = [n for n in nodes if isinstance(n, Node)]
        assert len(kept) == 1 and any(isinstance(n, NameTaken) for n in nodes), (trial, nodes)
        for node in kept:
            node.close()
        sessions = [zenoh.open(make_config(mode="client", connect=[lab])) for _ in range(2)]
        free = list(sessions)  # each racer takes one (list.pop is atomic)
        feeds = _race(lambda robot=f"z{trial}", free=free: RobotFeed(free.pop(), RobotStatus(robot, "real", 0)))
        kept_feeds = [f for f in feeds if isinstance(f, RobotFeed)]
        assert len(kept_feeds) == 1 and any(isinstance(f, RobotNameTaken) for f in feeds), (trial, feeds)
        for feed in kept_feeds:
            feed.close()
        for session in sessions:
            session.close()


def test_a_tool_names_a_module_of_its_own_robot_with_or_without_the_robot(lab: str) -> None:
    client = tool("a", lab)
    try:
        for address in ("m3", "a/m3"):
            began = time.monotonic()
            assert client.lookup(address, "estop", timeout=5).peek() in (True, False)
            assert time.monotonic() - began < 1.0, address  # not the whole timeout
    finally:
        client.close()


def test_a_query_of_every_robots_model_is_answered_under_each_robots_own_key(lab: str) -> None:
    import zenoh

    from asm_py.transport.zenoh_config import make_config

    session = zenoh.open(make_config(mode="client", connect=[lab]))
    try:
        replies = [r.ok for r in session.get("asm/*/@robot/mjcf", timeout=5) if r.ok is not None]
        assert sorted(str(r.key_expr) for r in replies) == ["asm/a/@robot/mjcf", "asm/b/@robot/mjcf"]
        statuses = [r.ok for r in session.get("asm/*/@robot/status", timeout=5) if r.ok is not None]
        assert sorted(str(r.key_expr) for r in statuses) == ["asm/a/@robot/status", "asm/b/@robot/status"]
        requests = list(session.get("asm/a/*/req/prober", payload=bytes.fromhex("5001000067"), timeout=5))
        keys = sorted(str(r.ok.key_expr) for r in requests if r.ok is not None)
        assert keys == sorted(f"asm/a/{m}/req/prober" for m in MODULES), keys
    finally:
        session.close()


# -- the same topology across two machines: network namespaces linked only to each other --------------------------


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30)


@pytest.fixture
def two_machines() -> Iterator[tuple[str, str]]:
    """Two network namespaces — a robot computer (10.77.0.1) and a laptop (10.77.0.2) — each with its loopback and
    one end of a veth pair between them, nothing else; removed afterwards."""
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("needs root and iproute2 to make private network namespaces")
    robot, laptop = fresh_name("asm-robotpc"), fresh_name("asm-laptop")
    made = [ns for ns in (robot, laptop) if _ip("netns", "add", ns).returncode == 0]
    try:
        if len(made) < 2:
            pytest.skip("cannot create network namespaces here")
        tag = str(os.getpid() % 100000)
        ends = (f"r{tag}", f"l{tag}")
        assert _ip("link", "add", ends[0], "netns", robot, "type", "veth", "peer", "name", ends[1], "netns",
                   laptop).returncode == 0  # fmt: skip
        for ns, end, address in ((robot, ends[0], "10.77.0.1/30"), (laptop, ends[1], "10.77.0.2/30")):
            for command in (("link", "set", "lo", "up"), ("addr", "add", address, "dev", end),
                            ("link", "set", end, "up")):  # fmt: skip
                done = _ip("-n", ns, *command)
                assert done.returncode == 0, done.stderr
            links = _ip("-n", ns, "-o", "link").stdout.splitlines()
            assert len(links) == 2 and ": lo:" in links[0] and end in links[1], links  # loopback and the link
        yield robot, laptop
    finally:
        for ns in made:
            _ip("netns", "del", ns)


LAPTOP = textwrap.dedent("""
    import sys
    from asm_py import Node
    from asm_py.transport.zenoh import ZenohTransport
    from gaits.deploy import deploy
    from gaits.model import LIBRARY, load
    router, config = sys.argv[1], sys.argv[2]
    node = Node("operator", ZenohTransport(robot="a", mode="client", connect=[router], config_file=config))
    names = [f"m{i}" for i in range(1, 9)]
    import time
    deadline = time.monotonic() + 30
    while not set(names) <= set(node.discover()) and time.monotonic() < deadline:
        time.sleep(0.2)
    report = deploy(node, load(LIBRARY / "caterpillar.toml"))
    print("RUNNING", len(report.running), flush=True)
    node.estop("laptop")
    time.sleep(0.5)
    print("LATCHED", sum(bool(node.lookup(n, "estop", timeout=5).peek()) for n in names), flush=True)
    node.close()
""")


def test_a_robot_computer_and_a_laptop_through_a_router_over_tls(two_machines: tuple[str, str], tmp_path: Path) -> None:
    """The documented lab topology across two machines: the router and robot ``a`` on the robot computer, an
    operator's tool on the laptop, every link TLS with mutual authentication and access control."""
    from ..certs import Authority, secure_config

    robot_ns, laptop_ns = two_machines
    authority = Authority(tmp_path)
    operators = ("router", "laptop")
    router_config = secure_config(tmp_path, authority, "router", ("10.77.0.1",), operators)
    robot_config = secure_config(tmp_path, authority, "robot", (), operators)
    laptop_config = secure_config(tmp_path, authority, "laptop", (), operators)
    on_robot, on_laptop = ("ip", "netns", "exec", robot_ns), ("ip", "netns", "exec", laptop_ns)
    port = run("-c", "import socket; s = socket.socket(); s.bind(('10.77.0.1', 0)); print(s.getsockname()[1])",
               prefix=on_robot).stdout.strip()  # fmt: skip
    router = f"tls/10.77.0.1:{port}"
    processes = [Process("-m", "server.router", "--listen", router, "--zenoh-config", router_config, prefix=on_robot)]
    try:
        processes[0].wait_for_line("READY router")
        processes.append(Process("-m", "server.robot", "--name", "a", "--zenoh-mode", "client", "--zenoh-connect",
                                 router, "--zenoh-config", robot_config, prefix=on_robot))  # fmt: skip
        processes[1].wait_for_line("READY robot", timeout=60)
        laptop = subprocess.run([*on_laptop, sys.executable, "-c", LAPTOP, router, laptop_config], cwd=ROOT,
                                capture_output=True, text=True, timeout=120)  # fmt: skip
        assert "RUNNING 8" in laptop.stdout and "LATCHED 8" in laptop.stdout, laptop.stdout + laptop.stderr
    finally:
        for process in reversed(processes):
            process.stop()
