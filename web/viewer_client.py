"""The page's websocket as a program sees it: what a browser sends first, and what in a message window moves the
robot. For tools and tests that watch the studio without a browser (bench/studio.py, tests/studio), so that they and
the studio agree on viser's protocol in one place."""

from __future__ import annotations


def camera_message() -> bytes:
    """The camera a browser reports when it opens the page (viser's ViewerCameraMessage, msgpack): viser counts a
    client as connected only from its first camera message, and the studio draws only for connected clients (it
    draws nothing nobody sees), so a client that never sends one receives no scene updates at all."""
    import msgspec

    return msgspec.msgpack.encode({"type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0],
                                   "position": [0.6, -1.2, 0.6], "fov": 1.0, "near": 0.01, "far": 100.0,
                                   "image_height": 800, "image_width": 1280, "look_at": [0.0, 0.0, 0.05],
                                   "up_direction": [0.0, 0.0, 1.0]})  # fmt: skip


def carries_poses(window: bytes) -> bool:
    """Whether a viser websocket window updates batched poses (the robot drawn). Its layout (viser/infra/_infra.py):
    8 bytes decompressed size, 8 bytes compressed size, zstd-compressed msgpack {"messages": [...]}, raw buffers."""
    import msgspec
    import zstandard

    size = int.from_bytes(window[8:16], "little")
    inner = msgspec.msgpack.decode(zstandard.ZstdDecompressor().decompress(window[16 : 16 + size]))
    return any("batched_positions" in str(message) for message in inner.get("messages", ()))
