"""The Live source of the 3D view: the robot process's pose feed, as any viewer receives it over Zenoh.

The robot publishes its bodies' poses (server/feed.py) and answers its MuJoCo model on request; this keeps the
newest frame and the model to draw it with. Callbacks run on Zenoh's threads and only store; the view reads.
"""

from __future__ import annotations

import logging
import threading
from collections import deque

import mujoco
import numpy as np
import zenoh

from server.feed import PoseFrame, RobotStatus, decode_poses, mjcf_key, poses_key, status_key

log = logging.getLogger("asm_studio.live")


class LiveFeed:
    """The newest pose frame and status of robot ``name``, and its model (fetched when the robot changes)."""

    def __init__(self, session: zenoh.Session, name: str = "robot") -> None:
        self.session = session
        self.name = name
        self.model: mujoco.MjModel | None = None
        self.status: RobotStatus | None = None
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
        self._changed.set()

    def _fetch_models(self) -> None:
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
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)
        self._fetcher.join(5)
