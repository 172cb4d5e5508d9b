"""The ground grid is line segments (web/scene_view.py's ``grid_lines``): viser's grid shades every pixel of its
plane, which in software WebGL cost a sixth of each frame at 32 modules (stop 47, bench/studio.py)."""

from __future__ import annotations

import numpy as np
import pytest

from web.scene_view import GRID_CELL, GRID_COLOR, GRID_SECTION_COLOR, GRID_SIZE, grid_lines, ground_offset


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


@pytest.mark.parametrize(
    ("size", "cell", "lines", "darker"),
    [
        (2.0, 0.1, 21, [-1.0, 0.0, 1.0]),
        (4.0, 0.5, 9, [-2.0, -1.0, 0.0, 1.0, 2.0]),
        (1.0, 0.25, 5, [0.0]),
        (2.2, 0.25, 9, [-1.0, 0.0, 1.0]),  # (a review: a size not a whole number of cells put them off the metres)
        (4.0, 0.3, 13, [0.0]),  # a cell that divides no metre: a line at the origin, the only one on a metre
        (4.0, 0.4, 11, [-2.0, 0.0, 2.0]),
        (4.0, 2.0, 3, [-2.0, 0.0, 2.0]),  # (it raised ZeroDivisionError)
    ],
)
def test_lines_are_cells_from_the_origin_and_the_darker_ones_on_whole_metres(
    size: float, cell: float, lines: int, darker: list[float]
) -> None:
    points, colors = grid_lines(size, cell)
    assert len(points) == 2 * lines
    offsets = points[:lines, 0, 1]
    assert np.allclose(offsets / cell, np.round(offsets / cell), atol=1e-5) and np.any(np.isclose(offsets, 0.0))
    assert np.abs(offsets).max() <= size / 2 + 1e-6 and np.abs(offsets).max() > size / 2 - cell
    sections = [float(o) for o, c in zip(offsets, colors[:lines, 0], strict=True) if tuple(c) == GRID_SECTION_COLOR]
    assert sections == pytest.approx(darker)


def test_the_moved_grid_keeps_its_darker_lines_on_whole_metres_and_its_edges_two_metres_round_the_robot() -> None:
    """A review of stop 47: moved modulo a metre, the 5 m grid's edge came within 1.5 m of the robot (it was 1.75 m
    with the 4 m grid moved modulo its 0.1 m cell); moved by the shift's part past the nearest whole metre, 2 m."""
    points, colors = grid_lines()
    lines = len(points) // 2  # the first half along x: their offsets are their y
    darker = points[:lines][(colors[:lines, 0] == GRID_SECTION_COLOR).all(axis=1)][:, 0, 1]
    assert len(darker) == 5
    half = np.abs(points[:, :, :2]).max()
    for shift in np.linspace(-3.0, 3.0, 6001):  # the robot's position: the view is shifted by it
        offset = ground_offset(float(shift))
        assert abs(offset) <= 0.5 + 1e-9
        floor = darker + offset + shift  # where the darker lines lie on the floor
        assert np.allclose(floor, np.round(floor), atol=1e-6)  # (the points are float32)
        assert half - abs(offset) >= GRID_SIZE / 2 - 0.5 - 1e-9 >= 2.0 - 1e-9
