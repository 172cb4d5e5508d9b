"""Cross-process: module processes on Zenoh over loopback, driven by this process and by the example clients."""

from __future__ import annotations

import threading
import time

import pytest

from asm_py import Attribute, EventDrivenService, Node, ServiceError
from asm_py.transport.zenoh import ZenohTransport

from ..helpers import wait_until
from ..processes import Process, run
from ..transports import free_port


@pytest.fixture
def hub():
    """This test's node, listening on a free loopback port; module processes connect to it."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    node = Node("tester", ZenohTransport(listen=[endpoint]))
    node.endpoint = endpoint  # type: ignore[attr-defined]
    yield node
    node.close()


@pytest.fixture
def start_module(hub):
    """Start examples/module.py processes connected to the hub; all are stopped at the end, even on failure."""
    started: list[Process] = []

    def start(name: str = "m1") -> Process:
        process = Process("examples/module.py", "--name", name, "--connect", hub.endpoint)
        started.append(process)
        process.wait_for_line(f"READY {name}")
        assert wait_until(lambda: name in hub.discover(), timeout=15)
        return process

    yield start
    for process in started:
        process.stop()


def test_four_sync_modes_across_processes(hub, start_module) -> None:
    start_module("m1")
    plain = hub.lookup("m1", "plain", timeout=5)
    plain.set(5, wait=True)
    assert plain.valid and plain.get() == 5 and not plain.valid
    fresh = hub.lookup("m1", "fresh", timeout=5)
    with pytest.raises(TimeoutError):
        fresh.get(timeout=0.2)
    fresh.set(6)
    assert fresh.get(timeout=5) == 6
    used = hub.lookup("m1", "used", timeout=5)
    used.set(1, timeout=5)
    with pytest.raises(TimeoutError):
        used.set(2, timeout=0.2)
    assert used.get() == 1
    slot = hub.lookup("m1", "slot", timeout=5)
    got: list[int] = []
    consumer = threading.Thread(target=lambda: [got.append(slot.get(timeout=10)) for _ in range(10)])
    consumer.start()
    for i in range(10):
        slot.set(i, timeout=10)
    consumer.join(20)
    assert got == list(range(10))
    plain.reset(wait=True)
    assert plain.get() == 0


def test_a_remote_sync_get_blocks_only_its_own_client(hub, start_module) -> None:
    start_module("m1")
    other = Node("other-client", ZenohTransport(connect=[hub.endpoint]))
    try:
        fresh = hub.lookup("m1", "fresh", timeout=5)
        box: list[int] = []
        blocked = threading.Thread(target=lambda: box.append(fresh.get(timeout=20)))
        blocked.start()
        time.sleep(0.2)
        plain = other.lookup("m1", "plain", timeout=5)
        for i in range(20):
            plain.set(i, wait=True)
            assert plain.get(timeout=5) == i
        assert hub.lookup("m1", "joint.angle", timeout=5).get(timeout=5) is not None
        assert blocked.is_alive() and not box
        other.lookup("m1", "fresh", timeout=5).set(77, wait=True)
        blocked.join(10)
        assert box == [77]
    finally:
        other.close()


def test_remote_service_lifecycle(hub, start_module) -> None:
    start_module("m1")
    servo = hub.lookup("m1", "servo.service", timeout=5)
    assert servo.started and servo.running
    with pytest.raises(ServiceError):
        servo.start(wait=True)
    servo.suspend(wait=True)
    assert servo.started and not servo.running
    servo.resume(wait=True)
    servo.stop(timeout=5, wait=True)
    assert not servo.started
    servo.reset(wait=True)
    servo.start(wait=True)
    assert servo.running


def test_remote_event_drives_an_event_driven_service(hub, start_module) -> None:
    start_module("m1")
    tick = hub.lookup("m1", "gait.tick", timeout=5)
    handled: list[float] = []
    service = EventDrivenService("tick-counter", tick, handler=handled.append)
    service.start()
    try:
        assert wait_until(lambda: len(handled) >= 10, timeout=15), "a 20 Hz remote timer drives the service"
        assert handled == sorted(handled)
    finally:
        service.stop(timeout=5)


def test_subscribe_to_a_published_angle_and_survive_a_restart(hub, start_module) -> None:
    process = start_module("m1")
    remote = hub.lookup("m1", "joint.angle", timeout=5)
    copy = Attribute("angle.copy", codec="float32")
    copy.subscribe(remote)
    hub.lookup("m1", "joint.goal", timeout=5).set(1.0, wait=True)
    assert wait_until(lambda: copy.peek() is not None and copy.peek() > 0.9, timeout=10), "the angle is published"
    process.stop()
    assert wait_until(lambda: "m1" not in hub.discover(), timeout=10)
    start_module("m1")
    assert wait_until(lambda: copy.peek() < 0.1, timeout=15), "the restarted module's publications arrive"
    hub.lookup("m1", "joint.goal", timeout=5).set(-1.0, wait=True)
    assert wait_until(lambda: copy.peek() < -0.9, timeout=10)
    copy.unsubscribe()


def test_discovery_reports_a_killed_process_within_one_second(hub, start_module) -> None:
    process = start_module("m1")
    left: list[float] = []
    hub.on_discovery(lambda name, alive: left.append(time.monotonic()) if name == "m1" and not alive else None)
    killed_at = time.monotonic()
    process.kill()
    assert wait_until(lambda: left, timeout=5)
    assert left[0] - killed_at < 1.0
    with pytest.raises(TimeoutError):
        hub.lookup("m1", "plain", timeout=0.5)


def test_example_clients_against_a_module(hub, start_module) -> None:
    start_module("m1")
    connect = ["--connect", hub.endpoint]
    out = run("examples/set.py", *connect, "--node", "m1", "--object", "plain", "--value", "42")
    assert out.returncode == 0, out.stdout + out.stderr
    out = run("examples/get.py", *connect, "--node", "m1", "--object", "plain")
    assert out.returncode == 0 and "m1/plain = 42" in out.stdout, out.stdout + out.stderr
    out = run("examples/service.py", *connect, "--node", "m1", "--object", "servo.service", "--do", "suspend")
    assert "started=True running=False" in out.stdout, out.stdout + out.stderr
    out = run("examples/subscribe.py", *connect, "--node", "m1", "--object", "gait.tick", "--count", "3")
    assert out.returncode == 0 and out.stdout.count("m1/gait.tick = ") == 3, out.stdout + out.stderr
    out = run("examples/discover.py", *connect)
    assert "m1" in out.stdout and "tester" in out.stdout, out.stdout + out.stderr
