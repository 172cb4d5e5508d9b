"""The Live source of the 3D view: the robot process's pose feed, as any viewer receives it over Zenoh.

A simulated robot publishes its bodies' poses (asm_module/feed.py) and answers its MuJoCo model on request; this keeps
the newest frame and the model to draw it with. A real robot has no poses: :class:`KinematicTwin` poses a model of
the edited gait's robot from the modules' ``joint.angle`` publications, with its base fixed where the model puts it
(it shows the joints, not where the robot went). Callbacks run on Zenoh's or the bus's threads and only store; the
view reads.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np
import zenoh

from asm_module.feed import PoseFrame, RobotStatus, decode_poses, mjcf_key, poses_key, status_key
from asm_module.names import module_name
from gaits.mjcf import build_mjcf
from gaits.model import Gait

log = logging.getLogger("asm_studio.live")


class LiveFeed:
    """The newest pose frame and status of robot ``name``, and its model (fetched when the robot changes)."""

    def __init__(self, session: zenoh.Session, name: str = "robot") -> None:
        self.session = session
        self.name = name
        self.model: mujoco.MjModel | None = None
        self.status: RobotStatus | None = None
        self._status_at: float | None = None
        self.latest: PoseFrame | None = None
        self.generation = 0
        """Incremented when the model changes (the view rebuilds its meshes)."""
        self.path: deque[tuple[float, float, float]] = deque(maxlen=600)
        """(time, x, y) of the robot's first body, the last 10 s of frames at 60 Hz: for distance and speed."""
        self._changed = threading.Event()
        self._lock = threading.Lock()
        self._want_model = threading.Event()
        self._want_model.set()
        self._stop = threading.Event()
        self._removers: list[Callable[[], object]] = []
        self._subs = [session.declare_subscriber(poses_key(name), self._on_poses),
                      session.declare_subscriber(status_key(name), self._on_status)]  # fmt: skip
        self._fetcher = threading.Thread(target=self._fetch_models, name="live-model", daemon=True)
        self._fetcher.start()

    def _on_poses(self, sample: zenoh.Sample) -> None:
        try:
            frame = decode_poses(sample.payload.to_bytes())
        except ValueError:
            return
        with self._lock:
            previous = self.latest
            model = self.model
            if model is None or model.nbody - 1 != len(frame.positions) or (previous and frame.seq < previous.seq):
                self._want_model.set()  # another robot, or the same one restarted: fetch its model again
            self.latest = frame
            if previous is not None and frame.time < previous.time:
                self.path.clear()
            self.path.append((frame.time, float(frame.positions[0, 0]), float(frame.positions[0, 1])))
        self._changed.set()

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            self.status = RobotStatus.from_json(sample.payload.to_bytes())
        except (ValueError, TypeError):
            return
        self._status_at = time.monotonic()
        self._changed.set()

    def status_age(self) -> float | None:
        """Seconds since the last status arrived (None: none yet)."""
        at = self._status_at
        return None if at is None else time.monotonic() - at

    def _fetch_models(self) -> None:
        try:  # the status at once, rather than at the robot's next publication (up to a second away)
            for reply in self.session.get(status_key(self.name), timeout=2.0):
                if reply.ok is not None and self.status is None:
                    self._on_status(reply.ok)
        except Exception as exc:  # the session closing
            log.debug("asking the robot's status failed: %s", exc)
        while not self._stop.is_set():
            if not self._want_model.wait(0.5):
                continue
            try:
                replies = list(self.session.get(mjcf_key(self.name), timeout=3.0))
                text = next((r.ok.payload.to_string() for r in replies if r.ok is not None), None)
            except Exception as exc:  # the session closing
                log.debug("fetching the robot's model failed: %s", exc)
                text = None
            if text is None:
                self._stop.wait(1.0)  # a real robot has no model to send; ask again later
                continue
            model = mujoco.MjModel.from_xml_string(text)
            with self._lock:
                self.model = model
                self.generation += 1
                self._want_model.clear()
            self._changed.set()

    def show_twin(self, model: mujoco.MjModel, frame: PoseFrame) -> None:
        """Show a kinematic twin's frame (a real robot: no pose feed of its own)."""
        with self._lock:
            if self.model is not model:
                self.model = model
                self.generation += 1
            self.latest = frame
        self._changed.set()

    def keep(self, remover: Callable[[], object]) -> None:
        """Keep a subscription's remover, called on close."""
        self._removers.append(remover)

    def wait_changed(self, timeout: float) -> bool:
        changed = self._changed.wait(timeout)
        self._changed.clear()
        return changed

    def speed(self) -> tuple[float, float]:
        """(metres travelled, m/s) by the first body over the frames kept (the last 10 s)."""
        with self._lock:
            path = list(self.path)
        if len(path) < 2:
            return 0.0, 0.0
        (t0, x0, y0), (t1, x1, y1) = path[0], path[-1]
        distance = float(np.hypot(x1 - x0, y1 - y0))
        return distance, distance / (t1 - t0) if t1 > t0 else 0.0

    def close(self) -> None:
        self._stop.set()
        for remove in self._removers:
            try:
                remove()
            except Exception:
                log.debug("unsubscribe failed", exc_info=True)
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)
        self._fetcher.join(5)


class KinematicTwin:
    """A model of ``gait``'s robot posed from measured joint angles (degrees by module ID), base fixed."""

    def __init__(self, gait: Gait) -> None:
        self.model = mujoco.MjModel.from_xml_string(build_mjcf(gait.robot, name=gait.name))
        self._data = mujoco.MjData(self.model)
        self._qpos = {}
        for assignment in gait.modules:
            joint = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, module_name(assignment.id))
            self._qpos[assignment.id] = int(self.model.jnt_qposadr[joint])
        self.angles: dict[int, float] = {}
        self._seq = 0

    def frame(self, angles: dict[int, float], time: float) -> PoseFrame:
        """The bodies' poses with each module's joint at ``angles[id]`` (others at 0)."""
        data = self._data
        data.qpos[:] = self.model.qpos0
        for module_id, degrees in angles.items():
            address = self._qpos.get(module_id)
            if address is not None:
                data.qpos[address] = np.radians(degrees)
        mujoco.mj_kinematics(self.model, data)
        self._seq += 1
        return PoseFrame(self._seq, time, data.xpos[1:].copy(), data.xquat[1:].copy(), simulated=False)

    def follow(self, feed: LiveFeed, lookup: Callable[..., Any]) -> None:
        """Subscribe to every module's ``joint.angle`` (``lookup(node, name, timeout=…)``: RobotLink.lookup,
        Node.lookup) and pose ``feed`` at each publication."""
        lock = threading.Lock()
        start = time.monotonic()

        def arrived(module_id: int, value: float) -> None:
            with lock:
                self.angles[module_id] = float(value)
                frame = self.frame(self.angles, time.monotonic() - start)
            feed.show_twin(self.model, frame)

        for module_id in self._qpos:
            try:
                remote = lookup(module_name(module_id), "joint.angle", timeout=2.0)
            except Exception as exc:  # a module not on the bus: its joint stays at 0
                log.info("kinematic twin: no joint.angle of %s (%s)", module_name(module_id), exc)
                continue
            feed.keep(remote.on_change(lambda value, m=module_id: arrived(m, value)))
