"""Where the 3D view's pieces are: box meshes and the world poses of geoms and hinges from their bodies' poses,
computed for every piece at once with numpy (the scene is fed these arrays, never per-piece Python)."""

from __future__ import annotations

import mujoco
import numpy as np

BOX_FACES = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                       [2, 3, 7], [2, 7, 6], [1, 2, 6], [1, 6, 5], [0, 4, 7], [0, 7, 3]], dtype=np.uint32)  # fmt: skip


def box_vertices(half: np.ndarray) -> np.ndarray:
    x, y, z = half
    return np.array([[-x, -y, -z], [x, -y, -z], [x, y, -z], [-x, y, -z],
                     [-x, -y, z], [x, -y, z], [x, y, z], [-x, y, z]], dtype=np.float32)  # fmt: skip


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of (n, 4) w-x-y-z quaternions."""
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=1)  # fmt: skip


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors (n, 3) rotated by unit quaternions (n, 4)."""
    w, u = q[:, :1], q[:, 1:]
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def geom_poses(model: mujoco.MjModel, xpos: np.ndarray, xquat: np.ndarray, geoms: np.ndarray) -> tuple[np.ndarray, ...]:
    """World positions and w-x-y-z orientations of ``geoms`` from their bodies' poses (arrays over bodies 1..)."""
    bodies = model.geom_bodyid[geoms] - 1
    quat = xquat[bodies]
    return xpos[bodies] + _rotate(quat, model.geom_pos[geoms]), _quat_mul(quat, model.geom_quat[geoms])


def hinge_anchors(model: mujoco.MjModel, xpos: np.ndarray, xquat: np.ndarray,
                  joints: np.ndarray) -> np.ndarray:  # fmt: skip
    """World positions of hinge ``joints`` from their bodies' poses (arrays over bodies 1..): where a module's
    label goes."""
    bodies = model.jnt_bodyid[joints] - 1
    return xpos[bodies] + _rotate(xquat[bodies], model.jnt_pos[joints])
