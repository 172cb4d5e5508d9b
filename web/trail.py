"""The robot's trail and heading arrow in the 3D view, for the preview and the live robot alike: where its middle
has been (a green line on the ground) and which way it travels now (a magenta arrow from its middle), so a turn can
be judged at a glance. The view follows the robot, so both are drawn shifted as the robot and the grid are."""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

TRAIL_POINTS = 300
"""Points kept: at one point every SAMPLE_EVERY draws (10 a second at 60 frames/s), the last 30 s."""
SAMPLE_EVERY = 6
HEADING_POINTS = 10
"""The heading is the travel over the last this many points (one second)."""
TRAIL_COLOR = (40, 170, 60)
ARROW_COLOR = (210, 30, 200)
ARROW_LENGTH = 0.15
"""Metres."""
HEIGHT = 0.003
"""Just above the ground, under the robot."""


class Trail:
    """Points of the robot's middle (x, y), sampled as frames are drawn; ``reset`` when another robot or gait is
    shown, or the shown time goes back (a scrubbed preview)."""

    def __init__(self, scene: Any) -> None:
        self.scene = scene
        self.points: deque[tuple[float, float]] = deque(maxlen=TRAIL_POINTS)
        self._count = 0
        self._time = -1.0
        self._line: Any = None
        self._arrow: Any = None

    def reset(self) -> None:
        self.points.clear()
        self._count = 0
        self._time = -1.0

    def clear(self) -> None:
        """Start again and draw nothing: the view shows no robot (its trail and arrow went on showing where the
        last one had been)."""
        self.reset()
        for handle in (self._line, self._arrow):
            if handle is not None:
                handle.remove()
        self._line = self._arrow = None

    def heading(self) -> np.ndarray | None:
        """The unit direction of travel over the last second (x, y), or None while it has not moved."""
        if len(self.points) < 2:
            return None
        recent = np.array(list(self.points)[-HEADING_POINTS:])
        step = recent[-1] - recent[0]
        norm = float(np.hypot(*step))
        return step / norm if norm > 1e-4 else None

    def add(self, middle: np.ndarray, shift: np.ndarray, seconds: float = 0.0) -> None:
        """The robot's middle at this frame (of time ``seconds``: earlier than the last, a scrubbed preview, starts
        the trail again); every SAMPLE_EVERY frames a point is kept and the lines drawn again, shifted by ``shift``
        (what the view subtracts to keep the robot in the middle)."""
        if seconds < self._time:
            self.reset()
        self._time = seconds
        self._count += 1
        if self._count % SAMPLE_EVERY != 1:
            return
        self.points.append((float(middle[0]), float(middle[1])))
        if len(self.points) < 2:
            return
        xy = np.array(self.points) - shift[:2]
        path = np.column_stack([xy, np.full(len(xy), HEIGHT)]).astype(np.float32)
        segments = np.stack([path[:-1], path[1:]], axis=1)
        self._line = self.scene.add_line_segments("/trail", segments, TRAIL_COLOR, thickness=4.0,
                                                  thickness_units="screen")  # fmt: skip
        heading = self.heading()
        if heading is None:
            return
        tip = path[-1, :2] + heading * ARROW_LENGTH
        back = heading * ARROW_LENGTH * 0.3
        side = np.array([-heading[1], heading[0]]) * ARROW_LENGTH * 0.2
        ends = [(path[-1, :2], tip), (tip, tip - back + side), (tip, tip - back - side)]
        arrow = np.array([[[*a, HEIGHT * 2], [*b, HEIGHT * 2]] for a, b in ends], dtype=np.float32)
        self._arrow = self.scene.add_line_segments("/travel_arrow", arrow, ARROW_COLOR, thickness=5.0,
                                                   thickness_units="screen")  # fmt: skip
