"""What a robot process publishes for viewers: its keys, the binary layout of its body poses, and its status.

Keys (docs/protocol.md §10), all under ``asm/<robot>/@robot/`` (asm_py.keys):

    poses   the simulated robot's body poses, at up to 60 Hz (binary, below); a real robot publishes none
    status  JSON, once a second and on a change: {"robot", "mode": "simulated"|"real", "modules", "real_time_factor",
            "behind", "estop": [module IDs latched] (null when unknown: a real bus), "time"}
    mjcf    a queryable answering the simulated robot's MuJoCo model (MJCF text), so a viewer draws the bodies
    alive/<session>  the robot process's liveliness token: it vanishes the moment the process does

Pose frame, little-endian::

    0   2  magic b"RP"
    2   1  version 1
    3   1  flags: bit 0 simulated
    4   4  uint32 frame sequence number
    8   8  float64 simulated time, s
    16  2  uint16 N, bodies (every body of the model but the world, in model order)
    18  28 per body: float32 x, y, z (m, world frame), float32 qw, qx, qy, qz (unit quaternion)
"""

from __future__ import annotations

import json
import struct
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from asm_py.keys import ALL_ROBOTS, RobotKeys, robot_of

if TYPE_CHECKING:
    import zenoh

MAGIC = b"RP"
VERSION = 1
_HEAD = struct.Struct("<2sBBIdH")
_BODY = np.dtype([("pos", "<f4", 3), ("quat", "<f4", 4)])


def poses_key(robot: str) -> str:
    return RobotKeys(robot).robot_key("poses")


def status_key(robot: str) -> str:
    return RobotKeys(robot).robot_key("status")


def mjcf_key(robot: str) -> str:
    return RobotKeys(robot).robot_key("mjcf")


@dataclass(frozen=True)
class PoseFrame:
    seq: int
    time: float
    positions: np.ndarray
    """(N, 3) metres."""
    quaternions: np.ndarray
    """(N, 4) w, x, y, z."""
    simulated: bool = True


def encode_poses(frame: PoseFrame) -> bytes:
    bodies = np.empty(len(frame.positions), dtype=_BODY)
    bodies["pos"] = frame.positions
    bodies["quat"] = frame.quaternions
    head = _HEAD.pack(MAGIC, VERSION, int(frame.simulated), frame.seq & 0xFFFFFFFF, frame.time, len(bodies))
    return head + bodies.tobytes()


def decode_poses(data: bytes) -> PoseFrame:
    """The frame in ``data``; ValueError for bytes that are not one."""
    if len(data) < _HEAD.size:
        raise ValueError(f"a pose frame has at least {_HEAD.size} bytes, not {len(data)}")
    magic, version, flags, seq, time, count = _HEAD.unpack_from(data)
    if magic != MAGIC or version != VERSION:
        raise ValueError(f"not a pose frame of version {VERSION} (magic {magic!r}, version {version})")
    if len(data) != _HEAD.size + count * _BODY.itemsize:
        raise ValueError(f"a pose frame of {count} bodies has {_HEAD.size + count * _BODY.itemsize} bytes")
    bodies = np.frombuffer(data, dtype=_BODY, count=count, offset=_HEAD.size)
    return PoseFrame(seq, time, bodies["pos"].astype(float), bodies["quat"].astype(float), bool(flags & 1))


@dataclass
class RobotStatus:
    robot: str
    mode: str
    """"simulated" or "real"."""
    modules: int
    real_time_factor: float | None = None
    """Simulated seconds per wall-clock second over the last second (None for a real robot)."""
    behind: bool = False
    """The simulation cannot keep up with the wall clock (it runs slower than real time)."""
    estop: list[int] | None = None
    """Modules whose e-stop is latched (None: not known, on a real bus)."""
    time: float = 0.0
    unread_tables: list[str] = field(default_factory=list)
    """Modules whose object table the bridge has not read yet: their publications do not reach Zenoh yet."""
    commissioning_stopped: bool = False
    """The robot's commissioning service latched on an e-stop and was not released since (a board without an ID
    cannot latch: nothing else says the e-stop holds for it)."""
    traffic: dict[str, int] = field(default_factory=dict)
    """The bridge's counters: messages from Zenoh put on the bus (``to_can``), replies and publications put on
    Zenoh, refusals, e-stops from Zenoh (``estops``) — what reached this robot."""

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str | bytes) -> RobotStatus:
        """The status in ``text``; ValueError for text that is not one (fields this version does not know are
        ignored, so an older viewer reads a newer robot)."""
        data = json.loads(text)
        if not isinstance(data, dict):
            raise ValueError("a robot status is a JSON object")
        known = {k: v for k, v in data.items() if k in cls.__dataclass_fields__}
        try:
            return cls(**known)
        except TypeError as exc:
            raise ValueError(f"not a robot status: {exc}") from None


def read_statuses(session: zenoh.Session, robot: str | None = None, timeout: float = 1.0) -> dict[str, RobotStatus]:
    """The robots' statuses now, by name (``robot``'s alone, or every robot's on the network): a status counts only
    when it came under its own robot's key, naming that robot."""
    keys = ALL_ROBOTS if robot is None else RobotKeys(robot)
    found: dict[str, RobotStatus] = {}
    for reply in session.get(keys.robot_key("status"), timeout=timeout):
        if reply.ok is None:
            continue
        try:
            status = RobotStatus.from_json(reply.ok.payload.to_bytes())
        except ValueError:
            continue
        if status.robot == robot_of(str(reply.ok.key_expr)):
            found[status.robot] = status
    return found
