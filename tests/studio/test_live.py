"""The Live view's sources without a browser: a kinematic twin of a real robot, posed from joint angles."""

from __future__ import annotations

import numpy as np

from gaits.model import LIBRARY, load
from web.live import KinematicTwin


def test_a_kinematic_twin_moves_its_bodies_with_the_joint_angles_and_keeps_its_base() -> None:
    gait = load(LIBRARY / "caterpillar.toml")
    twin = KinematicTwin(gait)
    flat = twin.frame({}, 0.0)
    bent = twin.frame({4: 45.0, 5: -30.0}, 0.1)
    assert not flat.simulated and len(flat.positions) == twin.model.nbody - 1
    moved = np.abs(bent.positions - flat.positions).max(axis=1)
    assert moved.max() > 0.01  # the bodies beyond the bent joints moved
    assert np.allclose(np.linalg.norm(bent.quaternions, axis=1), 1.0, atol=1e-6)
    root = int(twin.model.joint("root").bodyid[0]) - 1
    assert np.allclose(bent.positions[root], flat.positions[root])  # the base stays where it is
    assert twin.frame({99: 10.0}, 0.2).positions.shape == flat.positions.shape  # an unknown module is ignored
