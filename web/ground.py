"""The ground of the 3D view when it is more than the flat floor: a rough ground's height field, a step's raised slabs,
friction patches' tiles (gaits/terrain.py), drawn as meshes from the preview's MuJoCo model.

The floor plane itself is the view's grid. Everything else on the world body is drawn: a height field as one mesh of
its cells, boxes as one mesh per colour (a slippery tile is bluish, as in the model). :func:`ground_meshes` reads
the model only; :class:`GroundView` keeps the viser handles and moves them with the view when it follows the robot.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
import viser

_CORNERS = np.array([[sx, sy, sz] for sz in (-1, 1) for sy in (-1, 1) for sx in (-1, 1)], dtype=float)
_BOX = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                 [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])  # fmt: skip
MAX_SLAB = 5.0
"""A ground box is drawn within ±MAX_SLAB m of the start (a step's slabs are 100 m long in the model)."""

Mesh = tuple[np.ndarray, np.ndarray, tuple[int, int, int]]
"""Vertices, faces, colour."""


def ground_meshes(model: mujoco.MjModel) -> list[Mesh]:
    """The world body's height fields and boxes as meshes in world coordinates (none on flat ground)."""
    meshes: list[Mesh] = []
    boxes: dict[tuple[int, int, int], list[np.ndarray]] = {}
    for g in range(model.ngeom):
        if int(model.geom_bodyid[g]) != 0:
            continue
        colour = tuple(int(255 * c) for c in model.geom_rgba[g][:3])
        rgb = (colour[0], colour[1], colour[2])
        pos = np.array(model.geom_pos[g], dtype=float)
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_HFIELD:
            meshes.append((*_hfield(model, int(model.geom_dataid[g]), pos), rgb))
        elif model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
            size = np.array(model.geom_size[g], dtype=float)
            low, high = pos - size, pos + size
            low[:2], high[:2] = np.maximum(low[:2], -MAX_SLAB), np.minimum(high[:2], MAX_SLAB)  # its part in view
            boxes.setdefault(rgb, []).append((low + high) / 2 + _CORNERS * (high - low) / 2)
    for rgb, corners in boxes.items():
        faces = np.concatenate([_BOX + 8 * k for k in range(len(corners))])
        meshes.append((np.concatenate(corners), faces, rgb))
    return meshes


def covers_start(model: mujoco.MjModel) -> bool:
    """A height field or a box of the ground lies under the start (the origin)."""
    for g in range(model.ngeom):
        if int(model.geom_bodyid[g]) != 0:
            continue
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_HFIELD:
            return True
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
            pos, size = model.geom_pos[g], model.geom_size[g]
            if abs(float(pos[0])) < float(size[0]) and abs(float(pos[1])) < float(size[1]):
                return True
    return False


def _hfield(model: mujoco.MjModel, index: int, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A height field's surface: MuJoCo's rows run along y, columns along x, heights scaled by its size[2]."""
    nrow, ncol = int(model.hfield_nrow[index]), int(model.hfield_ncol[index])
    rx, ry, top, _ = (float(v) for v in model.hfield_size[index])
    start = int(model.hfield_adr[index])
    heights = np.asarray(model.hfield_data[start : start + nrow * ncol], dtype=float).reshape(nrow, ncol) * top
    xs, ys = np.meshgrid(np.linspace(-rx, rx, ncol), np.linspace(-ry, ry, nrow))
    vertices = np.stack([xs.ravel(), ys.ravel(), heights.ravel()], axis=1) + pos
    k = np.arange(nrow * ncol).reshape(nrow, ncol)[:-1, :-1].ravel()
    faces = np.concatenate([np.stack([k, k + 1, k + ncol], axis=1), np.stack([k + 1, k + ncol + 1, k + ncol], axis=1)])
    return vertices, faces


class GroundView:
    """The ground meshes of the model shown, rebuilt with it; moved by ``shift`` when the view follows the robot."""

    def __init__(self, server: viser.ViserServer) -> None:
        self.server = server
        self.handles: list[Any] = []
        self.covers_start = False
        """A mesh lies under the robot's start (a rough field, tiles): the view hides its grid, which would cut
        through the bumps and flicker against the tiles' tops."""

    def build(self, model: mujoco.MjModel | None) -> None:
        for handle in self.handles:
            handle.remove()
        meshes = ground_meshes(model) if model is not None else []
        self.covers_start = model is not None and covers_start(model)
        scene = self.server.scene
        self.handles = [scene.add_mesh_simple(f"/terrain/part{k}", vertices.astype(np.float32), faces.astype(np.uint32),
                                              color=rgb, flat_shading=True, side="double")
                        for k, (vertices, faces, rgb) in enumerate(meshes)]  # fmt: skip

    def move(self, shift: np.ndarray) -> None:
        for handle in self.handles:
            handle.position = (-float(shift[0]), -float(shift[1]), 0.0)
