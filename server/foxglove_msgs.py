"""What a robot's Zenoh traffic becomes for Foxglove: one place for the recorder (asm-record) and the live server.

Poses use foxglove-sdk's own message classes (``foxglove.messages``: ``FrameTransforms`` and ``SceneUpdate``,
protobuf), so Foxglove's 3D panel draws the robot from a recording or a live link without a custom schema: one
frame per body (named after the MJCF body, ``b1``…), each a child of ``world``, and a scene entity per body (its
box geometry, in its own frame) that follows it. Everything ASM-specific — attribute values, the status, e-stops,
group messages — is JSON with a JSON schema (the ``asm.*`` schemas below), the encoding every MCAP tool reads.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass

from foxglove.messages import (
    Color,
    CubePrimitive,
    FrameTransform,
    FrameTransforms,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    Timestamp,
    Vector3,
)

from asm_module.feed import PoseFrame
from asm_module.recording_topics import (  # noqa: F401 (the topics, re-exported: the writers' one import)
    ROBOT_TOPICS,
    TOPIC_ESTOP,
    TOPIC_GROUP,
    TOPIC_SCENE,
    TOPIC_STATUS,
    TOPIC_TRANSFORMS,
    attribute_topic,
)

WORLD = "world"
"""The parent frame of every body: the pose feed carries world-frame poses."""


_ANY: dict[str, object] = {}
ATTRIBUTE_SCHEMA: dict[str, object] = {
    "title": "asm.AttributeValue",
    "description": "A publication of an ASM attribute or event, decoded: the JSON view of docs/protocol.md §6",
    "type": "object",
    "properties": {
        "node": {"type": "string"},
        "object": {"type": "string"},
        "class": {"type": "string"},
        "seq": {"type": "integer"},
        "t": {"type": "number"},
        "value": _ANY,
    },
    "required": ["node", "object", "value"],
}
STATUS_SCHEMA: dict[str, object] = {
    "title": "asm.RobotStatus",
    "description": "The robot process's status record (asm_module/feed.py)",
    "type": "object",
    "properties": {
        "robot": {"type": "string"},
        "mode": {"type": "string"},
        "modules": {"type": "integer"},
        "real_time_factor": {"type": ["number", "null"]},
        "behind": {"type": "boolean"},
        "estop": {"type": ["array", "null"], "items": {"type": "integer"}},
        "time": {"type": "number"},
        "unread_tables": {"type": "array"},
        "traffic": {"type": "object"},
    },
    "required": ["robot", "mode", "modules"],
}
ESTOP_SCHEMA: dict[str, object] = {
    "title": "asm.EStop",
    "description": "An emergency stop seen on the network: this robot's (scope robot) or the lab's (scope lab)",
    "type": "object",
    "properties": {"scope": {"enum": ["robot", "lab"]}, "source": {"type": "string"}, "reason": {"type": "string"}},
    "required": ["scope", "source", "reason"],
}
GROUP_SCHEMA: dict[str, object] = {
    "title": "asm.GroupMessage",
    "description": "A one-to-many request inside the robot (a deploy's activation, a drive's goals), its header "
    "decoded and its payload in hex",
    "type": "object",
    "properties": {
        "group": {"type": "string"},
        "source": {"type": "string"},
        "kind": {"type": "integer"},
        "method": {"type": "integer"},
        "class_id": {"type": "integer"},
        "object_id": {"type": "integer"},
        "data": {"type": "string"},
    },
    "required": ["group", "source", "data"],
}


@dataclass(frozen=True)
class Body:
    """A body of the robot's model, in the pose feed's order, with the box that draws it."""

    name: str
    size: tuple[float, float, float]
    """Full extents of its first box geometry, metres (a small cube when it has none)."""
    offset: tuple[float, float, float]
    """The box's centre in the body's frame."""


_DEFAULT_SIZE = (0.05, 0.05, 0.05)


def bodies(mjcf: str | None, count: int = 0) -> list[Body]:
    """The bodies of an MJCF model in MuJoCo's order (document order under ``worldbody``), padded with ``body<i>``
    up to ``count`` when the model is unknown or has fewer (a real robot publishes no poses and no model)."""
    found: list[Body] = []
    if mjcf:
        try:
            root = ElementTree.fromstring(mjcf)
        except ElementTree.ParseError:
            root = None
        world = root.find("worldbody") if root is not None else None
        for element in world.iter("body") if world is not None else ():
            size, offset = _DEFAULT_SIZE, (0.0, 0.0, 0.0)
            box = next((g for g in element.findall("geom") if g.get("type") == "box"), None)
            if box is not None:
                half = [float(v) for v in (box.get("size") or "").split()]
                if len(half) == 3:
                    size = (2 * half[0], 2 * half[1], 2 * half[2])
                centre = [float(v) for v in (box.get("pos") or "0 0 0").split()]
                if len(centre) == 3:
                    offset = (centre[0], centre[1], centre[2])
            found.append(Body(element.get("name") or f"body{len(found)}", size, offset))
    return found + [Body(f"body{i}", _DEFAULT_SIZE, (0.0, 0.0, 0.0)) for i in range(len(found), count)]


def stamp(ns: int) -> Timestamp:
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def frame_transforms(frame: PoseFrame, names: list[Body], ns: int) -> FrameTransforms:
    """The pose frame as one ``foxglove.FrameTransforms``: body i is frame ``names[i]`` in ``world``."""
    when = stamp(ns)
    transforms = []
    for i, (p, q) in enumerate(zip(frame.positions.tolist(), frame.quaternions.tolist(), strict=True)):
        child = names[i].name if i < len(names) else f"body{i}"
        transforms.append(FrameTransform(timestamp=when, parent_frame_id=WORLD, child_frame_id=child,
                                         translation=Vector3(x=p[0], y=p[1], z=p[2]),
                                         rotation=Quaternion(x=q[1], y=q[2], z=q[3], w=q[0])))  # fmt: skip
    return FrameTransforms(transforms=transforms)


def scene_update(names: list[Body], ns: int) -> SceneUpdate:
    """One entity per body, a box in the body's own frame (frame-locked: it moves with the transforms)."""
    when = stamp(ns)
    colour = Color(r=0.2, g=0.55, b=0.9, a=1.0)
    entities = [
        SceneEntity(
            timestamp=when,
            frame_id=body.name,
            id=body.name,
            frame_locked=True,
            cubes=[
                CubePrimitive(
                    pose=Pose(
                        position=Vector3(x=body.offset[0], y=body.offset[1], z=body.offset[2]),
                        orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                    ),
                    size=Vector3(x=body.size[0], y=body.size[1], z=body.size[2]),
                    color=colour,
                )
            ],
        )
        for body in names
    ]
    return SceneUpdate(entities=entities)
