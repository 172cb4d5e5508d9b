"""``asm-robot --foxglove PORT``: the robot live in Foxglove, over the Foxglove WebSocket protocol (foxglove-sdk).

Why in the robot process: the poses and the decoded publications are already there (the pose feed and the bridge's
JSON views, on the robot's own Zenoh session), so serving them costs one subscriber per key and no second network
hop; Foxglove connects to ``ws://HOST:PORT`` with no Zenoh on its side. The channels and their schemas are the
recorder's (server/foxglove_msgs.py): a layout made on a recording works live and the other way round.

The server listens on loopback unless told otherwise: the WebSocket protocol has no authentication, and Foxglove's
clients may call services and publish on servers that advertise it — this one advertises nothing but its channels.
"""

from __future__ import annotations

import json
import logging
import threading
import time

import foxglove
import zenoh
from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel

from asm_module.feed import decode_poses, poses_key, status_key
from asm_py.keys import RobotKeys, split

from . import foxglove_msgs as fx

log = logging.getLogger("asm_robot.foxglove")
SCENE_PERIOD = 1.0
"""Seconds between scene updates: a client that joins late sees the bodies within this long."""


class FoxgloveLive:
    """A Foxglove WebSocket server fed by robot ``robot``'s keys on ``session``; ``port`` 0 picks a free one."""

    def __init__(
        self, session: zenoh.Session, robot: str, port: int = 0, mjcf: str | None = None, host: str = "127.0.0.1"
    ) -> None:
        self.robot = robot
        self.bodies = fx.bodies(mjcf)
        self.context = foxglove.Context()  # its own: two robots in one process (tests) never share channels
        self.server = foxglove.start_server(name=f"asm-robot {robot}", host=host, port=port, context=self.context)
        self.port: int = self.server.port
        self.frames = 0
        """Pose frames logged (the bench compares them with what a client received)."""
        self._transforms = FrameTransformsChannel(fx.TOPIC_TRANSFORMS, context=self.context)
        self._scene = SceneUpdateChannel(fx.TOPIC_SCENE, context=self.context)
        self._status = foxglove.Channel(fx.TOPIC_STATUS, schema=fx.STATUS_SCHEMA, context=self.context)
        self._attributes: dict[str, foxglove.Channel] = {}
        self._lock = threading.Lock()
        self._scene_at = 0.0
        self._subs = [
            session.declare_subscriber(poses_key(robot), self._on_poses),
            session.declare_subscriber(status_key(robot), self._on_status),
            session.declare_subscriber(RobotKeys(robot).json_view("*", "*"), self._on_json),
        ]

    def _on_poses(self, sample: zenoh.Sample) -> None:
        if not (self._transforms.has_sinks() or self._scene.has_sinks()):
            return  # nobody watches: a control process spends nothing on encoding
        try:
            frame = decode_poses(sample.payload.to_bytes())
        except ValueError:
            return
        ns = time.time_ns()
        if len(self.bodies) < len(frame.positions):
            self.bodies = fx.bodies(None, len(frame.positions))
        if time.monotonic() - self._scene_at >= SCENE_PERIOD:
            self._scene_at = time.monotonic()
            self._scene.log(fx.scene_update(self.bodies, ns), log_time=ns)
        self._transforms.log(fx.frame_transforms(frame, self.bodies, ns), log_time=ns)
        self.frames += 1

    def _on_status(self, sample: zenoh.Sample) -> None:
        if self._status.has_sinks():
            self._status.log(sample.payload.to_bytes(), log_time=time.time_ns())

    def _on_json(self, sample: zenoh.Sample) -> None:
        chunks = split(sample.key_expr)  # asm/<robot>/<node>/json/<object>
        topic = fx.attribute_topic(chunks[2], chunks[4])
        with self._lock:
            channel = self._attributes.get(topic)
            if channel is None:
                channel = self._attributes[topic] = foxglove.Channel(topic, schema=fx.ATTRIBUTE_SCHEMA,
                                                                     context=self.context)  # fmt: skip
        if not channel.has_sinks():  # advertised (a client sees the topic), not logged until one subscribes
            return
        data = sample.payload.to_bytes()
        try:
            json.loads(data)  # a client decodes what it is sent: only JSON goes out
        except ValueError:
            return
        channel.log(data, log_time=time.time_ns())

    def close(self) -> None:
        for sub in self._subs:
            try:
                sub.undeclare()
            except zenoh.ZError:
                log.debug("already undeclared", exc_info=True)
        self._subs.clear()
        self.server.stop()
