"""The states-over-time picture of an event-driven or one-shot gait (web/state_timeline.py), and the preview's
record of each module's state it is drawn from."""

from __future__ import annotations

import numpy as np

from web.control_table import CELL_HEIGHT
from web.state_timeline import (
    CELL_WIDTH,
    COLUMNS,
    ENDED,
    NOTHING,
    STOPPED,
    WINDOW_SECONDS,
    legend,
    state_colour,
    state_timeline,
    window,
)


def _column(image: np.ndarray, seconds: float, start: float = 0.0) -> int:
    return int((seconds - start) / WINDOW_SECONDS * COLUMNS) * CELL_WIDTH + 1


def test_each_module_row_shows_its_state_at_each_time_grey_once_stopped_and_a_black_line_at_the_end():
    times = np.arange(0.0, 8.0, 1 / 60)
    states = np.zeros((len(times), 3), dtype=int)
    states[times >= 2.0, :] = 1
    states[times >= 4.0, 1] = 2
    states[times >= 5.5, :] = -1  # the one-shot program ended
    image = state_timeline(times, states, ended_at=5.5)
    assert image.shape == (3 * CELL_HEIGHT, COLUMNS * CELL_WIDTH, 3) and image.dtype == np.uint8

    def row(module: int) -> int:
        return module * CELL_HEIGHT + CELL_HEIGHT // 2

    assert (image[row(0), _column(image, 1.0)] == state_colour(0)).all()
    assert (image[row(0), _column(image, 3.0)] == state_colour(1)).all()
    assert (image[row(1), _column(image, 4.5)] == state_colour(2)).all()
    assert (image[row(0), _column(image, 4.5)] == state_colour(1)).all()
    assert (image[row(2), _column(image, 7.0)] == STOPPED).all()
    assert (image[row(2), _column(image, 12.0)] == NOTHING).all()  # not run yet: the window reaches past now
    line = np.nonzero((image[row(1)] == ENDED).all(axis=1))[0]
    assert len(line) == 3 and abs(line[0] - 5.5 / WINDOW_SECONDS * COLUMNS * CELL_WIDTH) <= 1
    assert len({tuple(image[row(0), _column(image, s)]) for s in (1.0, 3.0, 7.0)}) == 3


def test_a_long_run_shows_its_last_window_and_hostile_input_draws_an_empty_picture():
    times = np.arange(0.0, 100.0, 0.5)
    assert window(times) == (99.5 - WINDOW_SECONDS, 99.5)
    states = (np.arange(len(times))[:, None] // 10 % 3).repeat(2, axis=1)
    image = state_timeline(times, states, ended_at=3.0)  # an end out of the window: no line
    assert not (image == ENDED).all(axis=2).any()
    assert (image[CELL_HEIGHT // 2, -2] == state_colour(int(states[-1, 0]))).all()
    empty = (CELL_HEIGHT, CELL_WIDTH, 3)
    assert state_timeline(np.zeros(0), np.zeros((0, 3))).shape == empty
    assert state_timeline(np.zeros(3), np.zeros((2, 3))).shape == empty  # times and states disagree
    assert state_timeline(np.zeros(3), np.zeros(3)).shape == empty  # not modules × frames
    huge = state_timeline(np.array([0.0, 1.0]), np.array([[65535, -5], [7, 0]]))  # any uint16 state, any negative
    assert (huge[CELL_HEIGHT // 2, 0] == state_colour(65535)).all() and (huge[CELL_HEIGHT + 5, 0] == STOPPED).all()
    assert "S1" in legend(["S1", "S2"]) and "not running" in legend([])


def test_the_preview_records_each_module_s_state_and_its_end_for_a_one_shot_gait():
    from gaits.model import LIBRARY, load
    from web.preview import PreviewLoop

    from ..helpers import wait_until

    loop = PreviewLoop(load(LIBRARY / "curl_into_loop.toml"))
    try:
        loop.request("speed", 4.0)
        assert wait_until(lambda: loop.ended_at is not None, timeout=120)
        ended_at = loop.ended_at
        assert ended_at is not None
        times, states = loop.state_history(WINDOW_SECONDS)
        assert states.shape == (len(times), 8) and len(times) > 100
        assert set(np.unique(states[times < 5.0])) == {0, 1, 2, 3}  # its four states, in turn
        assert (states[times > ended_at + 0.1] == -1).all()  # ended: no gait runs
        assert 5.0 < ended_at < 6.0
    finally:
        loop.close()
