"""A robot at rest costs nothing (server.rest, issue 31): a simulated robot with no gait running and nothing moving
stops stepping its physics, while its time, status and feed go on; anything that can move it wakes it."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from asm_py.node import Node
from asm_py.transport.zenoh import ZenohTransport
from gaits.deploy import deploy
from gaits.model import LIBRARY, load
from server.robot import Robot, RobotOptions
from server.zenoh_args import ZenohOptions

from ..helpers import wait_until
from ..transports import free_port
from .test_robot import Viewer

pytestmark = pytest.mark.timeout(180)


@pytest.fixture(params=["python", "c"])
def robot(request: pytest.FixtureRequest) -> Iterator[tuple[Robot, Node, Viewer]]:
    """The caterpillar's robot, its modules all Python or all C (the C runtime rests too; issue 31)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = Robot(RobotOptions(sim=LIBRARY / "caterpillar.toml", network=ZenohOptions(listen=(endpoint,)),
                               c_modules="all" if request.param == "c" else ()))  # fmt: skip
    client = Node("tool", ZenohTransport(connect=[endpoint]))
    viewer = Viewer(client.transport.session)  # type: ignore[attr-defined]
    try:
        assert wait_until(lambda: {f"m{i}" for i in range(1, 9)} <= set(client.discover()), 20)
        yield robot, client, viewer
    finally:
        viewer.close()
        client.close()
        robot.close()


@pytest.mark.realtime  # the resting robot's clock against the wall clock: beside four workers 1.54 s in 2.0
def test_a_still_robot_rests_its_time_goes_on_and_a_command_wakes_it(robot) -> None:
    robot, client, viewer = robot
    loop = robot.loop
    assert loop is not None and robot.sim is not None
    assert wait_until(lambda: loop.resting, timeout=30), "the caterpillar lying still never came to rest"
    with viewer._lock:
        viewer.frames.clear()
    began, sim_began, given_up = time.monotonic(), robot.sim.data.time, loop.given_up
    time.sleep(2.0)
    wall, simulated = time.monotonic() - began, robot.sim.data.time - sim_began
    assert loop.resting
    # its clock keeps the wall clock's pace without physics, but for time it gave up, said (starved more than
    # MAX_LAG, as beside the suite's other workers: 1.54 s in 2.0, twice); some of it is always kept
    assert simulated + (loop.given_up - given_up) == pytest.approx(wall, abs=0.3) and simulated > 0.5
    assert 2 <= len(viewer.frames) <= 8  # a pose every REST_TICK, not 60 a second of the same pose
    assert client.lookup("m3", "joint.angle", timeout=5).get(timeout=5) == pytest.approx(0.0, abs=2.0)
    client.lookup("m3", "joint.goal", timeout=5).set(30.0, wait=True)  # a command: the physics wakes
    angle = client.lookup("m3", "joint.angle", timeout=5)
    assert wait_until(lambda: angle.get(timeout=5) > 20.0, timeout=10)
    assert wait_until(lambda: loop.resting, timeout=30)  # still again: rests again
    assert loop.rest.rests >= 2


def test_a_deploy_to_a_resting_robot_runs_as_on_a_moving_one(robot) -> None:
    robot, client, viewer = robot
    loop = robot.loop
    assert loop is not None
    assert wait_until(lambda: loop.resting, timeout=30)
    report = deploy(client, load(LIBRARY / "caterpillar.toml"), timeout=5.0)
    assert report.running == list(range(1, 9))
    assert wait_until(lambda: not loop.resting, timeout=5)
    assert wait_until(lambda: viewer.latest() is not None, timeout=10)  # (none had come yet once, in CI's load)
    first = viewer.latest()
    assert first is not None
    assert wait_until(lambda: (latest := viewer.latest()) is not None and latest.time > first.time + 2.0, 15)
    assert not loop.resting  # a running gait never rests
    client.estop("test")  # the e-stop holds every joint; still, the robot rests, latched
    assert wait_until(lambda: loop.resting, timeout=30)
    assert robot.sim is not None and robot.sim.latched() == list(range(1, 9))
