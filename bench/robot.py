"""The robot process: real-time factor with modules running, live distance against the preview, start skew, e-stop.

    .venv/bin/python bench/robot.py

- ``robot_rtf_32_running`` / ``robot_rtf_128_running``: ``asm-robot --sim`` in its own process with a 32- and a
  128-module caterpillar, deployed and running (modules, bus, bridge and physics all working), its published
  real-time factor after a few seconds. Target >= 1.
- ``live_distance_vs_preview_<gait>``: distance the deployed gait carries the simulated robot in 10 s of wall time
  (the mean of its body positions, from the pose feed, after 2 s), over the preview's distance in 10 s of simulated
  time measured the same way. Target 0.9-1.1.
- ``start_skew_32_vs_tick``: spread of the 32 modules' gait start times (simulated clock) after the one broadcast
  activation, over one control tick (robot in this process). Target <= 1.
- ``estop_hold_ms_vs_50ms``: median wall time from the operator's E-STOP (a Zenoh put) to every simulated module
  latched and holding its joint, over 50 ms (robot in this process). Target <= 1.
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np
import zenoh

from asm_module.feed import RobotStatus, decode_poses, poses_key, status_key
from asm_py.node import Node
from asm_py.transport.zenoh import ZenohTransport
from bench._processes import Child, free_port
from gaits.deploy import deploy
from gaits.model import LIBRARY, dumps, load
from gaits.sim import Simulation
from server.realtime import prefer_latency
from server.robot import Robot, RobotOptions
from server.zenoh_args import ZenohOptions
from web.document import GaitDocument


def resized(name: str, modules: int, folder: Path) -> Path:
    doc = GaitDocument(load(LIBRARY / f"{name}.toml"))
    if modules:
        doc.set_robot("modules", modules)
    path = folder / f"{name}{modules or ''}.toml"
    path.write_text(dumps(doc.gait()))
    return path


class Watch:
    """A viewer of the robot: its status and the mean position of its bodies over time."""

    def __init__(self, session: zenoh.Session) -> None:
        self.status: RobotStatus | None = None
        self.track: list[tuple[float, np.ndarray]] = []
        self._subs = [session.declare_subscriber(status_key("robot"), self._status),
                      session.declare_subscriber(poses_key("robot"), self._poses)]  # fmt: skip

    def _status(self, sample: zenoh.Sample) -> None:
        self.status = RobotStatus.from_json(sample.payload.to_bytes())

    def _poses(self, sample: zenoh.Sample) -> None:
        frame = decode_poses(sample.payload.to_bytes())
        self.track.append((time.monotonic(), frame.positions.mean(axis=0)))

    def moved(self, start: float, end: float) -> float:
        points = [p for t, p in self.track if start <= t <= end]
        return float(np.hypot(*(points[-1] - points[0])[:2])) if len(points) > 1 else 0.0

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


def robot_process(path: Path, *options: str) -> tuple[Child, Node, Watch]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    process = Child("robot", "-m", "server.robot", "--sim", str(path), "--zenoh-listen", endpoint, *options)
    process.ready("READY robot", timeout=120)
    client = Node("bench", ZenohTransport(connect=[endpoint]))
    return process, client, Watch(client.transport.session)  # type: ignore[attr-defined]


def real_time_factor(path: Path, modules: int) -> float:
    process, client, watch = robot_process(path)
    try:
        deadline = time.monotonic() + 60.0
        while not {f"m{i}" for i in range(1, modules + 1)} <= set(client.discover()):
            if time.monotonic() > deadline:
                seen = len(client.discover())
                status = watch.status
                print(f"{modules} modules: only {seen} nodes discovered after 60 s; robot status {status}")
                return status.real_time_factor or 0.0 if status else 0.0
            time.sleep(0.2)
        report = deploy(client, load(path), timeout=10.0, deadline=30.0)
        assert len(report.running) == modules
        time.sleep(4.0)
        factors, behind = [], False
        for _ in range(4):
            time.sleep(1.0)
            factors.append(watch.status.real_time_factor or 0.0)  # type: ignore[union-attr]
            behind |= bool(watch.status.behind)  # type: ignore[union-attr]
        print(f"{modules} modules running: real-time factor each second {', '.join(f'{f:.3f}' for f in factors)}; "
              f"behind the wall clock: {'yes' if behind else 'no'}")  # fmt: skip
        return statistics.median(factors)
    finally:
        watch.close()
        client.close()
        process.stop()


def live_distance(path: Path, *options: str) -> float:
    """Metres the deployed gait carries the robot process's robot from 2 s to 12 s of wall time after the deploy."""
    gait = load(path)
    process, client, watch = robot_process(path, *options)
    try:
        while not {f"m{a.id}" for a in gait.modules} <= set(client.discover()):
            time.sleep(0.2)
        deploy(client, gait, timeout=5.0)
        began = time.monotonic()
        time.sleep(12.5)
        return watch.moved(began + 2.0, began + 12.0)
    finally:
        watch.close()
        client.close()
        process.stop()


def live_vs_preview(path: Path) -> tuple[float, float]:
    gait = load(path)
    with Simulation(gait) as sim:
        sim.start()
        sim.advance(2.0)
        start = sim.data.xpos[1:].mean(axis=0)
        sim.advance(10.0)
        preview = float(np.hypot(*(sim.data.xpos[1:].mean(axis=0) - start)[:2]))
    return live_distance(path), preview


def skew_and_estop(path: Path) -> tuple[float, list[float]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = Robot(RobotOptions(sim=path, network=ZenohOptions(listen=(endpoint,))))
    client = Node("operator", ZenohTransport(connect=[endpoint]))
    try:
        assert robot.sim is not None
        runtimes = list(robot.sim.modules.values())
        while not {f"m{i}" for i in robot.sim.modules} <= set(client.discover()):
            time.sleep(0.2)
        deploy(client, load(path), timeout=10.0, deadline=30.0)
        starts = [r._ramp_start for r in runtimes]
        skew = (max(starts) - min(starts)) / (robot.sim.steps_per_tick * robot.sim.model.opt.timestep)
        holds = []
        for _ in range(10):
            time.sleep(0.5)
            done = threading.Event()

            def check(_: object, done: threading.Event = done) -> None:
                if all(r.latched for r in runtimes):
                    done.set()

            removers = [r.estop.on_change(check) for r in runtimes]
            began = time.perf_counter()
            client.estop("bench")
            done.wait(5)
            holds.append((time.perf_counter() - began) * 1e3)
            for remove in removers:
                remove()
            for runtime in runtimes:
                runtime.estop.set(False)
        return skew, holds
    finally:
        client.close()
        robot.close()


def main() -> None:
    prefer_latency()
    with tempfile.TemporaryDirectory() as folder:
        directory = Path(folder)
        for modules in [int(m) for m in os.environ.get("ROBOT_SIZES", "32,128").split(",")]:
            rtf = real_time_factor(resized("caterpillar", modules, directory), modules)
            print(f"ratio robot_rtf_{modules}_running {rtf:.2f} (target >= 1.0)", flush=True)
        for name in ("caterpillar", "sidewinding"):
            live, preview = live_vs_preview(resized(name, 0, directory))
            ratio = live / preview if preview > 0 else 0.0
            print(f"{name}: live {live:.3f} m in 10 s of wall time, preview {preview:.3f} m in 10 s simulated")
            print(f"ratio live_distance_vs_preview_{name} {ratio:.2f} (target >= 0.9)")
            print(f"ratio live_distance_vs_preview_{name} {ratio:.2f} (target <= 1.1)", flush=True)
        skew, holds = skew_and_estop(resized("caterpillar", 32, directory))
        print(f"ratio start_skew_32_vs_tick {skew:.2f} (target <= 1)")
        print(f"e-stop to every module holding: {', '.join(f'{h:.1f}' for h in holds)} ms")
        print(f"ratio estop_hold_ms_vs_50ms {statistics.median(holds) / 50.0:.2f} (target <= 1)", flush=True)


if __name__ == "__main__":
    main()
