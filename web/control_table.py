"""The classic gait control table as a picture: modules down, time across one period, colour = commanded angle.

This is how modular-robot papers draw a gait (PolyBot's and M-TRAN's gait control tables): at a glance the wave's
slope shows the phase step, the colour its amplitude. Blue is negative, white zero, red positive, full colour at
the joint limits; a black column marks where in the period the preview is, and the module selected in the editor
is framed. Rendered with numpy alone (viser sends it as a PNG).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

SAMPLES = 64
"""Columns of the table: samples of one period."""
CELL_HEIGHT = 12
CELL_WIDTH = 6
FRAME = np.array([255, 170, 0], dtype=np.uint8)
"""The selected module's frame: orange, like the highlighted state in the table above."""


def colours(angles: np.ndarray, limit: float) -> np.ndarray:
    """Diverging colours for angles (…, ) → (…, 3) uint8: -limit blue, 0 white, +limit red."""
    x = np.clip(angles / max(limit, 1e-9), -1.0, 1.0)[..., None]
    white = np.array([255.0, 255.0, 255.0])
    red, blue = np.array([200.0, 30.0, 30.0]), np.array([30.0, 80.0, 200.0])
    out = np.where(x >= 0, white + (red - white) * x, white + (blue - white) * (-x))
    return out.astype(np.uint8)


def control_table(rows: Sequence[Sequence[float]], limits: tuple[float, float], *, cursor: float | None = None,
                  selected: int | None = None) -> np.ndarray:  # fmt: skip
    """The picture (H, W, 3) of ``rows`` (module i's angle at each sample of one period, as gaits.table.expand
    gives them); ``cursor`` a fraction of the period in [0, 1); ``selected`` a 0-based module row."""
    table = np.asarray(rows, dtype=float)
    if table.ndim != 2 or table.size == 0:
        return np.full((CELL_HEIGHT, CELL_WIDTH, 3), 255, dtype=np.uint8)
    modules, samples = table.shape
    limit = max(abs(limits[0]), abs(limits[1]))
    image = np.repeat(np.repeat(colours(table, limit), CELL_HEIGHT, axis=0), CELL_WIDTH, axis=1)
    image[::CELL_HEIGHT, :, :] = np.minimum(image[::CELL_HEIGHT, :, :], 220)  # a faint line between modules
    if selected is not None and 0 <= selected < modules:
        top, bottom = selected * CELL_HEIGHT, (selected + 1) * CELL_HEIGHT - 1
        image[top : top + 2, :, :] = FRAME
        image[bottom - 1 : bottom + 1, :, :] = FRAME
        image[top : bottom + 1, :2, :] = FRAME
        image[top : bottom + 1, -2:, :] = FRAME
    if cursor is not None and np.isfinite(cursor):
        column = int((cursor % 1.0) * samples) * CELL_WIDTH
        image[:, column : column + 2, :] = 0
    return image
