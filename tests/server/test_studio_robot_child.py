"""The studio's own robot child: a studio killed outright while its robot starts leaves nothing on disk (its gait
goes to the child as a file in memory) and no robot behind (the child watches its parent)."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import psutil
import pytest

from ..helpers import wait_until
from ..processes import Process
from ..transports import free_port

pytestmark = pytest.mark.timeout(120)


def test_a_studio_killed_while_its_robot_starts_leaves_no_file_and_no_robot(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    monkeypatch.setenv("TMPDIR", str(temporary))  # the studio's temporary folder, watched here
    studio = Process("-m", "server.studio", "--port", str(free_port()), "--zenoh-listen",
                     f"tcp/127.0.0.1:{free_port()}", "--recordings", str(tmp_path / "recordings"))  # fmt: skip
    robots: list[psutil.Process] = []
    try:

        def robot_starting() -> bool:
            robots[:] = [c for c in psutil.Process(studio.popen.pid).children()
                         if "server.robot" in " ".join(c.cmdline())]  # fmt: skip
            return bool(robots)

        assert wait_until(robot_starting, timeout=60, interval=0.01), "".join(studio.output)
        assert "READY robot" not in "".join(studio.output)  # killed before its robot was up
        os.kill(studio.popen.pid, signal.SIGKILL)
        studio.popen.wait(10)
        _, alive = psutil.wait_procs(robots, timeout=30)
        assert not alive, "the robot outlived its studio"
        assert list(temporary.iterdir()) == []
    finally:
        for robot in robots:
            if robot.is_running():
                robot.kill()
        studio.stop()


def test_a_studio_hands_its_robot_the_gait_in_memory_and_it_starts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    monkeypatch.setenv("TMPDIR", str(temporary))
    studio = Process("-m", "server.studio", "--port", str(free_port()), "--zenoh-listen",
                     f"tcp/127.0.0.1:{free_port()}", "--recordings", str(tmp_path / "recordings"))  # fmt: skip
    try:
        studio.wait_for_line("READY studio", timeout=90)
        assert list(temporary.iterdir()) == []
        began = time.monotonic()
        assert studio.stop() in (0, -15) and time.monotonic() - began < 30
    finally:
        studio.stop()
