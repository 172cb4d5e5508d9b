"""The 3D view: draws the robot in viser's scene from the preview (web/preview.py's frames), the live robot's pose
feed or a replayed recording, one batched mesh per distinct module shape; the loops that own those sources never
touch viser, and this never touches their simulations (as in mjviser)."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np
import viser

from .ground import GroundView
from .preview import PreviewLoop
from .scene_geometry import BOX_FACES, box_vertices, geom_poses, hinge_anchors
from .trail import Trail

GRID_CELL = 0.25
"""Metres between the ground grid's lines (0.1 until stop 47: 82 lines drew no faster than viser's grid)."""
GRID_SIZE = 5.0
"""The ground grid's width and depth, in metres: it moves under the robot by up to half a metre either way
(``ground_offset``)."""
GRID_COLOR, GRID_SECTION_COLOR = (200, 200, 200), (140, 140, 140)
"""Its lines' colours, and the colour of the lines on whole metres (viser's grid's)."""


def ground_offset(shift: float) -> float:
    """Where the grid goes when the view is shifted by ``shift`` metres to keep the robot in the middle: minus the
    shift's part past its nearest whole metre (within half a metre either way), so the darker lines stay on whole
    metres of the floor and the grid's edges stay at least GRID_SIZE / 2 - 0.5 m from the robot."""
    return -(shift - round(shift))


def grid_lines(size: float = GRID_SIZE, cell: float = GRID_CELL) -> tuple[np.ndarray, np.ndarray]:
    """The ground grid as line segments on z = 0: a line every ``cell`` metres from the origin, within ``size / 2``
    of it both ways, darker on whole metres; returns (segments, 2, 3) points and their colours.

    Line segments, not viser's grid: that grid is a shader run for every pixel of its plane, which covers most of
    the view, and with WebGL in software it cost a sixth of each frame (bench/studio.py, 32 modules, of 60 frames a
    second: 0.80-0.87 with it, 0.98-1.00 with no grid). Lines cost the pixels they cover: 34 of them (a cell of
    0.25 m) drew 0.97 and 0.97, 82 (0.1 m) 0.77 and 0.89."""
    half, tolerance = size / 2, 1e-9
    offsets = cell * np.arange(math.ceil(-half / cell - tolerance), math.floor(half / cell + tolerance) + 1)
    along_x = [((-half, o, 0.0), (half, o, 0.0)) for o in offsets]
    along_y = [((o, -half, 0.0), (o, half, 0.0)) for o in offsets]
    points = np.array(along_x + along_y, dtype=np.float32)
    section = np.tile(np.isclose(offsets, np.round(offsets), atol=1e-6), 2)
    colors = np.where(section[:, None, None], np.array(GRID_SECTION_COLOR), np.array(GRID_COLOR))
    return points, np.broadcast_to(colors, points.shape).astype(np.uint8)


LABEL_EVERY = 6
"""Module labels move with every sixth drawn frame (10 Hz at 60 frames a second): enough to read them, and 32
labels at full rate would double what the page receives."""


class SceneView:
    """Draws the robot in viser's scene, from the preview or from the live robot: one batched mesh per distinct
    module shape.

    ``source`` is "preview" (frames of a PreviewLoop) or "live" (the robot process's pose feed, a LiveFeed); a label
    in the scene says which one is shown. Lighting is plain by default — no shadows, no environment map: a browser
    without a GPU (software WebGL) draws a moving 32-module robot about 4× faster that way (bench/studio.py).
    ``rich=True`` turns both on.

    With ``follow`` (the default) the robot stays in the middle of the view and the ground moves under it: a gait
    crawls out of a fixed camera's view in seconds. The ground grid is shifted by the robot's position modulo one
    metre, so its lines, the darker ones on whole metres too, move exactly as the floor would."""

    def __init__(self, server: viser.ViserServer, loop: PreviewLoop, live: Any = None, *, rich: bool = False) -> None:
        self.server = server
        self.loop = loop
        self.live = live
        self.replay: Any = None
        """A recording played (web/replay.py's ReplaySource): the Replay tab sets it, then shows "replay"."""
        self.source = "preview"
        self._data: mujoco.MjData | None = None
        self._model: mujoco.MjModel | None = None
        self._batches: list[tuple[Any, np.ndarray]] = []
        self._built: tuple[Any, ...] | None = None
        self._drawn: object = None
        self._redraw = threading.Event()
        self.rich = rich
        self.follow = True
        self.labels = True
        """Show each module's name at its joint."""
        self._labels: list[Any] = []
        self._label_joints = np.zeros(0, dtype=int)
        self._draws = 0
        self.on_pick: Callable[[int], None] | None = None
        """Called with a module ID when the user clicks that module in the 3D view (on viser's thread pool)."""
        self._terrain = GroundView(server)
        """A rough ground, a step, patches: drawn from the preview's model (the flat floor is the grid)."""
        points, colors = grid_lines()
        self._ground = server.scene.add_line_segments("/ground", points, colors, thickness=1.0,
                                                      thickness_units="screen")  # fmt: skip
        self._label = server.scene.add_label("/source", "PREVIEW", position=(0.0, 0.0, 0.25))
        self.trail = Trail(server.scene)
        self.set_rich(rich)

    def set_rich(self, rich: bool) -> None:
        """Shadows and the environment map on or off (the meshes are rebuilt at the next draw)."""
        self.rich = rich
        self.server.scene.configure_default_lights(cast_shadow=rich)
        if rich:
            self.server.scene.configure_environment_map()
        else:
            self.server.scene.configure_environment_map(None)
        self._built = None

    def set_source(self, source: str) -> None:
        """Show the "preview", the "live" robot or a "replay" of a recording (rebuilt at the next draw, which comes at
        once: a source with nothing new, a paused replay, would otherwise wait for its next frame under the meshes of
        the one before)."""
        if source not in ("preview", "live", "replay") or (source != "preview" and getattr(self, source) is None):
            raise ValueError(f"no {source!r} source to show")
        self.source = source
        self._built = None
        self._redraw.set()

    def redraw(self) -> None:
        """Draw the newest frame again at the next draw (a browser connected after frames went undrawn)."""
        self._drawn = None
        self._redraw.set()

    def wait_changed(self, timeout: float) -> bool:
        """Wait until the shown source may have something new to draw."""
        if self._redraw.is_set():
            self._redraw.clear()
            return True
        if self.source in ("live", "replay"):
            return getattr(self, self.source).wait_changed(timeout)
        return self.loop.wait_changed(timeout)

    def _wanted(self) -> tuple[mujoco.MjModel | None, tuple[Any, ...]]:
        if self.source in ("live", "replay"):
            feed = getattr(self, self.source)
            return feed.model, (self.source, feed.generation, id(feed))
        return self.loop.sim.model, ("preview", self.loop.generation)

    def _remove_robot(self) -> None:
        """The robot's meshes and module labels out of the scene."""
        for handle, _ in self._batches:
            handle.remove()
        for label in self._labels:
            label.remove()
        self._batches, self._labels = [], []

    def _build(self, model: mujoco.MjModel, key: tuple[Any, ...]) -> None:
        self._remove_robot()
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or "" for j in range(model.njnt)]
        hinges = sorted((int(n[1:]), j) for j, n in enumerate(names) if n[:1] == "m" and n[1:].isdigit())
        self._label_joints = np.array([j for _, j in hinges], dtype=int)
        if self.labels:
            self._labels = [self.server.scene.add_label(f"/robot/label{k}", f"m{k}", position=(0.0, 0.0, 0.0))
                            for k, _ in hinges]  # fmt: skip
        self._model = model
        self._data = mujoco.MjData(model)
        groups: dict[tuple[float, float, float], list[int]] = {}
        # capsule chains collide with capsules but show their modules as the boxes of their visual geoms
        visual_bodies = {int(model.geom_bodyid[g]) for g in range(model.ngeom) if model.geom_group[g] == 1}
        for g in range(model.ngeom):
            body, kind = int(model.geom_bodyid[g]), model.geom_type[g]
            if body == 0:
                continue  # the floor
            if model.geom_group[g] != 1 and body in visual_bodies:
                continue
            size = model.geom_size[g]
            if kind == mujoco.mjtGeom.mjGEOM_BOX:
                half = (float(size[0]), float(size[1]), float(size[2]))
            elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
                half = (float(size[0]), float(size[0]), float(size[1] + size[0]))
            else:
                continue
            groups.setdefault((round(half[0], 5), round(half[1], 5), round(half[2], 5)), []).append(g)
        # live blue, a replay violet (apart from the green trail and the magenta heading arrow), the preview tan
        color = {"live": (60, 130, 200), "replay": (140, 70, 210)}.get(key[0], (217, 140, 38))
        for n, (half, geoms) in enumerate(groups.items()):
            ids = np.array(geoms)
            handle = self.server.scene.add_batched_meshes_simple(
                f"/robot/shape{n}", box_vertices(np.array(half)), BOX_FACES,
                batched_wxyzs=np.tile([1.0, 0, 0, 0], (len(ids), 1)), batched_positions=np.zeros((len(ids), 3)),
                batched_colors=color, cast_shadow=self.rich, receive_shadow=self.rich, lod="off",
            )  # fmt: skip
            self._batches.append((handle, ids))
            handle.on_click(lambda event, ids=ids, model=model: self._picked(model, ids, event.instance_index))
        self._terrain.build(model if key[0] == "preview" else None)
        self._ground.visible = not self._terrain.covers_start
        self._built = key
        self._drawn = None
        self.trail.reset()

    def _picked(self, model: mujoco.MjModel, ids: np.ndarray, instance: int | None) -> None:
        """A click on a piece of the robot: the module whose hinge starts that piece (``b<k>`` holds the half
        modules on either side of hinge k, so the piece b<k> belongs to module k, and b0 to module 1)."""
        if instance is None or self.on_pick is None or not 0 <= instance < len(ids):
            return
        body = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[ids[instance]])) or ""
        if body.startswith("b") and body[1:].isdigit():
            joints = sum(1 for j in range(model.njnt) if (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or "")
                         .startswith("m"))  # fmt: skip
            self.on_pick(min(max(int(body[1:]), 1), max(joints, 1)))

    def _poses(self, source: str) -> tuple[object, np.ndarray, np.ndarray] | None:
        """(what is drawn, body positions, body orientations) of ``source``, bodies 1.. of its model."""
        if source in ("live", "replay"):
            frame = getattr(self, source).latest
            model = self._model
            if frame is None or model is None or len(frame.positions) != model.nbody - 1:
                return None
            return frame, frame.positions, frame.quaternions
        frame = self.loop.shown()
        data, model = self._data, self._model
        if frame is None or data is None or model is None or len(frame.qpos) != data.qpos.shape[0]:
            return None
        data.qpos[:] = frame.qpos
        mujoco.mj_kinematics(model, data)
        return frame, data.xpos[1:], data.xquat[1:]

    def _clear(self, key: tuple[Any, ...]) -> None:
        """Nothing to draw for the shown source (a recording with no robot model, a robot whose model has not come):
        the robot last drawn goes, and the scene's label says why (it stayed drawn, the previous robot passed off as
        the recording's)."""
        self._remove_robot()
        self._model, self._data = None, None
        self._label_joints = np.zeros(0, dtype=int)
        self.trail.clear()
        self._terrain.build(None)
        self._ground.visible = True
        self._built, self._drawn = (*key, "nothing drawn"), None
        if key[0] == "replay":
            why = getattr(self.replay, "error", None) or "the recording has no robot model"
            self._label.text = f"REPLAY — {self.replay.recording.name}: {why}"
        else:
            self._label.text = f"{key[0].upper()} — no robot model yet: nothing drawn"
        self.server.flush()

    def draw(self) -> bool:
        """Draw the shown source's newest frame; False if there is none yet or it is the one already drawn."""
        model, key = self._wanted()
        if model is None:
            if self._built != (*key, "nothing drawn"):
                self._clear(key)
            return False
        if self._built != key:
            self._build(model, key)
            twin = key[0] == "live" and self.live.latest is not None and not self.live.latest.simulated
            self._label.text = ("LIVE — real robot: kinematic twin from its joint angles, base fixed" if twin
                                else "LIVE — the robot" if key[0] == "live"
                                else f"REPLAY — {self.replay.recording.name}" if key[0] == "replay"
                                else "PREVIEW — simulation of the edited gait")  # fmt: skip
        # the source this draw built for, not self.source read again: set_source on another thread between the two
        # drew a replay's frame on the preview's meshes, and that frame then counted as drawn (test_replay, stop 49)
        poses, built = self._poses(key[0]), self._model
        if poses is None or built is None or poses[0] is self._drawn:
            return False
        self._drawn, xpos, xquat = poses
        shift = np.zeros(3)
        placed = [(handle, *geom_poses(built, xpos, xquat, ids)) for handle, ids in self._batches]
        middle = np.concatenate([pos for _, pos, _ in placed]).mean(axis=0) if placed else np.zeros(3)
        if self.follow:
            shift[:2] = middle[:2]
        with self.server.atomic():
            for handle, pos, wxyz in placed:
                handle.batched_positions = (pos - shift).astype(np.float32)
                handle.batched_wxyzs = wxyz.astype(np.float32)
            self._ground.position = (ground_offset(shift[0]), ground_offset(shift[1]), 0.0)
            self._terrain.move(shift)
            self.trail.add(middle, shift, float(getattr(self._drawn, "time", 0.0)))  # a preview frame's time
            if self._labels and self._draws % LABEL_EVERY == 0:
                anchors = hinge_anchors(built, xpos, xquat, self._label_joints) - shift
                for label, anchor in zip(self._labels, anchors, strict=True):
                    label.position = (float(anchor[0]), float(anchor[1]), float(anchor[2]) + 0.04)
        # Send it now: after each send viser waits out a 1/60 s window, and a frame drawn inside that window is
        # replaced by the next one (same redundancy key) before it goes out: 60 frames/s reached the page as 54.
        self.server.flush()
        self._draws += 1
        return True

    def set_labels(self, shown: bool) -> None:
        """Module labels on or off (rebuilt at the next draw)."""
        self.labels = shown
        self._built = None
