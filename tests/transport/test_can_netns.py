"""CAN between OS processes: python-can's udp_multicast interface, ONLY inside a network namespace this test makes
with nothing but its loopback device (never on the host's network). A module process and a bridge process share the
multicast "bus"; a Zenoh client process in the same namespace drives the module through the bridge."""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator

import pytest

from ..processes import Process, run
from ..transports import fresh_name

GROUP = "239.74.163.2"


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30)


@pytest.fixture
def netns() -> Iterator[str]:
    """A loopback-only network namespace with multicast routed to lo; removed afterwards."""
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("needs root and iproute2 to create a private network namespace for udp_multicast")
    name = fresh_name("asm-test")
    made = _ip("netns", "add", name)
    if made.returncode != 0:
        pytest.skip(f"cannot create a network namespace here: {made.stderr.strip()}")
    try:
        for command in (("link", "set", "lo", "up"), ("link", "set", "lo", "multicast", "on"),
                        ("route", "add", "224.0.0.0/4", "dev", "lo")):  # fmt: skip
            done = _ip("-n", name, *command)
            assert done.returncode == 0, done.stderr
        links = _ip("-n", name, "-o", "link").stdout.splitlines()
        assert len(links) == 1 and ": lo:" in links[0], links  # nothing but loopback
        yield name
    finally:
        _ip("netns", "del", name)


def test_module_and_bridge_in_separate_processes_over_udp_multicast(netns: str) -> None:
    pytest.importorskip("msgpack", reason="python-can's udp_multicast interface needs msgpack")
    inside = ("ip", "netns", "exec", netns)
    can = f"udp_multicast:{GROUP}"
    picked = run(
        "-c", "import socket; s = socket.socket(); s.bind(('127.0.0.1', 0)); print(s.getsockname()[1])", prefix=inside
    )  # a port free inside the namespace, picked there
    endpoint = f"tcp/127.0.0.1:{int(picked.stdout)}"
    module = Process("examples/can_module.py", "--can", can, "--node-id", "1", "--name", "m1", prefix=inside)
    bridge = Process("-m", "server.bridge", "--can", can, "--zenoh-listen", endpoint, prefix=inside)
    try:
        module.wait_for_line("READY m1")
        bridge.wait_for_line("READY bridge")
        common = ("--connect", endpoint, "--node", "m1")
        done = run("examples/set.py", *common, "--object", "plain", "--value", "7", prefix=inside)
        assert done.returncode == 0, done.stdout + done.stderr
        done = run("examples/get.py", *common, "--object", "plain", prefix=inside)
        assert done.returncode == 0 and "m1/plain = 7" in done.stdout, done.stdout + done.stderr
    finally:
        bridge.stop()
        module.stop()


DEPLOY = r"""
import sys, time
from asm_py.node import Node
from asm_py.transport.zenoh import ZenohTransport
from gaits.deploy import deploy
from gaits.model import LIBRARY, load
from web.document import GaitDocument
doc = GaitDocument(load(LIBRARY / "caterpillar.toml"))
doc.set_robot("modules", 3)
gait = doc.gait()
node = Node("operator", ZenohTransport(connect=[sys.argv[1]]))
deadline = time.monotonic() + 30
while not {"m1", "m2", "m3"} <= set(node.discover()) and time.monotonic() < deadline:
    time.sleep(0.2)
report = deploy(node, gait, timeout=5.0)
print("RUNNING", report.running, flush=True)
angle = node.lookup("m2", "joint.angle", timeout=5)
seen = []
remove = angle.on_change(seen.append)
time.sleep(2.0)
remove()
print("ANGLES", len(seen), round(max(seen) - min(seen), 1) if seen else 0, flush=True)
node.close()
"""


def test_a_real_bus_robot_computer_modules_in_processes_and_a_deploying_tool(netns: str) -> None:
    """The real-robot topology without hardware: three asm-module processes and asm-robot --can share the bus;
    a tool reaches them over Zenoh, deploys a 3-module gait as a transaction and sees the joints move."""
    pytest.importorskip("msgpack", reason="python-can's udp_multicast interface needs msgpack")
    inside = ("ip", "netns", "exec", netns)
    can = f"udp_multicast:{GROUP}"
    picked = run(
        "-c", "import socket; s = socket.socket(); s.bind(('127.0.0.1', 0)); print(s.getsockname()[1])", prefix=inside
    )
    endpoint = f"tcp/127.0.0.1:{int(picked.stdout)}"
    modules = [Process("-m", "server.module", "--can", can, "--node-id", str(i), prefix=inside) for i in (1, 2, 3)]
    robot = Process("-m", "server.robot", "--can", can, "--zenoh-listen", endpoint, prefix=inside)
    try:
        for i, module in enumerate(modules, start=1):
            module.wait_for_line(f"READY m{i}")
        robot.wait_for_line("READY robot")
        done = run("-c", DEPLOY, endpoint, prefix=inside, timeout=120)
        assert "RUNNING [1, 2, 3]" in done.stdout, done.stdout + done.stderr
        count, swing = done.stdout.split("ANGLES", 1)[1].split()[:2]
        assert int(count) > 5 and float(swing) > 5.0, done.stdout  # the twin's input: joint angles published
    finally:
        robot.stop()
        for module in modules:
            module.stop()
