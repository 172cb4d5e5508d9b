"""The topics of a robot's recordings and of its live Foxglove server (docs/protocol.md §11), in one place: the
recorder and the live server write them (server/foxglove_msgs.py), the studio's Replay tab reads them
(web/recording.py), and the page imports nothing of server/.
"""

from __future__ import annotations

TOPIC_TRANSFORMS = "/robot/transforms"
"""Every body's pose (foxglove.FrameTransforms, protobuf)."""
TOPIC_SCENE = "/robot/scene"
"""The bodies' boxes (foxglove.SceneUpdate, protobuf)."""
TOPIC_STATUS = "/robot/status"
TOPIC_ESTOP = "/robot/estop"
TOPIC_GROUP = "/robot/group"
ROBOT_TOPICS = (TOPIC_TRANSFORMS, TOPIC_SCENE, TOPIC_STATUS, TOPIC_ESTOP, TOPIC_GROUP)
"""The robot's own topics; any other is an attribute's, ``/<node>/<object>``."""


def attribute_topic(node: str, object_name: str) -> str:
    """``/m3/joint.angle``: one channel per publishing object, so a plot panel picks one by name."""
    return f"/{node}/{object_name}"


def attribute_of(topic: str) -> tuple[str, str] | None:
    """(node, object) of an attribute's topic; None for a robot topic or a name that is not one."""
    if topic in ROBOT_TOPICS:
        return None
    parts = topic.strip("/").split("/", 1)
    return (parts[0], parts[1]) if len(parts) == 2 and all(parts) else None
