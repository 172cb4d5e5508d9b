"""The ground grid is line segments (web/scene_view.py's ``grid_lines``): viser's grid shades every pixel of its
plane, which in software WebGL cost a sixth of each frame at 32 modules (stop 47, bench/studio.py)."""

from __future__ import annotations

import numpy as np
import pytest

from web.scene_view import GRID_CELL, GRID_COLOR, GRID_SECTION_COLOR, GRID_SIZE, grid_lines


def test_the_grid_is_every_cell_line_both_ways_on_the_floor_with_every_metre_darker() -> None:
    points, colors = grid_lines()
    lines = round(GRID_SIZE / GRID_CELL) + 1
    assert points.shape == colors.shape == (2 * lines, 2, 3) and colors.dtype == np.uint8
    assert np.all(points[:, :, 2] == 0.0) and np.abs(points).max() == pytest.approx(GRID_SIZE / 2)
    along_x, along_y = points[:lines], points[lines:]
    assert np.all(along_x[:, 0, 1] == along_x[:, 1, 1]) and np.all(along_y[:, 0, 0] == along_y[:, 1, 0])
    offsets = along_x[:, 0, 1]
    assert np.allclose(np.diff(offsets), GRID_CELL) and offsets[0] == pytest.approx(-GRID_SIZE / 2)
    assert np.all(colors[:, 0] == colors[:, 1])  # one colour per segment
    darker = {round(float(o), 6) for o, c in zip(offsets, colors[:lines, 0], strict=True)
              if tuple(c) == GRID_SECTION_COLOR}  # fmt: skip
    assert darker == {float(m) for m in range(-int(GRID_SIZE // 2), int(GRID_SIZE // 2) + 1)}
    assert {tuple(c) for c in colors[:, 0]} == {GRID_COLOR, GRID_SECTION_COLOR}


@pytest.mark.parametrize(("size", "cell"), [(2.0, 0.1), (4.0, 0.5), (1.0, 0.25)])
def test_the_darker_lines_are_at_whole_metres_from_the_origin_whatever_the_size(size: float, cell: float) -> None:
    points, colors = grid_lines(size, cell)
    lines = round(size / cell) + 1
    sections = [float(o) for o, c in zip(points[:lines, 0, 1], colors[:lines, 0], strict=True)
                if tuple(c) == GRID_SECTION_COLOR]  # fmt: skip
    half = int(size / 2)
    assert sections == pytest.approx([float(m) for m in range(-half, half + 1)])
