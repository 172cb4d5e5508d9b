"""The robot process (asm-robot): a simulated robot in real-time physics, reached over a real Zenoh link."""

from __future__ import annotations

import itertools
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

from asm_module.feed import PoseFrame, RobotStatus, decode_poses, encode_poses, mjcf_key, poses_key, status_key
from asm_py.errors import AsmTimeout
from asm_py.node import Node
from asm_py.transport.zenoh import ZenohTransport
from gaits.deploy import deploy
from gaits.model import LIBRARY, load

from ..helpers import wait_until
from ..processes import Process
from ..transports import free_port

pytestmark = pytest.mark.timeout(180)
CATERPILLAR = load(LIBRARY / "caterpillar.toml")


@pytest.fixture
def robot_process(request) -> Iterator[tuple[Process, str]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    process = Process("-m", "server.robot", "--zenoh-listen", endpoint, *getattr(request, "param", ()))
    try:
        process.wait_for_line("READY robot", timeout=60)
        yield process, endpoint
    finally:
        assert process.stop() == 0, "".join(process.output[-30:])


class Viewer:
    """What a viewer sees of the robot: its latest pose frame and status."""

    def __init__(self, session: zenoh.Session, name: str = "robot") -> None:
        self.frames: list[PoseFrame] = []
        self.status: RobotStatus | None = None
        self._lock = threading.Lock()
        self._subs = [session.declare_subscriber(poses_key(name), self._pose),
                      session.declare_subscriber(status_key(name), self._status)]  # fmt: skip

    def _pose(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.frames.append(decode_poses(sample.payload.to_bytes()))
            del self.frames[:-600]

    def _status(self, sample: zenoh.Sample) -> None:
        self.status = RobotStatus.from_json(sample.payload.to_bytes())

    def latest(self) -> PoseFrame | None:
        with self._lock:
            return self.frames[-1] if self.frames else None

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


def test_a_pose_frame_round_trips_and_matches_its_golden_vector() -> None:
    frame = PoseFrame(7, 1.5, np.array([[0.1, -0.2, 0.025]]), np.array([[1.0, 0.0, 0.0, 0.0]]))
    data = encode_poses(frame)
    assert data.hex(" ") == (
        "52 50 01 01 07 00 00 00 00 00 00 00 00 00 f8 3f 01 00 "
        "cd cc cc 3d cd cc 4c be cd cc cc 3c 00 00 80 3f 00 00 00 00 00 00 00 00 00 00 00 00"
    )
    back = decode_poses(data)
    assert back.seq == 7 and back.time == 1.5 and back.simulated
    assert np.allclose(back.positions, frame.positions) and np.allclose(back.quaternions, frame.quaternions)
    for bad in (data[:-1], b"XP" + data[2:], data[:2] + b"\x02" + data[3:]):
        with pytest.raises(ValueError):
            decode_poses(bad)


@pytest.mark.parametrize("robot_process", [(), ("--c-modules", "odd")], ids=["python", "half-C"], indirect=True)
def test_every_pose_frame_of_the_feed_is_a_new_pose(robot_process) -> None:
    """The robot steps its physics to the wall clock by physics steps (2 ms), not by whole module ticks (20 ms):
    while it moves, its 60 Hz feed carries a new pose in every frame, times strictly increasing, about 1/60 s
    apart (at rest it stands still, and so does its feed: server.rest)."""
    _, endpoint = robot_process
    client = Node("tool", ZenohTransport(connect=[endpoint]))
    viewer = Viewer(client.transport.session)  # type: ignore[attr-defined]
    try:
        assert wait_until(lambda: {f"m{i}" for i in range(1, 9)} <= set(client.discover()), 20)
        deploy(client, CATERPILLAR, timeout=5.0)
        with viewer._lock:
            viewer.frames.clear()
        assert wait_until(lambda: len(viewer.frames) > 120, 20)
        with viewer._lock:
            frames = list(viewer.frames[-120:])
        gaps = [b.time - a.time for a, b in itertools.pairwise(frames) if b.seq == a.seq + 1]
        assert len(gaps) > 100
        assert min(gaps) > 0, "no frame repeats the one before"
        assert sorted(gaps)[len(gaps) // 2] == pytest.approx(1 / 60, abs=0.004)
    finally:
        viewer.close()
        client.close()


def test_the_deployed_robot_crawls_in_physics_stops_on_estop_and_starts_again(robot_process) -> None:
    """All modules Python, or modules 1, 3, 5, 7 running the C runtime on the same bus: the same behaviour."""
    _, endpoint = robot_process
    client = Node("tool", ZenohTransport(connect=[endpoint]))
    viewer = Viewer(client.transport.session)  # type: ignore[attr-defined]
    try:
        assert wait_until(lambda: {f"m{i}" for i in range(1, 9)} <= set(client.discover()), 20)
        assert wait_until(lambda: viewer.status is not None and viewer.latest() is not None, 10)
        assert viewer.status.mode == "simulated" and viewer.status.modules == 8  # type: ignore[union-attr]
        mjcf = list(client.transport.session.get(mjcf_key("robot"), timeout=5))  # type: ignore[attr-defined]
        assert "<mujoco" in mjcf[0].ok.payload.to_string()
        still = viewer.latest()
        assert still is not None
        report = deploy(client, CATERPILLAR, timeout=5.0)
        assert report.running == list(range(1, 9))

        def crawled() -> bool:  # simulated time went on (even slowly) and the bodies moved: the robot crawls
            moving = viewer.latest()
            return (moving is not None and moving.time > still.time + 1.0
                    and np.abs(moving.positions - still.positions).max() > 0.02)  # fmt: skip

        assert wait_until(crawled, timeout=20)
        client.estop("test")
        assert wait_until(lambda: viewer.status is not None and len(viewer.status.estop or []) == 8, 5)
        time.sleep(0.5)
        held = viewer.latest()
        time.sleep(1.0)
        after = viewer.latest()
        assert held is not None and after is not None and after.time > held.time + 0.2
        assert np.abs(after.positions - held.positions).max() < 0.005  # every joint holds: the robot stands still
        for i in range(1, 9):
            client.lookup(f"m{i}", "estop", timeout=5).set(False, wait=True)
        report = deploy(client, CATERPILLAR, timeout=5.0)
        assert report.running == list(range(1, 9))
        status = viewer.status
        assert status is not None and (status.real_time_factor or 0.0) > 0  # its value is bench/robot.py's
    finally:
        viewer.close()
        client.close()


def _children(pid: int) -> list[int]:
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(entry))
    return found


def test_the_studio_runs_its_robot_as_a_child_that_dies_with_it_even_on_sigkill() -> None:
    studio = Process("-m", "server.studio", "--port", "0")
    try:
        studio.wait_for_line("READY studio", timeout=90)
        children = _children(studio.popen.pid)
        assert len(children) == 1 and "server.robot" in Path(f"/proc/{children[0]}/cmdline").read_text()
        command = Path(f"/proc/{children[0]}/cmdline").read_text().split("\0")
        handed = command[command.index("--sim") + 1]
        # the gait the robot read at start is on no disk: a file in memory it inherited (or, without memfd, a
        # temporary file gone once the robot is up), and the studio keeps no copy of it open
        assert handed.startswith("/dev/fd/") or not Path(handed).exists(), handed
        studio_fds = [os.readlink(fd) for fd in Path(f"/proc/{studio.popen.pid}/fd").iterdir()]
        assert not any("asm-studio-robot" in target for target in studio_fds), studio_fds
        os.kill(studio.popen.pid, signal.SIGKILL)
        studio.popen.wait(10)
        assert wait_until(lambda: not os.path.exists(f"/proc/{children[0]}") or _zombie(children[0]), 15)
    finally:
        studio.stop()


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


def test_asm_robot_can_takes_the_bridge_options_fd_and_node_id() -> None:
    """`asm-robot --can` is the one command for a real bus: it takes what asm-bridge takes (FD, its node ID)."""
    from server.robot import Robot, RobotOptions
    from server.zenoh_args import ZenohOptions
    from tests.transports import free_port

    channel = f"asm-robot-fd-{os.getpid()}"
    robot = Robot(RobotOptions(sim=None, can={"interface": "virtual", "channel": channel, "fd": True}, node_id=77,
                               network=ZenohOptions(listen=(f"tcp/127.0.0.1:{free_port()}",))))  # fmt: skip
    try:
        assert robot.bridge.can.node_id == 77 and robot.bridge.can.fd
    finally:
        robot.close()


def test_a_deployed_robot_runs_neighbour_events_over_its_bus_and_a_one_shot_curl_says_it_is_done(robot_process) -> None:
    """Module k+1 starts each stroke on module k's state, heard over the robot's CAN bus: every module keeps the
    leader's 1 s cycle (waiting out its 2 s timeout instead would take ~3 s a cycle)."""
    _, endpoint = robot_process
    client = Node("tool", ZenohTransport(connect=[endpoint]))
    try:
        assert wait_until(lambda: {f"m{i}" for i in range(1, 9)} <= set(client.discover()), 20)
        report = deploy(client, load(LIBRARY / "neighbour_caterpillar.toml"), timeout=5.0)
        assert report.running == list(range(1, 9))
        cycles = [client.lookup(f"m{i}", "gait.cycle", timeout=5) for i in (1, 8)]
        first = [c.get(timeout=5) for c in cycles]
        assert wait_until(lambda: cycles[0].get(timeout=5) - first[0] >= 6, timeout=30)  # the span the check had
        lead, last = (c.get(timeout=5) - f for c, f in zip(cycles, first, strict=True))
        # the last module keeps the leader's pace: two strokes behind at most over six (a module waiting out its
        # 2 s timeout instead would do two of the leader's six); on a loaded machine the chain's CAN hand-offs lag
        assert lead >= 6 and last >= lead - 2, (lead, last)
        report = deploy(client, load(LIBRARY / "curl_into_loop.toml"), timeout=5.0)
        done = client.lookup("m4", "gait.done", timeout=5)

        def finished() -> bool:
            try:
                return done.get(timeout=1) == 1  # FINISHED (an event: no value until it fires)
            except AsmTimeout:
                return False

        assert wait_until(finished, 20)  # it curled and stopped by itself
        assert wait_until(lambda: not client.lookup("m4", "gait.service", timeout=5).running, 5)
        assert abs(client.lookup("m4", "joint.angle", timeout=5).get(timeout=5) - 45.0) < 5.0
    finally:
        client.close()
